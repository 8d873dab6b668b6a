// Observers of a mediating server that put what it does with devices into its trace, next to
// what its behaviors do: the commands it sends to devices and their outcome, devices lost and
// back, and what its services hear and see (speech, robot positions). None of them changes what
// the server does; `icars run` attaches them for its timeline, summary and plot.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <string_view>
#include <vector>

#include "icars/behavior/trace.h"
#include "icars/clock/clock.h"
#include "icars/planet/proxy.h"
#include "icars/service/service_container.h"

namespace icars::report {

// Stamps records with a clock's time, or 0 before one is set. Thread-safe; once set(nullptr)
// returns, the previous clock is no longer read.
class TraceClock {
 public:
  void set(const Clock* clock);
  Time now() const;

 private:
  mutable std::mutex mutex_;
  const Clock* clock_ = nullptr;
};

// The commands a server sends to devices: every call of an operation that changes a device,
// traced as "command" records (fields event = sent / acknowledged / failed, request, device,
// capability, method, error) with the PLANET request id the device side logs with what it
// executed, so the two can be matched. Install with DeviceRegistry::set_call_observer.
class CommandRecorder final : public planet::CallObserver {
 public:
  // `commands`: the operation names that change a device (the others only read or subscribe).
  CommandRecorder(behavior::Trace& trace, const TraceClock& clock, std::set<std::string, std::less<>> commands);
  // The operations of idl/home.idl that change a device.
  static std::set<std::string, std::less<>> house_commands();

  void sent(std::uint32_t request_id, const std::string& path, std::string_view method) override;
  void ended(std::uint32_t request_id, const std::string& path, std::string_view method,
             const std::exception_ptr& error) override;

 private:
  void add(std::uint32_t request_id, const std::string& path, std::string_view method, const char* event,
           const std::string& error);

  behavior::Trace& trace_;
  const TraceClock& clock_;
  const std::set<std::string, std::less<>> commands_;
};

// Devices lost, back, restored with another state and forgotten, as "device" records (fields
// event, device; differences and reapplied for DeviceRestored). Stops recording when destroyed
// or stop()ped.
class DeviceEventRecorder {
 public:
  DeviceEventRecorder(service::ServiceContainer& services, behavior::Trace& trace, const TraceClock& clock);
  ~DeviceEventRecorder();
  DeviceEventRecorder(const DeviceEventRecorder&) = delete;
  DeviceEventRecorder& operator=(const DeviceEventRecorder&) = delete;
  void stop();

 private:
  service::ServiceContainer& services_;
  std::uint64_t watch_ = 0;
};

// What the server's services hear and see: every SpeechSensor's recognized speech ("speech"
// records: words, device, confidence) and, when `positions`, every Navigation service's robot
// positions ("robot" records: robot, x, y, moving), for services present now and added later.
class ServiceRecorder {
 public:
  ServiceRecorder(service::ServiceContainer& services, behavior::Trace& trace, bool positions);
  ~ServiceRecorder();
  ServiceRecorder(const ServiceRecorder&) = delete;
  ServiceRecorder& operator=(const ServiceRecorder&) = delete;
  int heard() const { return heard_.load(); }

 private:
  void observe(const std::shared_ptr<service::Service>& service);

  service::ServiceContainer& services_;
  behavior::Trace& trace_;
  const bool positions_;
  std::uint64_t watch_ = 0;
  std::mutex mutex_;
  std::set<std::string> seen_;
  std::vector<std::function<void()>> releases_;
  std::atomic<int> heard_{0};
};

}  // namespace icars::report
