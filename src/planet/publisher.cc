#include "icars/planet/publisher.h"

#include <fmt/format.h>

#include <algorithm>

#include "icars/planet/rmi_message.h"

namespace icars::planet::detail {

namespace {

bool is_direct(const Link& link) { return dynamic_cast<const Connection*>(&link) != nullptr; }

// Who a listener is beyond one connection: the principal its endpoint authenticated as, the
// name (PUN) that endpoint announced, and the listener's path there.
std::string listener_identity(const Link& link, const std::string& path) {
  auto connection = link.connection();
  if (!connection) return fmt::format("\x1f{}\x1f{}", link.describe(), path);
  const auto principal = connection->principal();
  return fmt::format("{}\x1f{}\x1f{}", principal ? principal->name : "", connection->peer_pun(),
                     path);
}

}  // namespace

std::uint64_t FanOut::subscribe(std::shared_ptr<Link> link, std::string path) {
  const auto now = std::chrono::steady_clock::now();
  std::lock_guard lock(mutex_);
  sweep(now);
  auto identity = listener_identity(*link, path);
  // The same listener back (its link came back): it takes over what was held for it.
  std::deque<Held> held;
  std::uint64_t dropped = 0;
  if (auto it = std::find_if(subscribers_.begin(), subscribers_.end(),
                             [&](const Subscriber& s) { return s.lapsed && s.listener == identity; });
      it != subscribers_.end()) {
    held = std::move(it->held);
    dropped = it->info.dropped;
    subscribers_.erase(it);
  }
  const auto active = static_cast<std::size_t>(
      std::count_if(subscribers_.begin(), subscribers_.end(), [](const Subscriber& s) { return !s.lapsed; }));
  if (active >= options_.max_subscribers) {
    throw Error(ErrorKind::overloaded,
                fmt::format("{} refuses {} at {}: {} subscribers already (max_subscribers)",
                            method_, link->describe(), path, active));
  }
  // Lapsed subscribers make room for subscribed ones, the oldest first.
  while (subscribers_.size() >= options_.max_subscribers) {
    auto oldest = std::min_element(subscribers_.begin(), subscribers_.end(), [](const Subscriber& a, const Subscriber& b) {
      return a.lapsed != b.lapsed ? a.lapsed : a.lapsed_since < b.lapsed_since;
    });
    subscribers_.erase(oldest);
  }
  Subscriber s;
  s.info.id = next_id_++;
  s.info.link = link->describe();
  s.info.path = std::move(path);
  s.info.dropped = dropped;
  s.link = std::move(link);
  s.listener = std::move(identity);
  for (auto& h : held) s.held_bytes += h.arguments.size();
  s.held = std::move(held);
  s.info.held = s.held.size();
  subscribers_.push_back(std::move(s));
  auto& added = subscribers_.back();
  if (!added.held.empty()) {
    if (auto connection = added.link->connection(); connection && connection->is_open()) {
      replay(added, *connection, now);
    }
  }
  return added.info.id;
}

bool FanOut::unsubscribe(std::uint64_t id) {
  std::lock_guard lock(mutex_);
  return std::erase_if(subscribers_, [id](const Subscriber& s) { return !s.lapsed && s.info.id == id; }) != 0;
}

bool FanOut::unsubscribe(const Link& link, const std::string& path) {
  std::lock_guard lock(mutex_);
  return std::erase_if(subscribers_, [&](const Subscriber& s) {
           return !s.lapsed && s.info.path == path && s.link.get() == &link;
         }) != 0;
}

std::size_t FanOut::publish(std::span<const std::byte> arguments) {
  const auto now = std::chrono::steady_clock::now();
  std::lock_guard lock(mutex_);
  sweep(now);
  std::size_t sent = 0;
  std::erase_if(subscribers_, [&](Subscriber& s) {
    if (s.lapsed) {
      hold(s, arguments, now);
      return false;
    }
    const auto delivered = s.info.delivered;
    const auto outcome = deliver(s, arguments, now);
    if (s.info.delivered != delivered) ++sent;
    if (outcome == Outcome::lapse) lapse(s, now);
    if (outcome == Outcome::remove) ++removed_;
    return outcome == Outcome::remove;
  });
  return sent;
}

void FanOut::sweep(TimePoint now) {
  std::erase_if(subscribers_, [&](Subscriber& s) {
    if (!s.lapsed) {
      auto connection = s.link->connection();
      if (is_direct(*s.link) && (!connection || !connection->is_open())) lapse(s, now);
      return false;
    }
    return now - s.lapsed_since >= options_.hold_for;
  });
}

void FanOut::lapse(Subscriber& s, TimePoint now) {
  s.lapsed = true;
  s.lapsed_since = now;
  s.over_limit = false;
  s.link.reset();  // the closed connection goes; the identity stays
  ++removed_;
}

void FanOut::hold(Subscriber& s, std::span<const std::byte> arguments, TimePoint now) {
  if (options_.hold_for.count() <= 0 || options_.max_held == 0 ||
      arguments.size() > options_.max_backlog_bytes) {
    ++s.info.dropped;
    return;
  }
  while (!s.held.empty() && (s.held.size() >= options_.max_held ||
                             s.held_bytes + arguments.size() > options_.max_backlog_bytes)) {
    s.held_bytes -= s.held.front().arguments.size();
    s.held.pop_front();
    ++s.info.dropped;
  }
  s.held.push_back(Held{now, std::vector<std::byte>(arguments.begin(), arguments.end())});
  s.held_bytes += arguments.size();
  s.info.held = s.held.size();
}

bool FanOut::replay(Subscriber& s, Connection& connection, TimePoint now) {
  while (!s.held.empty()) {
    auto& h = s.held.front();
    if (now - h.at < options_.hold_for) {
      if (!send(s, connection, h.arguments)) return false;
      --s.info.delivered;  // counted as replayed instead
      ++s.info.replayed;
    } else {
      ++s.info.dropped;
    }
    s.held_bytes -= h.arguments.size();
    s.held.pop_front();
    s.info.held = s.held.size();
  }
  return true;
}

// Sends one event to `s` (after its held ones), holding it when the link is down.
FanOut::Outcome FanOut::deliver(Subscriber& s, std::span<const std::byte> arguments, TimePoint now) {
  auto connection = s.link->connection();
  const bool direct = is_direct(*s.link);
  if (!connection || !connection->is_open()) {
    // A direct connection that closed is gone for good (the listener may come back over a new
    // one); a reconnecting link may come back itself.
    hold(s, arguments, now);
    return direct ? Outcome::lapse : Outcome::keep;
  }
  if (connection->queued_bytes() > options_.max_backlog_bytes) {
    if (!s.over_limit) {
      s.over_limit = true;
      s.over_limit_since = now;
    }
    ++s.info.dropped;
    return now - s.over_limit_since < options_.stall_timeout ? Outcome::keep : Outcome::remove;
  }
  s.over_limit = false;
  if (!replay(s, *connection, now) || !send(s, *connection, arguments)) {
    hold(s, arguments, now);
    return direct ? Outcome::lapse : Outcome::keep;
  }
  return Outcome::keep;
}

bool FanOut::send(Subscriber& s, Connection& connection, std::span<const std::byte> arguments) {
  std::vector<std::byte> message;
  message.reserve(16 + s.info.path.size() + method_.size() + arguments.size());
  Writer w(message);
  w.u8(static_cast<std::uint8_t>(RmiCode::notify));
  w.u32(0);
  w.str(s.info.path);
  w.str(method_);
  w.raw(arguments);
  try {
    connection.send(std::move(message), {}, /*in_order=*/true);
    ++s.info.delivered;
  } catch (const Error& e) {
    if (e.kind() == ErrorKind::disconnected) return false;
    ++s.info.dropped;  // too large for the connection, or its queue is full: this event is lost
  }
  return true;
}

std::vector<SubscriberInfo> FanOut::subscribers() const {
  std::lock_guard lock(mutex_);
  std::vector<SubscriberInfo> out;
  out.reserve(subscribers_.size());
  for (const auto& s : subscribers_) {
    if (s.lapsed) continue;
    // One whose connection closed lapses at the next publish or subscribe; it is gone already.
    auto connection = s.link->connection();
    if (is_direct(*s.link) && (!connection || !connection->is_open())) continue;
    out.push_back(s.info);
  }
  return out;
}

std::vector<SubscriberInfo> FanOut::lapsed() const {
  std::lock_guard lock(mutex_);
  std::vector<SubscriberInfo> out;
  for (const auto& s : subscribers_) {
    if (s.lapsed) out.push_back(s.info);
  }
  return out;
}

std::uint64_t FanOut::removed() const {
  std::lock_guard lock(mutex_);
  return removed_;
}

}  // namespace icars::planet::detail
