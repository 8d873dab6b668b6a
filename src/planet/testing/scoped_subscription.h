// A test's subscription to a service's events (or watch of its availability) that ends with its
// scope: a callback that captures the test's locals by reference never runs after they are gone
// (unsubscribe and remove_watcher wait for a call in progress). Declare it after what the
// callback uses, and after the pointer that keeps the service alive.
//
//   std::atomic<int> heard{0};
//   const auto subscription = planet_test::subscribe_scoped(*speech, [&](const SpeechEvent&) { ++heard; });
//   const auto watch = planet_test::watch_scoped(*tv, [&](const bool& up) { ... });
//   const auto devices = planet_test::watch_devices_scoped(container, [&](const Event& e) { ... });
#pragma once

#include <cstdint>
#include <utility>

namespace planet_test {

template <class Source>
class ScopedSubscription {
 public:
  using End = void (Source::*)(std::uint64_t);
  ScopedSubscription(Source& source, std::uint64_t id, End end) : source_(&source), id_(id), end_(end) {}
  ~ScopedSubscription() {
    if (source_) (source_->*end_)(id_);
  }
  ScopedSubscription(ScopedSubscription&& other) noexcept
      : source_(std::exchange(other.source_, nullptr)), id_(other.id_), end_(other.end_) {}
  ScopedSubscription(const ScopedSubscription&) = delete;
  ScopedSubscription& operator=(const ScopedSubscription&) = delete;
  ScopedSubscription& operator=(ScopedSubscription&&) = delete;

 private:
  Source* source_;
  std::uint64_t id_;
  End end_;
};

template <class Source, class Fn>
[[nodiscard]] ScopedSubscription<Source> subscribe_scoped(Source& source, Fn&& fn) {
  return ScopedSubscription<Source>(source, source.subscribe(std::forward<Fn>(fn)), &Source::unsubscribe);
}

template <class Source, class Fn>
[[nodiscard]] ScopedSubscription<Source> watch_scoped(Source& source, Fn&& fn) {
  return ScopedSubscription<Source>(source, source.watch(std::forward<Fn>(fn)), &Source::remove_watcher);
}

// A watch of a service container's device events (DeviceLost, DeviceBack...): they arrive on
// the server's io thread, possibly after the test body has returned, while the servers that
// send them are still being torn down.
template <class Container, class Fn>
[[nodiscard]] ScopedSubscription<Container> watch_devices_scoped(Container& container, Fn&& fn) {
  return ScopedSubscription<Container>(container, container.watch_devices(std::forward<Fn>(fn)),
                                       &Container::remove_device_watcher);
}

}  // namespace planet_test
