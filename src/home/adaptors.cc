#include "icars/home/adaptors.h"

#include "icars/home/sound_sensor.h"

namespace icars::home {

service::AdaptorFactory adaptors() {
  service::AdaptorFactory f;
  f.add<home::TVControl, TVControlService>();
  f.add<home::Light, LightService>();
  f.add<home::Speaker, SpeakerService>();
  f.add<home::Microphone, SoundSensor>();
  f.add<home::SpeechRecognizer, SpeechRecognizerService>();
  f.add<home::Wheels, NavigationService>();
  f.add<home::MotionSensor, MotionSensorService>();
  f.add<home::OccupancySensor, OccupancyService>();
  f.add<home::Camera, CameraService>();
  f.add<home::FaceRecognizer, FaceRecognizerService>();
  f.add<home::Clock, ClockService>();
  f.add<home::Simulation, SimulationService>();
  f.add<home::MeasurementSensor, MeasurementService>();
  f.add<home::Cover, CoverService>();
  f.add<home::PowerSwitch, PowerSwitchService>();
  return f;
}

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

void TVControlService::read_state(std::function<void(std::exception_ptr, service::DeviceState)> done) {
  proxy().state_async([done = std::move(done)](std::exception_ptr e, home::TVState s = {}) {
    service::DeviceState state;
    if (!e) {
      state.set("on", s.on);
      state.set("channel", s.channel);
      state.set("volume", s.volume);
    }
    done(e, std::move(state));
  });
}

void TVControlService::apply_state(const service::DeviceState& wanted, std::function<void(std::exception_ptr)> done) {
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

void LightService::read_state(std::function<void(std::exception_ptr, service::DeviceState)> done) {
  proxy().state_async([done = std::move(done)](std::exception_ptr e, home::LightState s = {}) {
    service::DeviceState state;
    if (!e) {
      state.set("on", s.on);
      state.set("intensity", s.intensity);
    }
    done(e, std::move(state));
  });
}

void LightService::apply_state(const service::DeviceState& wanted, std::function<void(std::exception_ptr)> done) {
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

void SpeakerService::read_state(std::function<void(std::exception_ptr, service::DeviceState)> done) {
  proxy().state_async([done = std::move(done)](std::exception_ptr e, home::SpeakerState s = {}) {
    service::DeviceState state;
    if (!e) {
      state.set("playing", s.playing);
      state.set("volume", s.volume);
    }
    done(e, std::move(state));
  });
}

void SpeakerService::apply_state(const service::DeviceState& wanted, std::function<void(std::exception_ptr)> done) {
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

void MeasurementService::reread(const home::MeasurementSensorPrx& sensor) {
  sensor.quantity_async([weak = weak_from_this(), sensor](std::exception_ptr e, std::string quantity = {}) {
    if (e) return;
    sensor.unit_async([weak, sensor, quantity](std::exception_ptr e2, std::string unit = {}) {
      if (e2) return;
      // Fails while the sensor has no reading yet: then there is no baseline to compare with.
      sensor.value_async([weak, quantity, unit](std::exception_ptr e3, double value = 0) {
        auto self = std::static_pointer_cast<MeasurementService>(weak.lock());
        if (!self || e3) return;
        const auto last = self->last_event();
        home::MeasurementEvent reading{self->device_id(), quantity, value, unit, self->attributes().room,
                                       last ? last->time_ms : 0};
        self->deliver_if_changed(reading);
      });
    });
  });
}

bool CoverService::is_command(std::string_view method) const {
  return method == "open" || method == "close" || method == "stop";
}

void CoverService::read_state(std::function<void(std::exception_ptr, service::DeviceState)> done) {
  proxy().state_async([done = std::move(done)](std::exception_ptr e, home::CoverState s = {}) {
    service::DeviceState state;
    if (!e) {
      const auto& p = s.position;
      state.set("position", p == "opening" ? std::string("open") : p == "closing" ? std::string("closed") : p);
    }
    done(e, std::move(state));
  });
}

// Only a cover that was open or closed is moved there again; one stopped part-way stays.
void CoverService::apply_state(const service::DeviceState& wanted, std::function<void(std::exception_ptr)> done) {
  const auto position = wanted.get<std::string>("position");
  if (position == "open") {
    proxy().open_async(std::move(done));
  } else if (position == "closed") {
    proxy().close_async(std::move(done));
  } else {
    done(nullptr);
  }
}

std::string PowerSwitchService::service_type(std::string_view capability) {
  if (capability == "fan") return "FanControl";
  if (capability == "climate") return "ClimateControl";
  return "PowerControl";
}

bool PowerSwitchService::is_command(std::string_view method) const { return method == "set_power"; }

void PowerSwitchService::read_state(std::function<void(std::exception_ptr, service::DeviceState)> done) {
  proxy().on_async([done = std::move(done)](std::exception_ptr e, bool on = false) {
    service::DeviceState state;
    if (!e) state.set("on", on);
    done(e, std::move(state));
  });
}

void PowerSwitchService::apply_state(const service::DeviceState& wanted, std::function<void(std::exception_ptr)> done) {
  proxy().set_power_async(wanted.get<bool>("on"), std::move(done));
}

}  // namespace icars::home
