// The live feed of the dashboard: every trace record, numbered, fanned out to each connected
// browser through a queue of its own, and the most recent ones kept for a browser that joins
// late. A slow or stuck browser never slows whoever publishes: its queue is bounded, and what
// does not fit is dropped and counted for that browser (which then reloads its snapshot), as a
// PLANET Publisher drops for a slow subscriber.
//
//   EventHub hub({.queue = 4096, .history = 2000});
//   trace.add_sink([&hub](const TraceRecord& r) { hub.publish_record(r.to_json()); });
//   auto client = hub.connect();
//   while (auto batch = client->next(15s)) send(*batch);   // Server-Sent Events, ready to write
//
// A message is formatted once, as the Server-Sent Event every page gets, and shared by the
// pages' queues: each page costs the publisher a pointer in a queue, not a copy.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

namespace icars::dashboard {

struct EventHubOptions {
  std::size_t queue = 4096;    // messages a browser may be behind before they are dropped
  std::size_t history = 2000;  // records kept for a snapshot
  std::size_t max_clients = 64;
  // After a page's first waiting message, how long more are gathered before they go out in one
  // batch: fewer wake-ups and writes for a busy trace, at most this much later (a page draws at
  // most every 16 ms anyway).
  std::chrono::milliseconds linger{5};
};

// One message to the browsers: a Server-Sent Event's type and its data (one line of JSON).
struct Message {
  std::string event;  // "record", "services"
  std::string data;
};
// "event: <event>\ndata: <data>\n\n".
std::string server_sent_event(const Message& m);

class EventHub;

// One browser's queue. Thread-safe.
class HubClient {
 public:
  // What is waiting, as Server-Sent Events ready to write (gathered for up to the hub's
  // `linger` after the first), or — after `wait` with nothing — "" (time for a keep-alive);
  // nullopt once the client is closed. A batch begins with a "dropped" event ({"dropped":N})
  // when messages were lost.
  std::optional<std::string> next(std::chrono::milliseconds wait);
  void close();
  std::uint64_t dropped() const;

 private:
  friend class EventHub;
  HubClient(std::size_t capacity, std::chrono::milliseconds linger) : capacity_(capacity), linger_(linger) {}
  void push(const std::shared_ptr<const std::string>& event);

  const std::size_t capacity_;
  const std::chrono::milliseconds linger_;
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<std::shared_ptr<const std::string>> queue_;
  std::uint64_t dropped_total_ = 0;
  std::uint64_t dropped_unsaid_ = 0;  // dropped since the last batch told it
  bool closed_ = false;
};

class EventHub {
 public:
  explicit EventHub(EventHubOptions options = {});

  // Numbers a trace record (a JSON object: `"index":N` is added), keeps it for snapshots and
  // queues it for every browser. Never blocks on a browser.
  void publish_record(const std::string& record_json);
  // Any other message, to every browser (not kept).
  void broadcast(Message message);

  // A new browser's queue (nullptr when max_clients are connected); it gets what is published
  // from now on. disconnect() (or close()) ends it.
  std::shared_ptr<HubClient> connect();
  void disconnect(const std::shared_ptr<HubClient>& client);
  std::size_t clients() const;

  struct History {
    std::vector<std::string> records;  // the most recent, oldest first, each with its index
    std::uint64_t first_index = 0;
    std::uint64_t total = 0;           // records published so far
  };
  History history() const;
  std::uint64_t dropped() const;  // messages dropped for slow browsers, in all

  // Closes every browser's queue (their streams end).
  void close_all();

 private:
  EventHubOptions options_;
  mutable std::mutex mutex_;
  using Clients = std::vector<std::shared_ptr<HubClient>>;
  // Replaced, never changed: a publisher takes the current list without copying it.
  std::shared_ptr<const Clients> clients_ = std::make_shared<const Clients>();
  std::deque<std::string> history_;
  std::uint64_t total_ = 0;
  std::uint64_t dropped_gone_ = 0;  // drops of clients that left
};

}  // namespace icars::dashboard
