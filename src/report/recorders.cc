#include "icars/report/recorders.h"

#include <fmt/format.h>

#include "icars/home/services.h"
#include "icars/planet/error.h"
#include "icars/service/adaptor.h"

namespace icars::report {

namespace {

behavior::TraceRecord record(Time t, std::string kind, std::string source, std::string text) {
  behavior::TraceRecord r;
  r.time = t;
  r.kind = std::move(kind);
  r.source = std::move(source);
  r.text = std::move(text);
  return r;
}

}  // namespace

void TraceClock::set(const Clock* clock) {
  std::lock_guard lock(mutex_);
  clock_ = clock;
}

Time TraceClock::now() const {
  std::lock_guard lock(mutex_);
  return clock_ ? clock_->now() : Time(0);
}

// --- CommandRecorder ----------------------------------------------------------------------------

CommandRecorder::CommandRecorder(behavior::Trace& trace, const TraceClock& clock,
                                 std::set<std::string, std::less<>> commands)
    : trace_(trace), clock_(clock), commands_(std::move(commands)) {}

std::set<std::string, std::less<>> CommandRecorder::house_commands() {
  return {"set_power", "set_channel", "set_volume", "set_intensity", "play",
          "stop",      "speak",       "go_to",      "go_to_waypoint", "turn_to"};
}

void CommandRecorder::sent(std::uint32_t request_id, const std::string& path, std::string_view method) {
  if (!commands_.contains(method)) return;
  add(request_id, path, method, "sent", {});
}

void CommandRecorder::ended(std::uint32_t request_id, const std::string& path, std::string_view method,
                            const std::exception_ptr& error) {
  if (!commands_.contains(method)) return;
  add(request_id, path, method, error ? "failed" : "acknowledged", planet::describe(error));
}

void CommandRecorder::add(std::uint32_t request_id, const std::string& path, std::string_view method,
                          const char* event, const std::string& error) {
  // The path of a device capability is /devices/<device>/<capability>.
  std::string device = path, capability;
  if (path.starts_with("/devices/")) {
    device = path.substr(9);
    if (const auto slash = device.find('/'); slash != std::string::npos) {
      capability = device.substr(slash + 1);
      device.resize(slash);
    }
  }
  auto r = record(clock_.now(), "command", device,
                  fmt::format("command {} {}: {}.{}.{}{}", request_id, event, device, capability, method,
                              error.empty() ? std::string() : fmt::format(" ({})", error)));
  r.with("event", std::string(event))
      .with("request", static_cast<std::int64_t>(request_id))
      .with("device", device)
      .with("capability", capability)
      .with("method", std::string(method));
  if (!error.empty()) r.with("error", error);
  trace_.record(std::move(r));
}

// --- DeviceEventRecorder ------------------------------------------------------------------------

DeviceEventRecorder::DeviceEventRecorder(service::ServiceContainer& services, behavior::Trace& trace,
                                         const TraceClock& clock)
    : services_(services) {
  watch_ = services_.watch_devices([&trace, &clock](const planet::Event& e) {
    const auto device = e.get<std::string>("device");
    std::string text;
    if (e.type() == "DeviceLost") {
      text = fmt::format("{} lost: {}", device, e.get<std::string>("reason"));
    } else if (e.type() == "DeviceBack") {
      text = fmt::format("{} registered again", device);
    } else if (e.type() == "DeviceForgotten") {
      text = fmt::format("{} forgotten (gone too long)", device);
    } else if (e.type() == "DeviceRestored") {
      const auto error = e.get<std::string>("error");
      text = fmt::format("{} came back with another state: {}{}{}", device, e.get<std::string>("differences"),
                         e.get<bool>("reapplied") ? "; re-applied" : "", error.empty() ? "" : "; failed: " + error);
    } else {
      return;
    }
    auto r = record(clock.now(), "device", device, std::move(text));
    r.with("event", e.type()).with("device", device);
    if (e.type() == "DeviceRestored") {
      r.with("differences", e.get<std::string>("differences")).with("reapplied", e.get<bool>("reapplied"));
    }
    trace.record(std::move(r));
  });
}

DeviceEventRecorder::~DeviceEventRecorder() { stop(); }

void DeviceEventRecorder::stop() {
  if (watch_ != 0) services_.remove_device_watcher(watch_);
  watch_ = 0;
}

// --- ServiceRecorder ----------------------------------------------------------------------------

ServiceRecorder::ServiceRecorder(service::ServiceContainer& services, behavior::Trace& trace, bool positions)
    : services_(services), trace_(trace), positions_(positions) {
  watch_ = services_.watch([this](const std::shared_ptr<service::Service>& service,
                                  const service::ServiceChange& change) {
    if (change == service::ServiceChange::added) observe(service);
  });
  for (const auto& service : services_.all()) observe(service);
}

ServiceRecorder::~ServiceRecorder() {
  services_.remove_watcher(watch_);
  std::lock_guard lock(mutex_);
  for (auto& release : releases_) release();
}

void ServiceRecorder::observe(const std::shared_ptr<service::Service>& service) {
  std::lock_guard lock(mutex_);
  if (!seen_.insert(service->id()).second) return;
  if (auto speech = std::dynamic_pointer_cast<home::SpeechSensor>(service)) {
    // Both what was recognized and what was heard but not taken for any phrase.
    struct Recorder {
      ServiceRecorder* self;
      void operator()(const home::SpeechEvent& e) const {
        ++self->heard_;
        auto r = record(Time(e.time_ms), "speech", e.device,
                        fmt::format("{} heard \"{}\" ({:.0f}% sure)", e.device, e.text, e.confidence * 100));
        r.with("words", e.text).with("device", e.device).with("confidence", e.confidence).with("recognized", true);
        r.with("latency_ms", e.latency_ms);
        self->trace_.record(std::move(r));
      }
      void operator()(const home::UnrecognizedSpeech& e) const {
        auto r = record(Time(e.time_ms), "speech", e.device,
                        fmt::format("{} heard speech it did not recognize: {}", e.device, e.reason));
        r.with("words", "").with("device", e.device).with("confidence", 0.0).with("recognized", false);
        r.with("reason", e.reason);
        self->trace_.record(std::move(r));
      }
    };
    const auto id = speech->subscribe(Recorder{this});
    releases_.push_back([speech, id] { speech->unsubscribe(id); });
  }
  if (auto nav = std::dynamic_pointer_cast<home::NavigationService>(service); nav && positions_) {
    const auto id = nav->subscribe([this](const home::PositionEvent& e) {
      auto r = record(Time(e.time_ms), "robot", e.robot,
                      fmt::format("{} at ({:.2f}, {:.2f}){}", e.robot, e.x, e.y, e.moving ? " moving" : ""));
      r.with("robot", e.robot).with("x", e.x).with("y", e.y).with("moving", e.moving);
      trace_.record(std::move(r));
    });
    releases_.push_back([nav, id] { nav->unsubscribe(id); });
  }
}

}  // namespace icars::report
