// ICARS Service Framework (SF): services adapted from device capabilities (ICARS paper 3.3,
// 4.3.1, Fig. 10).
//
// A Service is what behaviors use: an adaptor that wraps one capability's remote reference
// (TVControl, SoundSensor...), or an adaptive service composed from others (SpeechSensor =
// SoundSensor + SpeechRecognizer). Every service has a type, an id and attributes (room, device,
// robot) for discovery in the ServiceContainer, and an availability that follows its devices:
// when a device disconnects its services become unavailable and their watchers are told; when
// it registers again they come back.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace icars::service {

struct ServiceAttributes {
  std::string device;      // the device it adapts ("" for composites of several)
  std::string capability;  // the capability it adapts
  std::string room;        // where its device stands; "" when carried by a robot
  std::string carrier;     // the robot carrying its device, or ""
};

// A list of callbacks. `notify` calls them outside the list's lock, so a callback may add or
// remove others; `remove` waits for a call of that callback running on another thread, so once
// it returns the callback is never running (removing itself from inside is allowed).
template <class... A>
class Listeners {
 public:
  std::uint64_t add(std::function<void(const A&...)> fn) {
    std::lock_guard lock(mutex_);
    entries_.emplace(next_, std::make_shared<Entry>(std::move(fn)));
    return next_++;
  }
  bool remove(std::uint64_t id) {
    std::shared_ptr<Entry> entry;
    {
      std::lock_guard lock(mutex_);
      auto it = entries_.find(id);
      if (it == entries_.end()) return false;
      entry = std::move(it->second);
      entries_.erase(it);
    }
    std::lock_guard calling(entry->calling);  // recursive: a callback may remove itself
    entry->removed = true;
    return true;
  }
  void notify(const A&... args) const {
    std::vector<std::shared_ptr<Entry>> copy;
    {
      std::lock_guard lock(mutex_);
      for (const auto& [id, entry] : entries_) copy.push_back(entry);
    }
    for (const auto& entry : copy) {
      std::lock_guard calling(entry->calling);
      if (!entry->removed) entry->fn(args...);
    }
  }
  std::size_t size() const {
    std::lock_guard lock(mutex_);
    return entries_.size();
  }

 private:
  struct Entry {
    explicit Entry(std::function<void(const A&...)> f) : fn(std::move(f)) {}
    std::function<void(const A&...)> fn;
    std::recursive_mutex calling;
    bool removed = false;
  };
  mutable std::mutex mutex_;
  std::map<std::uint64_t, std::shared_ptr<Entry>> entries_;
  std::uint64_t next_ = 1;
};

// Services are owned by shared_ptr (the container holds them); asynchronous work a service
// starts holds only a weak reference, so a service may go away with calls in flight.
class Service : public std::enable_shared_from_this<Service> {
 public:
  Service(std::string id, std::string type, ServiceAttributes attributes);
  virtual ~Service() = default;
  Service(const Service&) = delete;
  Service& operator=(const Service&) = delete;

  const std::string& id() const { return id_; }
  const std::string& type() const { return type_; }
  const ServiceAttributes& attributes() const { return attributes_; }

  bool available() const;
  // `fn(available)` runs on every change of availability. Returns an id for remove_watcher.
  std::uint64_t watch(std::function<void(const bool&)> fn) { return watchers_.add(std::move(fn)); }
  void remove_watcher(std::uint64_t id) { watchers_.remove(id); }

 protected:
  void set_available(bool available);

 private:
  std::string id_;
  std::string type_;
  ServiceAttributes attributes_;
  mutable std::mutex mutex_;
  bool available_ = false;
  Listeners<bool> watchers_;
};

}  // namespace icars::service
