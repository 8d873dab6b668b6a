#include "icars/planet/publisher.h"

#include <fmt/format.h>

#include <algorithm>

#include "icars/planet/rmi_message.h"

namespace icars::planet::detail {

std::uint64_t FanOut::subscribe(std::shared_ptr<Link> link, std::string path) {
  std::lock_guard lock(mutex_);
  if (subscribers_.size() >= options_.max_subscribers) {
    throw Error(ErrorKind::overloaded,
                fmt::format("{} refuses {} at {}: {} subscribers already (max_subscribers)",
                            method_, link->describe(), path, subscribers_.size()));
  }
  Subscriber s;
  s.info.id = next_id_++;
  s.info.link = link->describe();
  s.info.path = std::move(path);
  s.link = std::move(link);
  subscribers_.push_back(std::move(s));
  return subscribers_.back().info.id;
}

bool FanOut::unsubscribe(std::uint64_t id) {
  std::lock_guard lock(mutex_);
  return std::erase_if(subscribers_, [id](const Subscriber& s) { return s.info.id == id; }) != 0;
}

bool FanOut::unsubscribe(const Link& link, const std::string& path) {
  std::lock_guard lock(mutex_);
  return std::erase_if(subscribers_, [&](const Subscriber& s) {
           return s.info.path == path && s.link.get() == &link;
         }) != 0;
}

std::size_t FanOut::publish(std::span<const std::byte> arguments) {
  const auto now = std::chrono::steady_clock::now();
  std::lock_guard lock(mutex_);
  std::size_t sent = 0;
  const auto before = subscribers_.size();
  std::erase_if(subscribers_, [&](Subscriber& s) {
    const auto delivered = s.info.delivered;
    const bool keep = deliver(s, arguments, now);
    if (s.info.delivered != delivered) ++sent;
    return !keep;
  });
  removed_ += before - subscribers_.size();
  return sent;
}

// Sends one event to `s`; false when the subscriber is to be removed.
bool FanOut::deliver(Subscriber& s, std::span<const std::byte> arguments,
                     std::chrono::steady_clock::time_point now) {
  auto connection = s.link->connection();
  if (!connection || !connection->is_open()) {
    // A direct connection that closed is gone for good; a reconnecting link may come back.
    if (dynamic_cast<Connection*>(s.link.get()) != nullptr) return false;
    ++s.info.dropped;
    return true;
  }
  if (connection->queued_bytes() > options_.max_backlog_bytes) {
    if (!s.over_limit) {
      s.over_limit = true;
      s.over_limit_since = now;
    }
    ++s.info.dropped;
    return now - s.over_limit_since < options_.stall_timeout;
  }
  s.over_limit = false;
  std::vector<std::byte> message;
  message.reserve(16 + s.info.path.size() + method_.size() + arguments.size());
  Writer w(message);
  w.u8(static_cast<std::uint8_t>(RmiCode::notify));
  w.u32(0);
  w.str(s.info.path);
  w.str(method_);
  w.raw(arguments);
  try {
    connection->send(std::move(message));
    ++s.info.delivered;
  } catch (const Error& e) {
    ++s.info.dropped;
    if (e.kind() == ErrorKind::disconnected && dynamic_cast<Connection*>(s.link.get())) {
      return false;
    }
  }
  return true;
}

std::vector<SubscriberInfo> FanOut::subscribers() const {
  std::lock_guard lock(mutex_);
  std::vector<SubscriberInfo> out;
  out.reserve(subscribers_.size());
  for (const auto& s : subscribers_) out.push_back(s.info);
  return out;
}

std::uint64_t FanOut::removed() const {
  std::lock_guard lock(mutex_);
  return removed_;
}

}  // namespace icars::planet::detail
