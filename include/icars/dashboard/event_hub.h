// The live feed of the dashboard: every trace record, numbered, fanned out to each connected
// browser through a queue of its own, and the most recent ones kept for a browser that joins
// late. A slow or stuck browser never slows whoever publishes: its queue is bounded, and what
// does not fit is dropped and counted for that browser (which then reloads its snapshot), as a
// PLANET Publisher drops for a slow subscriber.
//
//   EventHub hub({.queue = 4096, .history = 2000});
//   trace.add_sink([&hub](const TraceRecord& r) { hub.publish(r.to_json()); });
//   auto client = hub.connect();
//   while (auto batch = client->next(15s)) send(*batch);
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
};

// One message to the browsers: a Server-Sent Event's type and its data (one line of JSON).
struct Message {
  std::string event;  // "record", "services"
  std::string data;
};

class EventHub;

// One browser's queue. Thread-safe.
class HubClient {
 public:
  // What is waiting, or — after `wait` with nothing — an empty batch (a keep-alive); nullopt
  // once the client is closed. A batch begins with a "dropped" message when messages were lost.
  std::optional<std::vector<Message>> next(std::chrono::milliseconds wait);
  void close();
  std::uint64_t dropped() const;

 private:
  friend class EventHub;
  explicit HubClient(std::size_t capacity) : capacity_(capacity) {}
  void push(const Message& m);

  const std::size_t capacity_;
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<Message> queue_;
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
  std::vector<std::shared_ptr<HubClient>> clients_;
  std::deque<std::string> history_;
  std::uint64_t total_ = 0;
  std::uint64_t dropped_gone_ = 0;  // drops of clients that left
};

}  // namespace icars::dashboard
