#include "icars/service/adaptor.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

namespace icars::service {

std::string describe_value(const planet::Value& value) {
  if (value.empty()) return "(none)";
  if (value.is<bool>()) return value.as<bool>() ? "true" : "false";
  if (value.is<std::int32_t>()) return std::to_string(value.as<std::int32_t>());
  if (value.is<std::int64_t>()) return std::to_string(value.as<std::int64_t>());
  if (value.is<double>()) return fmt::format("{:g}", value.as<double>());
  if (value.is<std::string>()) return fmt::format("\"{}\"", value.as<std::string>());
  return value.type_name();
}

std::string describe(const std::vector<StateDifference>& differences) {
  std::string out;
  for (const auto& d : differences) {
    if (!out.empty()) out += ", ";
    out += fmt::format("{} {} -> {}", d.name, describe_value(d.wanted), describe_value(d.found));
  }
  return out;
}

// Forwards to the registry's observer and, after each acknowledged command of a stateful
// capability, has the adaptor read the state the device now keeps.
class Adaptor::CommandTracker final : public planet::CallObserver {
 public:
  CommandTracker(std::weak_ptr<Adaptor> adaptor, std::shared_ptr<planet::CallObserver> next)
      : adaptor_(std::move(adaptor)), next_(std::move(next)) {}
  void sent(std::uint32_t request_id, const std::string& path, std::string_view method) override {
    if (next_) next_->sent(request_id, path, method);
  }
  void ended(std::uint32_t request_id, const std::string& path, std::string_view method,
             const std::exception_ptr& error) override {
    if (next_) next_->ended(request_id, path, method, error);
    if (error) return;
    if (auto adaptor = adaptor_.lock(); adaptor && adaptor->is_command(method)) {
      adaptor->command_acknowledged();
    }
  }

