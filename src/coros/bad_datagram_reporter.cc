#include "bad_datagram_reporter.h"

#include <fmt/format.h>

namespace icars::coros {

BadDatagramReporter::BadDatagramReporter(std::chrono::milliseconds period, std::size_t max_sources)
    : period_(period), max_sources_(max_sources) {}

std::optional<BadDatagramReporter::Report> BadDatagramReporter::add(
    const asio::ip::udp::endpoint& from, Reason reason, std::string error, Clock::time_point now) {
  std::string source = from.address().to_string();
  if (!sources_.contains(source) && sources_.size() >= max_sources_) source = "other";
  Report one;
  one.source = source;
  one.from = fmt::format("{}:{}", from.address().to_string(), from.port());
  one.error = std::move(error);
  one.count = 1;
  (reason == Reason::malformed ? one.malformed : one.refused) = 1;
  const auto [it, fresh] = sources_.try_emplace(source);
  if (fresh) {
    it->second.period_end = now + period_;
    return one;
  }
  Report& pending = it->second.pending;
  pending.source = std::move(one.source);
  pending.from = std::move(one.from);
  pending.error = std::move(one.error);
  pending.count += 1;
  pending.malformed += one.malformed;
  pending.refused += one.refused;
  return std::nullopt;
}

std::vector<BadDatagramReporter::Report> BadDatagramReporter::due(Clock::time_point now) {
  std::vector<Report> out;
  for (auto it = sources_.begin(); it != sources_.end();) {
    if (it->second.period_end > now) {
      ++it;
    } else if (it->second.pending.count == 0) {
      it = sources_.erase(it);
    } else {
      out.push_back(std::exchange(it->second.pending, Report{}));
      it->second.period_end = now + period_;
      ++it;
    }
  }
  return out;
}

std::optional<BadDatagramReporter::Clock::time_point> BadDatagramReporter::next_due() const {
  std::optional<Clock::time_point> next;
  for (const auto& [source, s] : sources_) {
    if (!next || s.period_end < *next) next = s.period_end;
  }
  return next;
}

std::vector<BadDatagramReporter::Report> BadDatagramReporter::flush() {
  std::vector<Report> out;
  for (auto& [source, s] : sources_) {
    if (s.pending.count > 0) out.push_back(std::move(s.pending));
  }
  sources_.clear();
  return out;
}

}  // namespace icars::coros
