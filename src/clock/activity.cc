#include "icars/clock/activity.h"

#include <vector>

namespace icars {

// --- Hold ------------------------------------------------------------------------------------

Activity::Hold::Hold(Activity* activity) : activity_(activity) {
  if (activity_) activity_->begin();
}

Activity::Hold& Activity::Hold::operator=(Hold&& other) noexcept {
  if (this != &other) {
    release();
    activity_ = std::exchange(other.activity_, nullptr);
  }
  return *this;
}

void Activity::Hold::release() {
  if (auto* a = std::exchange(activity_, nullptr)) a->end();
}

// --- Link ------------------------------------------------------------------------------------

// The link's lock is never held while the activity's is taken (join() takes them the other way
// round): counts change under the link's lock, the activity hears of them after.
void Activity::Link::sent(int from_side) {
  const auto activity = activity_.lock();
  if (!activity) return;
  {
    std::lock_guard lock(mutex_);
    if (closed_ || !joined_[0] || !joined_[1]) return;
  }
  // Begun before it is counted in flight (and before the message is queued, so before its
  // receiver can handle it): a close() on another thread ends what it finds in flight, and an
  // end that came before its begin would be lost, leaving the activity busy for ever.
  activity->begin();
  {
    std::lock_guard lock(mutex_);
    if (!closed_) {
      ++in_flight_[1 - from_side];
      return;
    }
  }
  activity->end();  // closed meanwhile: never to be handled
}

void Activity::Link::handled(int at_side) {
  const auto activity = activity_.lock();
  if (!activity) return;
  {
    std::lock_guard lock(mutex_);
    if (closed_ || in_flight_[at_side] == 0) return;
    --in_flight_[at_side];
  }
  activity->end();
}

void Activity::Link::close() {
  const auto activity = activity_.lock();
  std::size_t lost = 0;
  {
    std::lock_guard lock(mutex_);
    if (closed_) return;
    closed_ = true;
    lost = in_flight_[0] + in_flight_[1];
    in_flight_[0] = in_flight_[1] = 0;
  }
  if (!activity) return;
  for (; lost > 0; --lost) activity->end();  // never to be handled
  activity->unjoin(key_, this);
}

bool Activity::Link::joined() const {
  std::lock_guard lock(mutex_);
  return !closed_ && joined_[0] && joined_[1];
}

// --- Activity --------------------------------------------------------------------------------

void Activity::begin() {
  std::lock_guard lock(mutex_);
  ++busy_;
  ++generation_;
}

void Activity::end() {
  std::lock_guard lock(mutex_);
  if (busy_ > 0 && --busy_ == 0) changed_.notify_all();
}

std::size_t Activity::busy() const {
  std::lock_guard lock(mutex_);
  return busy_;
}

std::uint64_t Activity::generation() const {
  std::lock_guard lock(mutex_);
  return generation_;
}

Activity::LinkEnd Activity::join(const std::string& local, const std::string& remote) {
  const bool first = local < remote;
  const auto key = first ? local + "|" + remote : remote + "|" + local;
  const int side = first ? 0 : 1;
  std::lock_guard lock(mutex_);
  if (const auto it = half_joined_.find(key); it != half_joined_.end()) {
    if (auto link = it->second.lock()) {
      std::lock_guard link_lock(link->mutex_);
      if (!link->closed_ && !link->joined_[side]) {
        link->joined_[side] = true;
        half_joined_.erase(it);
        return {link, side};
      }
    }
    half_joined_.erase(it);  // an end that closed, or another connection's leftover
  }
  auto link = std::shared_ptr<Link>(new Link(weak_from_this()));
  link->joined_[side] = true;
  link->key_ = key;
  half_joined_.emplace(key, link);
  return {link, side};
}

void Activity::unjoin(const std::string& key, const Link* link) {
  std::lock_guard lock(mutex_);
  const auto it = half_joined_.find(key);
  if (it == half_joined_.end()) return;
  const auto held = it->second.lock();
  if (!held || held.get() == link) half_joined_.erase(it);
}

std::uint64_t Activity::add_queue(Post post) {
  std::lock_guard lock(mutex_);
  const auto id = next_queue_++;
  queues_.emplace(id, std::move(post));
  return id;
}

void Activity::remove_queue(std::uint64_t id) {
  std::lock_guard lock(mutex_);
  queues_.erase(id);
  if (owed_.erase(id) > 0) changed_.notify_all();
}

bool Activity::settle(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::unique_lock lock(mutex_);
  int quiet_rounds = 0;
  for (;;) {
    if (!changed_.wait_until(lock, deadline, [this] { return busy_ == 0; })) return false;
    // Nothing began since the last time everything was found settled: nothing can be queued.
    if (generation_ == settled_generation_) return true;
    const auto generation = generation_;
    // A round of markers: each queue runs what was posted to it before its marker.
    const auto round = ++round_;
    owed_.clear();
    std::vector<std::pair<std::uint64_t, Post>> posts(queues_.begin(), queues_.end());
    for (const auto& [id, post] : posts) owed_.emplace(id, true);
    lock.unlock();
    for (const auto& [id, post] : posts) {
      post([weak = weak_from_this(), id = id, round] {
        const auto self = weak.lock();
        if (!self) return;
        std::lock_guard marker_lock(self->mutex_);
        if (self->round_ == round && self->owed_.erase(id) > 0 && self->owed_.empty()) {
          self->changed_.notify_all();
        }
      });
    }
    lock.lock();
    if (!changed_.wait_until(lock, deadline, [this] { return owed_.empty(); })) return false;
    // Two rounds in a row in which nothing began: what a marker's predecessors posted behind
    // it has run too.
    if (busy_ == 0 && generation_ == generation) {
      if (++quiet_rounds >= 2) {
        settled_generation_ = generation;
        return true;
      }
    } else {
      quiet_rounds = 0;
    }
  }
}

}  // namespace icars
