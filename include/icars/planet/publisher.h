// PLANET publish/subscribe: fanning events out to remote listeners over NOTIFY.
//
// A publisher (a sensor's capability, a service) keeps the listeners that subscribed to it —
// each a remote object reached through a Proxy, usually the stub a servant received as the
// argument of its `subscribe` operation — and sends every published event to all of them as a
// one-way call of the listener's callback operation:
//
//   planet::Publisher<SoundEvent> sounds(SoundListener::on_sound);
//   sounds.subscribe(listener_prx);      // inside the servant's subscribe(listener, current)
//   sounds.publish(SoundEvent{...});     // never blocks
//
// A slow or dead subscriber never stalls the others. Policy: each subscriber may have at most
// `max_backlog_bytes` accepted by its connection and not yet written to the socket; while it is
// over that limit, events for it are dropped (and counted), the others still get every event.
// A subscriber that has been over the limit for `stall_timeout` is unsubscribed.
//
// A subscriber whose connection closed lapses: it is unsubscribed, but for `hold_for` the
// publisher keeps the events published meanwhile for it (at most `max_held` events and
// `max_backlog_bytes` bytes; past that the oldest go). When the same listener subscribes again
// in that time — the same path, from the endpoint with the same name (PUN) and principal, as a
// server does when its link to this process comes back — it first gets the held events, in
// order, then the new ones. So an event published while the link was down (a voice command
// while a device manager was stopped, say) is not lost; one already written to the socket when
// the link broke is not sent again (delivery is at most once per event). A subscriber reached
// through a reconnecting link holds its events the same way while the link is down and gets
// them with the next event after it is back. Delivery is in publish order per subscriber.
#pragma once

#include <chrono>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "icars/planet/proxy.h"

namespace icars::planet {

struct PublisherOptions {
  std::size_t max_backlog_bytes = 1u << 20;        // per subscriber: unwritten bytes before drops
  std::chrono::milliseconds stall_timeout{10000};  // over the backlog this long: unsubscribed
  std::size_t max_subscribers = 1024;  // more subscribe() calls fail with Error(overloaded)
  // A lapsed subscriber's events are kept this long for its return (zero: not at all).
  std::chrono::milliseconds hold_for{60000};
  std::size_t max_held = 256;  // events kept per lapsed subscriber; beyond it the oldest go
};

struct SubscriberInfo {
  std::uint64_t id = 0;
  std::string link;  // describes the subscriber's link
  std::string path;
  std::uint64_t delivered = 0;
  std::uint64_t dropped = 0;
  std::size_t held = 0;        // events kept for it while its link is down
  std::uint64_t replayed = 0;  // held events delivered after its link came back
};

namespace detail {

// The type-independent part of a Publisher. Thread-safe.
class FanOut {
 public:
  FanOut(std::string method, PublisherOptions options) : method_(std::move(method)),
                                                           options_(options) {}
  std::uint64_t subscribe(std::shared_ptr<Link> link, std::string path);
  bool unsubscribe(std::uint64_t id);
  bool unsubscribe(const Link& link, const std::string& path);
  // `arguments` is the argument count byte followed by the tagged arguments.
  std::size_t publish(std::span<const std::byte> arguments);
  std::vector<SubscriberInfo> subscribers() const;  // the subscribed ones
  std::vector<SubscriberInfo> lapsed() const;       // lapsed ones still holding events
  std::uint64_t removed() const;  // subscribers dropped by the policy (or lapsed) so far

 private:
  using TimePoint = std::chrono::steady_clock::time_point;
  struct Held {
    TimePoint at;
    std::vector<std::byte> arguments;
  };
  struct Subscriber {
    SubscriberInfo info;
    std::shared_ptr<Link> link;
    std::string listener;  // the listener's identity: principal, peer's PUN and path
    TimePoint over_limit_since{};
    bool over_limit = false;
    bool lapsed = false;
    TimePoint lapsed_since{};
    std::deque<Held> held;
    std::size_t held_bytes = 0;
  };
  enum class Outcome { keep, remove, lapse };
  Outcome deliver(Subscriber& s, std::span<const std::byte> arguments, TimePoint now);
  // Sends one event to `s` over `connection`; false when the connection is gone.
  bool send(Subscriber& s, Connection& connection, std::span<const std::byte> arguments);
  void hold(Subscriber& s, std::span<const std::byte> arguments, TimePoint now);
  // Sends `s`'s held events not older than hold_for; false when the connection went meanwhile.
  bool replay(Subscriber& s, Connection& connection, TimePoint now);
  void lapse(Subscriber& s, TimePoint now);
  // Lapses subscribers whose direct connection closed and forgets lapsed ones past hold_for.
  void sweep(TimePoint now);

  std::string method_;
  PublisherOptions options_;
  mutable std::mutex mutex_;
  std::vector<Subscriber> subscribers_;
  std::uint64_t next_id_ = 1;
  std::uint64_t removed_ = 0;
};

}  // namespace detail

template <class... A>
class Publisher {
 public:
  Publisher(const OneWay<A...>& callback, PublisherOptions options = {})
      : fanout_(std::string(callback.name()), options) {}

  // Adds the listener `listener` names; returns its subscription id. Throws Error(overloaded)
  // when `max_subscribers` are subscribed already (a servant's subscribe operation then fails
  // with that error at the caller).
  std::uint64_t subscribe(const Proxy& listener) {
    if (!listener.bound()) throw Error(ErrorKind::failed, "cannot subscribe an unbound proxy");
    return fanout_.subscribe(listener.link(), listener.path());
  }
  bool unsubscribe(std::uint64_t id) { return fanout_.unsubscribe(id); }
  bool unsubscribe(const Proxy& listener) {
    return listener.bound() && fanout_.unsubscribe(*listener.link(), listener.path());
  }

  // Sends the event to every subscriber; returns how many it was queued for. Never blocks.
  std::size_t publish(const std::type_identity_t<A>&... args) {
    std::vector<std::byte> arguments;
    Writer w(arguments);
    w.u8(static_cast<std::uint8_t>(sizeof...(A)));
    (encode_tagged(w, args), ...);
    return fanout_.publish(arguments);
  }

  std::vector<SubscriberInfo> subscribers() const { return fanout_.subscribers(); }
  std::vector<SubscriberInfo> lapsed() const { return fanout_.lapsed(); }
  std::size_t size() const { return fanout_.subscribers().size(); }
  std::uint64_t removed() const { return fanout_.removed(); }

 private:
  detail::FanOut fanout_;
};

}  // namespace icars::planet
