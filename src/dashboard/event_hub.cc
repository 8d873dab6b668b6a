#include "icars/dashboard/event_hub.h"

#include <algorithm>
#include <chrono>
#include <utility>

namespace icars::dashboard {

std::string server_sent_event(const Message& m) { return "event: " + m.event + "\ndata: " + m.data + "\n\n"; }

void HubClient::push(const std::shared_ptr<const std::string>& event) {
  bool first = false;
  {
    std::lock_guard lock(mutex_);
    if (closed_) return;
    if (queue_.size() >= capacity_) {
      ++dropped_total_;
      ++dropped_unsaid_;
      return;
    }
    first = queue_.empty();
    queue_.push_back(event);
  }
  // Only the first of a batch wakes the page's thread; the rest join the batch it gathers.
  if (first) changed_.notify_one();
}

std::optional<std::string> HubClient::next(std::chrono::milliseconds wait) {
  std::unique_lock lock(mutex_);
  changed_.wait_for(lock, wait, [this] { return closed_ || !queue_.empty() || dropped_unsaid_ > 0; });
  if (!closed_ && linger_ > std::chrono::milliseconds::zero() && !queue_.empty()) {
    changed_.wait_for(lock, linger_, [this] { return closed_; });
  }
  if (closed_) return std::nullopt;
  std::string batch;
  if (dropped_unsaid_ > 0) {
    batch = server_sent_event({"dropped", "{\"dropped\":" + std::to_string(dropped_unsaid_) + "}"});
    dropped_unsaid_ = 0;
  }
  std::size_t size = batch.size();
  for (const auto& e : queue_) size += e->size();
  batch.reserve(size);
  for (const auto& e : queue_) batch += *e;
  queue_.clear();
  return batch;
}

void HubClient::close() {
  {
    std::lock_guard lock(mutex_);
    closed_ = true;
    queue_.clear();
  }
  changed_.notify_all();
}

std::uint64_t HubClient::dropped() const {
  std::lock_guard lock(mutex_);
  return dropped_total_;
}

EventHub::EventHub(EventHubOptions options) : options_(options) {}

void EventHub::publish_record(const std::string& record_json) {
  std::shared_ptr<const Clients> clients;
  std::shared_ptr<const std::string> event;
  {
    std::lock_guard lock(mutex_);
    const auto index = total_++;
    // {"t":... → {"index":N,"t":...}
    auto data = record_json.size() >= 2 && record_json.front() == '{'
                    ? "{\"index\":" + std::to_string(index) + (record_json.size() > 2 ? "," : "") + record_json.substr(1)
                    : record_json;
    if (!clients_->empty()) {
      event = std::make_shared<const std::string>(server_sent_event({"record", data}));
      clients = clients_;
    }
    history_.push_back(std::move(data));
    while (history_.size() > options_.history) history_.pop_front();
  }
  if (!clients) return;
  for (const auto& c : *clients) c->push(event);
}

void EventHub::broadcast(Message message) {
  std::shared_ptr<const Clients> clients;
  {
    std::lock_guard lock(mutex_);
    clients = clients_;
  }
  const auto event = std::make_shared<const std::string>(server_sent_event(message));
  for (const auto& c : *clients) c->push(event);
}

std::shared_ptr<HubClient> EventHub::connect() {
  std::lock_guard lock(mutex_);
  if (clients_->size() >= options_.max_clients) return nullptr;
  auto c = std::shared_ptr<HubClient>(new HubClient(options_.queue, options_.linger));
  auto next = std::make_shared<Clients>(*clients_);
  next->push_back(c);
  clients_ = std::move(next);
  return c;
}

void EventHub::disconnect(const std::shared_ptr<HubClient>& client) {
  if (!client) return;
  client->close();
  std::lock_guard lock(mutex_);
  const auto it = std::find(clients_->begin(), clients_->end(), client);
  if (it == clients_->end()) return;
  dropped_gone_ += client->dropped();
  auto next = std::make_shared<Clients>(*clients_);
  next->erase(next->begin() + (it - clients_->begin()));
  clients_ = std::move(next);
}

std::size_t EventHub::clients() const {
  std::lock_guard lock(mutex_);
  return clients_->size();
}

EventHub::History EventHub::history() const {
  std::lock_guard lock(mutex_);
  History h;
  h.records.assign(history_.begin(), history_.end());
  h.total = total_;
  h.first_index = total_ - history_.size();
  return h;
}

std::uint64_t EventHub::dropped() const {
  std::lock_guard lock(mutex_);
  std::uint64_t n = dropped_gone_;
  for (const auto& c : *clients_) n += c->dropped();
  return n;
}

void EventHub::close_all() {
  std::shared_ptr<const Clients> clients;
  {
    std::lock_guard lock(mutex_);
    clients = std::exchange(clients_, std::make_shared<const Clients>());
  }
  for (const auto& c : *clients) {
    c->close();
    std::lock_guard lock(mutex_);
    dropped_gone_ += c->dropped();
  }
}

}  // namespace icars::dashboard
