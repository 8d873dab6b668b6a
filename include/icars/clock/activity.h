// Work in progress in one process, so that a simulated clock can wait for it (lock-step).
//
// A simulated house run in lock-step advances its clock only when the mediating server, the
// behaviors and the devices have finished reacting to what the last event started: then the
// reaction to "stop the music" comes at the simulated instant of the command at any speed, and
// a run is the same trace at 600x and as fast as the machine goes (LockStepDriver,
// icars/clock/lock_step.h). An Activity is what they report their work to:
//
//  - a piece of work that another thread will do holds the activity while it waits and runs
//    (`hold()` when posting it, released when it has run): the behavior runtime's handlers, the
//    completions of remote calls;
//  - a message between two endpoints of this process is counted from the moment it is sent
//    until the receiver has handled it (`join()` by both ends of a connection, `Link::sent` /
//    `Link::handled`); messages to other processes are not counted;
//  - every queue that runs work posted to it in order (a communicator's io thread) is flushed
//    by settle(): what was posted there before settle() looked has run.
//
// Work that waits for the clock (a timer, a robot's arrival) holds nothing: the clock has to
// move for it. Thread-safe.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <utility>

namespace icars {

class Activity : public std::enable_shared_from_this<Activity> {
 public:
  // Held work: released (once) on destruction or release(). An empty Hold holds nothing.
  class Hold {
   public:
    Hold() = default;
    explicit Hold(Activity* activity);  // null: an empty Hold
    ~Hold() { release(); }
    Hold(Hold&& other) noexcept : activity_(std::exchange(other.activity_, nullptr)) {}
    Hold& operator=(Hold&& other) noexcept;
    Hold(const Hold&) = delete;
    Hold& operator=(const Hold&) = delete;
    void release();
    explicit operator bool() const { return activity_ != nullptr; }

   private:
    Activity* activity_ = nullptr;
  };

  // One connection between two endpoints of this process, seen from both ends. Its messages
  // are counted only once both ends have joined, and no longer once either has closed (then
  // what was in flight is released: it will never be handled).
  class Link {
   public:
    void sent(int from_side);   // a message leaves `from_side` for the other end
    void handled(int at_side);  // a message `at_side` received has been handled (or refused)
    void close();               // either end; idempotent
    bool joined() const;        // both ends joined and neither closed

   private:
    friend class Activity;
    explicit Link(std::weak_ptr<Activity> activity) : activity_(std::move(activity)) {}
    std::weak_ptr<Activity> activity_;
    mutable std::mutex mutex_;
    bool joined_[2] = {false, false};
    bool closed_ = false;
    std::size_t in_flight_[2] = {0, 0};  // messages on their way to side i
    std::string key_;
  };
  // One end of a Link: the link and the side this end is.
  struct LinkEnd {
    std::shared_ptr<Link> link;
    int side = 0;
    void sent() const { if (link) link->sent(side); }
    void handled() const { if (link) link->handled(side); }
    void close() const { if (link) link->close(); }
  };

  // Activities are shared: links keep a weak reference to theirs.
  static std::shared_ptr<Activity> create() { return std::shared_ptr<Activity>(new Activity()); }
  Activity(const Activity&) = delete;
  Activity& operator=(const Activity&) = delete;

  void begin();
  void end();
  Hold hold() { return Hold(this); }
  std::size_t busy() const;
  // How many pieces of work have begun since the start: changes whenever anything begins.
  std::uint64_t generation() const;

  // The end of the connection between `local` and `remote` (each "<ip>:<port>"): the same Link
  // for the two ends of one TCP connection of this process. Call once per end, when the
  // connection is made, before any message is sent over it.
  LinkEnd join(const std::string& local, const std::string& remote);

  // A queue that runs work posted to it in order: `post(marker)` must run `marker` after
  // everything posted to the queue before (or never, once the queue is removed). Returns an id
  // for remove_queue.
  using Post = std::function<void(std::function<void()> marker)>;
  std::uint64_t add_queue(Post post);
  void remove_queue(std::uint64_t id);  // a marker it still owes counts as run

  // Waits until nothing is busy and every queue has run what was posted to it before, twice in
  // a row with nothing begun in between. True when settled; false after `timeout` (something
  // is stuck: a blocked thread, a message to a peer that never answers).
  bool settle(std::chrono::milliseconds timeout);

 private:
  Activity() = default;
  void unjoin(const std::string& key, const Link* link);

  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::size_t busy_ = 0;
  std::uint64_t generation_ = 0;
  std::uint64_t settled_generation_ = ~std::uint64_t{0};  // the generation last found settled
  std::map<std::uint64_t, Post> queues_;
  std::uint64_t next_queue_ = 1;
  // The markers of the current flush round still owed, by queue id.
  std::map<std::uint64_t, bool> owed_;
  std::uint64_t round_ = 0;
  std::map<std::string, std::weak_ptr<Link>> half_joined_;  // links only one end joined yet
};

}  // namespace icars