 private:
  std::weak_ptr<Adaptor> adaptor_;
  std::shared_ptr<planet::CallObserver> next_;
};

Adaptor::Adaptor(std::string type, const df::DeviceInfo& device, const df::CapabilityInfo& capability)
    : Service(device.id + "." + capability.name, std::move(type),
              ServiceAttributes{device.id, capability.name, device.room, device.carrier}),
      interface_id_(capability.interface_id),
      path_(capability.path),
      device_(device.id) {}

Adaptor::~Adaptor() = default;

void Adaptor::bind(planet::Communicator& communicator, const std::shared_ptr<planet::Link>& link) {
  const auto connection = link ? link->connection() : nullptr;
  bound_connection_ = connection ? connection->id() : 0;
  on_bind(communicator, link);
  set_available(true);
}

void Adaptor::log_failure(planet::Communicator& communicator, std::string_view what,
                          std::exception_ptr error) const {
  communicator.log().warn("service {} {}: {}", id(), what, planet::describe(error));
}

void Adaptor::set_call_observer(std::shared_ptr<planet::CallObserver> observer) {
  std::lock_guard lock(observer_mutex_);
  call_observer_ = std::move(observer);
}

std::shared_ptr<planet::CallObserver> Adaptor::call_observer() {
  std::lock_guard lock(observer_mutex_);
  if (!keeps_state()) return call_observer_;
  return std::make_shared<CommandTracker>(
      std::static_pointer_cast<Adaptor>(shared_from_this()), call_observer_);
}

void Adaptor::check_own_link(const planet::Current& current) const {
  const auto bound = bound_connection();
  if (current.connection && current.connection->id() == bound) return;
  const auto principal = current.connection ? current.connection->principal() : nullptr;
  throw planet::Error(
      planet::ErrorKind::denied,
      fmt::format("{} may not deliver events of device '{}': {}",
                  principal ? fmt::format("principal '{}'", principal->name)
                            : (current.connection ? current.connection->describe() : "a peer"),
                  device_id(),
                  bound == 0 ? "the device is not connected"
                             : "only the link that registered the device may"));
}

DeviceState Adaptor::acknowledged_state() const {
  std::lock_guard lock(observer_mutex_);
  return acknowledged_;
}

void Adaptor::command_acknowledged() {
  std::uint64_t read = 0;
  {
    std::lock_guard lock(observer_mutex_);
    read = ++reads_started_;
  }
  read_state([weak = weak_from_this(), read](std::exception_ptr error, DeviceState state) {
    auto self = std::static_pointer_cast<Adaptor>(weak.lock());
    if (!self || error) return;  // the next command or the next restore reads it again
    std::lock_guard lock(self->observer_mutex_);
    if (read == self->reads_started_) self->acknowledged_ = std::move(state);
  });
}

void Adaptor::restore(bool reapply, std::function<void(Restoration)> done) {
  const DeviceState wanted = acknowledged_state();
  if (!keeps_state() || wanted.size() == 0) {
    done({});
    return;
  }
  read_state([weak = weak_from_this(), wanted, reapply, done = std::move(done)](
                 std::exception_ptr error, DeviceState found) mutable {
    auto self = std::static_pointer_cast<Adaptor>(weak.lock());
    Restoration result;
    if (!self) return;
    if (error) {
      result.error = error;
      done(std::move(result));
      return;
    }
    for (const auto& [name, value] : wanted.items()) {
      const planet::Value* now = found.has(name) ? &found.value(name) : nullptr;
      if (!now || !(*now == value)) {
        result.differences.push_back({name, value, now ? *now : planet::Value()});
      }
    }
    if (result.differences.empty() || !reapply) {
      done(std::move(result));
      return;
    }
    result.reapplied = true;
    self->apply_state(wanted, [result = std::move(result), done = std::move(done)](
                                  std::exception_ptr e) mutable {
      result.error = e;
      done(std::move(result));
    });
  });
}

void Adaptor::unbind() {
  bound_connection_ = 0;
  set_available(false);
  on_unbind();
}

// --- The stateful house adaptors ----------------------------------------------------------------

namespace {

// Runs the steps one after another; the first failure ends the chain and is reported.
using Step = std::function<void(std::function<void(std::exception_ptr)>)>;
void run_steps(std::shared_ptr<std::vector<Step>> steps, std::size_t next,
               std::function<void(std::exception_ptr)> done) {
  if (next == steps->size()) {
    done(nullptr);
    return;
  }
  (*steps)[next]([steps, next, done](std::exception_ptr e) mutable {
    if (e) {
      done(e);
      return;
    }
    run_steps(std::move(steps), next + 1, std::move(done));
  });
}

}  // namespace

bool TVControlService::is_command(std::string_view method) const {
  return method == "set_power" || method == "set_channel" || method == "set_volume";
}

void TVControlService::read_state(std::function<void(std::exception_ptr, DeviceState)> done) {
  proxy().state_async([done = std::move(done)](std::exception_ptr e, home::TVState s = {}) {
    DeviceState state;
    if (!e) {
      state.set("on", s.on);
      state.set("channel", s.channel);
      state.set("volume", s.volume);
    }
    done(e, std::move(state));
  });
}

void TVControlService::apply_state(const DeviceState& wanted, std::function<void(std::exception_ptr)> done) {
  auto tv = proxy();
  auto steps = std::make_shared<std::vector<Step>>();
  const bool on = wanted.get<bool>("on");
  steps->push_back([tv, on](auto next) { tv.set_power_async(on, std::move(next)); });
  if (wanted.has("channel")) {
    steps->push_back([tv, c = wanted.get<std::int32_t>("channel")](auto next) { tv.set_channel_async(c, std::move(next)); });
  }
  if (wanted.has("volume")) {
    steps->push_back([tv, v = wanted.get<std::int32_t>("volume")](auto next) { tv.set_volume_async(v, std::move(next)); });
  }
  run_steps(std::move(steps), 0, std::move(done));
}

bool LightService::is_command(std::string_view method) const {
  return method == "set_power" || method == "set_intensity";
}

void LightService::read_state(std::function<void(std::exception_ptr, DeviceState)> done) {
  proxy().state_async([done = std::move(done)](std::exception_ptr e, home::LightState s = {}) {
    DeviceState state;
    if (!e) {
      state.set("on", s.on);
      state.set("intensity", s.intensity);
    }
    done(e, std::move(state));
  });
}

void LightService::apply_state(const DeviceState& wanted, std::function<void(std::exception_ptr)> done) {
  auto light = proxy();
  auto steps = std::make_shared<std::vector<Step>>();
  if (wanted.has("intensity")) {
    steps->push_back([light, i = wanted.get<std::int32_t>("intensity")](auto next) {
      light.set_intensity_async(i, std::move(next));
    });
  }
  steps->push_back([light, on = wanted.get<bool>("on")](auto next) { light.set_power_async(on, std::move(next)); });
  run_steps(std::move(steps), 0, std::move(done));
}

bool SpeakerService::is_command(std::string_view method) const {
  return method == "play" || method == "stop" || method == "set_volume";
}

void SpeakerService::read_state(std::function<void(std::exception_ptr, DeviceState)> done) {
  proxy().state_async([done = std::move(done)](std::exception_ptr e, home::SpeakerState s = {}) {
    DeviceState state;
    if (!e) {
      state.set("playing", s.playing);
      state.set("volume", s.volume);
    }
    done(e, std::move(state));
  });
}

void SpeakerService::apply_state(const DeviceState& wanted, std::function<void(std::exception_ptr)> done) {
  auto speaker = proxy();
  auto steps = std::make_shared<std::vector<Step>>();
  if (wanted.has("volume")) {
    steps->push_back([speaker, v = wanted.get<std::int32_t>("volume")](auto next) {
      speaker.set_volume_async(v, std::move(next));
    });
  }
  const auto playing = wanted.get<std::string>("playing");
  if (playing.empty()) {
    steps->push_back([speaker](auto next) { speaker.stop_async(std::move(next)); });
  } else {
    steps->push_back([speaker, playing](auto next) { speaker.play_async(playing, std::move(next)); });
  }
  run_steps(std::move(steps), 0, std::move(done));
}

// A reading carries the last event's time (the sensor has no clock of its own to ask); before
// any event, 0.
void MotionSensorService::reread(const home::MotionSensorPrx& sensor) {
  sensor.motion_async([weak = weak_from_this()](std::exception_ptr e, bool motion = false) {
    auto self = std::static_pointer_cast<MotionSensorService>(weak.lock());
    if (!self || e) return;
    const auto last = self->last_event();
    home::MotionEvent reading{self->device_id(), self->attributes().room, motion, last ? last->time_ms : 0};
    self->deliver_if_changed(reading);
  });
}

void OccupancyService::reread(const home::OccupancySensorPrx& sensor) {
  sensor.furniture_async([weak = weak_from_this(), sensor](std::exception_ptr e, std::string furniture = {}) {
    if (e) return;
    sensor.occupied_async([weak, furniture](std::exception_ptr e2, bool occupied = false) {
      auto self = std::static_pointer_cast<OccupancyService>(weak.lock());
      if (!self || e2) return;
      const auto last = self->last_event();
      home::OccupancyEvent reading{self->device_id(), furniture, occupied, last ? last->time_ms : 0};
      self->deliver_if_changed(reading);
    });
  });
}

}  // namespace icars::service
