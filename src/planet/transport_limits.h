// What the connections of one ConnectionManager share so that many connections together stay
// within bounds: the receive budget across all of them (total_receive_budget) and rate limits for
// the log lines a flood would otherwise repeat without end. Private to the transport.
#pragma once

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

namespace icars::planet::detail {

// At most one line per key (a remote address) per interval; the lines held back in between are
// counted and reported with the next line for that key. Thread-safe.
class LogRateLimiter {
 public:
  explicit LogRateLimiter(std::chrono::milliseconds interval = std::chrono::seconds(1))
      : interval_(interval) {}

  // nullopt: hold this line back. Otherwise log it, with the number of lines held back since
  // the last one for `key`.
  std::optional<std::uint64_t> admit(const std::string& key) {
    const auto now = std::chrono::steady_clock::now();
    std::lock_guard lock(mutex_);
    if (entries_.size() >= kMaxKeys && !entries_.contains(key)) {
      std::erase_if(entries_, [&](const auto& e) {
        return e.second.held == 0 && now - e.second.last >= interval_;
      });
    }
    // A flood from more addresses than kMaxKeys shares one key rather than growing the table.
    const std::string& k = entries_.size() >= kMaxKeys && !entries_.contains(key) ? kOthers : key;
    auto [it, fresh] = entries_.try_emplace(k);
    Entry& e = it->second;
    if (!fresh && now - e.last < interval_) {
      ++e.held;
      return std::nullopt;
    }
    e.last = now;
    return std::exchange(e.held, 0);
  }

 private:
  static constexpr std::size_t kMaxKeys = 4096;
  inline static const std::string kOthers = "(other addresses)";
  struct Entry {
    std::chrono::steady_clock::time_point last;
    std::uint64_t held = 0;
  };
  std::chrono::milliseconds interval_;
  std::mutex mutex_;
  std::unordered_map<std::string, Entry> entries_;
};

// Bytes the receivers of all connections may have to hold for incomplete incoming messages:
// what arrived plus the flow-control credit granted and not yet used. A message is only started,
// and credit only granted, within the limit, except for one message at a time (the privileged
// one) that may exceed it, so that some message always completes and the others then proceed.
// Thread-safe.
class ReceiveBudget {
 public:
  // `wake_room`: the room a waiting connection needs (one ack's credit); less wakes nobody.
  ReceiveBudget(std::size_t limit, std::size_t wake_room) : limit_(limit), wake_room_(wake_room) {}

  std::size_t limit() const { return limit_; }
  std::size_t reserved() const { return reserved_.load(); }
  bool fits(std::size_t more) const { return reserved_.load() + more <= limit_; }

  // Changes the reservation by `delta`; a decrease wakes the connections waiting for room.
  void add(std::size_t more) { reserved_ += more; }
  void remove(std::size_t less) {
    reserved_ -= less;
    if (less > 0 && fits(wake_room_)) wake();
  }

  // True if message `msg_no` of connection `connection` is (now) the privileged one.
  bool claim(std::uint64_t connection, std::uint32_t msg_no) {
    std::lock_guard lock(mutex_);
    if (!holder_) holder_ = {connection, msg_no};
    return *holder_ == std::pair{connection, msg_no};
  }
  bool is_privileged(std::uint64_t connection, std::uint32_t msg_no) const {
    std::lock_guard lock(mutex_);
    return holder_ && *holder_ == std::pair{connection, msg_no};
  }
  // The message completed, was refused or its connection closed.
  void release(std::uint64_t connection, std::uint32_t msg_no) {
    {
      std::lock_guard lock(mutex_);
      if (!holder_ || *holder_ != std::pair{connection, msg_no}) return;
      holder_.reset();
    }
    wake();
  }

  // Runs `resume` once (on the caller's thread of the next release) when room may have appeared.
  void wait(std::function<void()> resume) {
    std::lock_guard lock(mutex_);
    waiting_.push_back(std::move(resume));
  }

 private:
  void wake() {
    std::vector<std::function<void()>> waiting;
    {
      std::lock_guard lock(mutex_);
      if (waiting_.empty()) return;
      waiting.swap(waiting_);
    }
    for (auto& w : waiting) w();
  }

  const std::size_t limit_;
  const std::size_t wake_room_;
  std::atomic<std::size_t> reserved_{0};
  mutable std::mutex mutex_;
  std::optional<std::pair<std::uint64_t, std::uint32_t>> holder_;
  std::vector<std::function<void()>> waiting_;
};

struct TransportLimits {
  TransportLimits(std::size_t total_receive_budget, std::size_t wake_room)
      : receive(total_receive_budget, wake_room) {}
  ReceiveBudget receive;
  LogRateLimiter denials;       // CONNECT_ACK 0xFF, per remote address
  LogRateLimiter tls_failures;  // failed TLS handshakes, per remote address
  LogRateLimiter refusals;      // messages refused for the receive budget, per remote address
};

}  // namespace icars::planet::detail
