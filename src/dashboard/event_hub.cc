#include "icars/dashboard/event_hub.h"

#include <algorithm>

namespace icars::dashboard {

void HubClient::push(const Message& m) {
  {
    std::lock_guard lock(mutex_);
    if (closed_) return;
    if (queue_.size() >= capacity_) {
      ++dropped_total_;
      ++dropped_unsaid_;
      return;
    }
    queue_.push_back(m);
  }
  changed_.notify_one();
}

std::optional<std::vector<Message>> HubClient::next(std::chrono::milliseconds wait) {
  std::unique_lock lock(mutex_);
  changed_.wait_for(lock, wait, [this] { return closed_ || !queue_.empty() || dropped_unsaid_ > 0; });
  if (closed_) return std::nullopt;
  std::vector<Message> batch;
  if (dropped_unsaid_ > 0) {
    batch.push_back({"dropped", "{\"dropped\":" + std::to_string(dropped_unsaid_) + "}"});
    dropped_unsaid_ = 0;
  }
  batch.insert(batch.end(), std::make_move_iterator(queue_.begin()), std::make_move_iterator(queue_.end()));
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
  std::vector<std::shared_ptr<HubClient>> clients;
  Message m{"record", {}};
  {
    std::lock_guard lock(mutex_);
    const auto index = total_++;
    // {"t":... → {"index":N,"t":...}
    m.data = record_json.size() >= 2 && record_json.front() == '{'
                 ? "{\"index\":" + std::to_string(index) + (record_json.size() > 2 ? "," : "") + record_json.substr(1)
                 : record_json;
    history_.push_back(m.data);
    while (history_.size() > options_.history) history_.pop_front();
    clients = clients_;
  }
  for (const auto& c : clients) c->push(m);
}

void EventHub::broadcast(Message message) {
  std::vector<std::shared_ptr<HubClient>> clients;
  {
    std::lock_guard lock(mutex_);
    clients = clients_;
  }
  for (const auto& c : clients) c->push(message);
}

std::shared_ptr<HubClient> EventHub::connect() {
  std::lock_guard lock(mutex_);
  if (clients_.size() >= options_.max_clients) return nullptr;
  auto c = std::shared_ptr<HubClient>(new HubClient(options_.queue));
  clients_.push_back(c);
  return c;
}

void EventHub::disconnect(const std::shared_ptr<HubClient>& client) {
  if (!client) return;
  client->close();
  std::lock_guard lock(mutex_);
  const auto it = std::find(clients_.begin(), clients_.end(), client);
  if (it == clients_.end()) return;
  dropped_gone_ += client->dropped();
  clients_.erase(it);
}

std::size_t EventHub::clients() const {
  std::lock_guard lock(mutex_);
  return clients_.size();
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
  for (const auto& c : clients_) n += c->dropped();
  return n;
}

void EventHub::close_all() {
  std::vector<std::shared_ptr<HubClient>> clients;
  {
    std::lock_guard lock(mutex_);
    clients.swap(clients_);
  }
  for (const auto& c : clients) {
    c->close();
    std::lock_guard lock(mutex_);
    dropped_gone_ += c->dropped();
  }
}

}  // namespace icars::dashboard
