#include "icars/coros/agent.h"

#include <fmt/format.h>

#include <asio/post.hpp>

#include "bad_datagram_reporter.h"

namespace icars::coros {

namespace {

void emit_bad_datagrams(Agent& agent, const BadDatagramReporter::Report& r) {
  agent.emit({{"event", "bad_datagram"},
              {"from", r.from},
              {"source", r.source},
              {"error", r.error},
              {"count", r.count},
              {"malformed", r.malformed},
              {"refused", r.refused}});
}

}  // namespace

void MessageProcessor::process(const Datagram& datagram, const Envelope& envelope) const {
  const auto it = handlers_.find(static_cast<std::uint16_t>(datagram.code));
  if (it == handlers_.end()) {
    throw CorosError(fmt::format("no handler for message code {} from {}",
                                 static_cast<unsigned>(datagram.code), envelope.sender));
  }
  for (const auto& handler : it->second) handler(datagram, envelope);
}

void Timer::cancel() {
  active_ = false;
  timer_.cancel();
}

Agent::Agent(AgentConfiguration config)
    : config_(std::move(config)),
      neighbors_(config_.neighbor_expiry),
      bad_datagram_reports_(std::make_unique<BadDatagramReporter>()) {
  if (config_.id.empty()) throw CorosError("an agent needs an id");
  transport_ = std::make_unique<UdpTransport>(io_, config_.transport);
}

Agent::~Agent() { stop(); }

void Agent::add_operator(std::shared_ptr<Operator> op) {
  if (started_flag_) throw std::logic_error("Agent::add_operator after start()");
  operators_.push_back(std::move(op));
}

void Agent::set_event_sink(EventSink sink) { sink_ = std::move(sink); }

double Agent::wall_seconds() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

void Agent::emit(nlohmann::json event) {
  if (!sink_) return;
  event["agent"] = config_.id;
  event["time"] = wall_seconds();
  sink_(event);
}

void Agent::start() {
  if (started_flag_) return;
  started_flag_ = true;
  started_ = std::chrono::steady_clock::now();
  post([this] {
    transport_->start(
        [this](const Datagram& d, const asio::ip::udp::endpoint& from) { on_datagram(d, from); },
        [this](const std::string& what, const asio::ip::udp::endpoint& from) {
          on_bad_datagram(from, true, what);
        });
    const auto self = transport_->local_endpoint();
    emit({{"event", "started"},
          {"role", config_.role},
          {"ip", self.address().to_string()},
          {"port", self.port()},
          {"authentication", transport_->authenticated() ? "hmac-sha256" : "none"}});
    for (const auto& op : operators_) op->init(*this);
  });
  thread_ = std::thread([this] {
    auto guard = asio::make_work_guard(io_);
    io_.run();
  });
}

void Agent::stop() {
  if (stopped_) return;
  stopped_ = true;
  if (thread_.joinable()) {
    asio::post(io_, [this] {
      for (const auto& op : operators_) op->shutdown();
      for (const auto& weak : timers_) {
        if (auto t = weak.lock()) t->cancel();
      }
      bad_datagram_timer_.cancel();
      for (const auto& r : bad_datagram_reports_->flush()) emit_bad_datagrams(*this, r);
      const TransportStats s = transport_->stats();
      nlohmann::json by_source = nlohmann::json::object();
      for (const auto& [source, d] : s.dropped_by_source) {
        by_source[source] = {{"malformed", d.malformed},
                             {"rejected_unsigned", d.rejected_unsigned},
                             {"rejected_bad_tag", d.rejected_bad_tag},
                             {"rejected_replayed", d.rejected_replayed}};
      }
      emit({{"event", "stopped"},
            {"datagrams",
             {{"sent", s.sent},
              {"received", s.received},
              {"malformed", s.malformed},
              {"rejected_unsigned", s.rejected_unsigned},
              {"rejected_bad_tag", s.rejected_bad_tag},
              {"rejected_replayed", s.rejected_replayed},
              {"refused", bad_datagrams_ - s.malformed},
              {"dropped_by_source", std::move(by_source)}}}});
      transport_->close();
      io_.stop();
    });
    thread_.join();
  }
  transport_->close();
  // Run what the closing aborted (receives, cancelled timers), so nothing pending refers to
  // the sockets when they are destroyed.
  io_.restart();
  io_.run();
}

void Agent::post(std::function<void()> fn) { asio::post(io_, std::move(fn)); }

void Agent::on_datagram(const Datagram& datagram, const asio::ip::udp::endpoint& from) {
  if (!processor_.handles(datagram.code)) return;  // another application's message: not ours
  try {
    processor_.process(datagram, Envelope{datagram.sender, from});
  } catch (const std::exception& e) {  // a handler's bug must not take the agent down
    on_bad_datagram(from, false, e.what());
  }
}

void Agent::on_bad_datagram(const asio::ip::udp::endpoint& from, bool malformed, std::string error) {
  ++bad_datagrams_;
  const auto reason =
      malformed ? BadDatagramReporter::Reason::malformed : BadDatagramReporter::Reason::refused;
  if (auto report = bad_datagram_reports_->add(from, reason, std::move(error),
                                               std::chrono::steady_clock::now())) {
    emit_bad_datagrams(*this, *report);
  }
  arm_bad_datagram_timer();
}

void Agent::arm_bad_datagram_timer() {
  if (bad_datagram_timer_armed_) return;
  const auto next = bad_datagram_reports_->next_due();
  if (!next) return;
  bad_datagram_timer_armed_ = true;
  bad_datagram_timer_.expires_at(*next);
  bad_datagram_timer_.async_wait([this](const std::error_code& ec) {
    bad_datagram_timer_armed_ = false;
    if (ec) return;
    for (const auto& r : bad_datagram_reports_->due(std::chrono::steady_clock::now())) {
      emit_bad_datagrams(*this, r);
    }
    arm_bad_datagram_timer();
  });
}

void Agent::schedule(const std::shared_ptr<Timer>& timer, std::chrono::milliseconds delay,
                     std::function<void()> fn, bool repeat) {
  timer->timer_.expires_after(delay);
  std::weak_ptr<Timer> weak = timer;
  timer->timer_.async_wait(
      [this, weak, delay, fn = std::move(fn), repeat](const std::error_code& ec) {
        auto t = weak.lock();
        if (ec || !t || !t->active_) return;
        if (!repeat) t->active_ = false;
        fn();
        if (repeat && t->active_) schedule(t, delay, fn, true);
      });
}

std::shared_ptr<Timer> Agent::start_timer(std::chrono::milliseconds delay, std::function<void()> fn,
                                          bool repeat) {
  if (timers_.size() > 64) std::erase_if(timers_, [](const auto& w) { return w.expired(); });
  auto timer = std::shared_ptr<Timer>(new Timer(io_));
  timers_.push_back(timer);
  schedule(timer, delay, std::move(fn), repeat);
  return timer;
}

std::shared_ptr<Timer> Agent::after(std::chrono::milliseconds delay, std::function<void()> fn) {
  return start_timer(delay, std::move(fn), false);
}

std::shared_ptr<Timer> Agent::every(std::chrono::milliseconds period, std::function<void()> fn) {
  return start_timer(period, std::move(fn), true);
}

}  // namespace icars::coros
