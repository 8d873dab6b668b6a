#include "icars/clock/driver_thread.h"

namespace icars::detail {

bool DriverThread::start(std::function<void()> loop) {
  std::lock_guard lock(mutex_);
  if (thread_.joinable()) return false;
  stopping_ = false;
  thread_ = std::thread(std::move(loop));
  return true;
}

void DriverThread::stop() {
  std::thread thread;
  {
    std::lock_guard lock(mutex_);
    if (!thread_.joinable()) return;
    stopping_ = true;
    thread = std::move(thread_);
  }
  wake_.notify_all();
  thread.join();
}

void DriverThread::request_stop() {
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
}

bool DriverThread::running() const {
  std::lock_guard lock(mutex_);
  return thread_.joinable();
}

bool DriverThread::stopping() const {
  std::lock_guard lock(mutex_);
  return stopping_;
}

bool DriverThread::wait_until(std::chrono::steady_clock::time_point wall) {
  std::unique_lock lock(mutex_);
  return !wake_.wait_until(lock, wall, [this] { return stopping_; });
}

}  // namespace icars::detail
