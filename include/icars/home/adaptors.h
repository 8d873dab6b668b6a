// The adaptor services of the home's capabilities (idl/home.idl, ICARS paper 5.1): the Service
// objects SF makes for a TV, a light, a speaker, a microphone, the robot's wheels and camera,
// the sensors of the house, its covers, fans and heating, and the simulation's clock. adaptors() puts them all in an
// AdaptorFactory for a ServerOptions or a ServiceFramework.
#pragma once

#include <string_view>

#include "home.planet.h"
#include "icars/service/adaptor.h"
#include "icars/service/device_registry.h"

namespace icars::home {

// The adaptors of every capability in idl/home.idl, by interface id.
service::AdaptorFactory adaptors();

// The stateful house adaptors remember the TV's, light's and speaker's state after every
// acknowledged command and restore it when the device comes back (Adaptor::restore).
class TVControlService final : public service::AdaptorOf<home::TVControlPrx> {
 public:
  TVControlService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("TVControl", d, c) {}
  bool keeps_state() const override { return true; }

 protected:
  bool is_command(std::string_view method) const override;
  void read_state(std::function<void(std::exception_ptr, service::DeviceState)> done) override;
  void apply_state(const service::DeviceState& wanted, std::function<void(std::exception_ptr)> done) override;
};

class LightService final : public service::AdaptorOf<home::LightPrx> {
 public:
  LightService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("LightControl", d, c) {}
  bool keeps_state() const override { return true; }

 protected:
  bool is_command(std::string_view method) const override;
  void read_state(std::function<void(std::exception_ptr, service::DeviceState)> done) override;
  void apply_state(const service::DeviceState& wanted, std::function<void(std::exception_ptr)> done) override;
};

class SpeakerService final : public service::AdaptorOf<home::SpeakerPrx> {
 public:
  SpeakerService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("AudioControl", d, c) {}
  bool keeps_state() const override { return true; }

 protected:
  // What it plays and how loud; what it last said is not state to restore.
  bool is_command(std::string_view method) const override;
  void read_state(std::function<void(std::exception_ptr, service::DeviceState)> done) override;
  void apply_state(const service::DeviceState& wanted, std::function<void(std::exception_ptr)> done) override;
};

class SpeechRecognizerService final : public service::AdaptorOf<home::SpeechRecognizerPrx> {
 public:
  SpeechRecognizerService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("SpeechRecognizer", d, c) {}
};

class CameraService final : public service::AdaptorOf<home::CameraPrx> {
 public:
  CameraService(const df::DeviceInfo& d, const df::CapabilityInfo& c) : AdaptorOf("Camera", d, c) {}
};

class FaceRecognizerService final : public service::AdaptorOf<home::FaceRecognizerPrx> {
 public:
  FaceRecognizerService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("FaceRecognizer", d, c) {}
};

class ClockService final : public service::AdaptorOf<home::ClockPrx> {
 public:
  ClockService(const df::DeviceInfo& d, const df::CapabilityInfo& c) : AdaptorOf("Clock", d, c) {}
};

class SimulationService final : public service::AdaptorOf<home::SimulationPrx> {
 public:
  SimulationService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("Simulation", d, c) {}
};

// The robot's wheels as a navigation service: go_to/go_to_waypoint/stop and position events.
class NavigationService final : public service::SensorAdaptor<home::WheelsPrx, home::PositionListener, home::PositionEvent,
                                                      home::PositionListener::on_position> {
 public:
  NavigationService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : SensorAdaptor("Navigation", d, c) {}
};

class MotionSensorService final : public service::SensorAdaptor<home::MotionSensorPrx, home::MotionListener,
                                                        home::MotionEvent, home::MotionListener::on_motion> {
 public:
  MotionSensorService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : SensorAdaptor("MotionSensor", d, c) {}

 protected:
  void reread(const home::MotionSensorPrx& sensor) override;
  bool changed_from(const home::MotionEvent& last, const home::MotionEvent& reading) const override {
    return last.motion != reading.motion;
  }
};

class OccupancyService final
    : public service::SensorAdaptor<home::OccupancySensorPrx, home::OccupancyListener, home::OccupancyEvent,
                           home::OccupancyListener::on_occupancy> {
 public:
  OccupancyService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : SensorAdaptor("OccupancySensor", d, c) {}

 protected:
  void reread(const home::OccupancySensorPrx& sensor) override;
  bool changed_from(const home::OccupancyEvent& last, const home::OccupancyEvent& reading) const override {
    return last.occupied != reading.occupied;
  }
};

// A sensor's readings (temperature, humidity, illuminance, ...), an event on every change.
class MeasurementService final
    : public service::SensorAdaptor<home::MeasurementSensorPrx, home::MeasurementListener, home::MeasurementEvent,
                           home::MeasurementListener::on_measurement> {
 public:
  MeasurementService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : SensorAdaptor("MeasurementSensor", d, c) {}

 protected:
  void reread(const home::MeasurementSensorPrx& sensor) override;
  bool changed_from(const home::MeasurementEvent& last, const home::MeasurementEvent& reading) const override {
    return last.value != reading.value;
  }
};

// Blinds, shutters, curtains. The state it restores is where the cover was last heading after
// an acknowledged command ("open" for opening too, "closed" for closing).
class CoverService final : public service::AdaptorOf<home::CoverPrx> {
 public:
  CoverService(const df::DeviceInfo& d, const df::CapabilityInfo& c) : AdaptorOf("CoverControl", d, c) {}
  bool keeps_state() const override { return true; }

 protected:
  bool is_command(std::string_view method) const override;
  void read_state(std::function<void(std::exception_ptr, service::DeviceState)> done) override;
  void apply_state(const service::DeviceState& wanted, std::function<void(std::exception_ptr)> done) override;
};

// An on/off device other than a light. Its service type says what it is, from the name of its
// capability: "FanControl" for a `fan`, "ClimateControl" for a `climate` (heating, air
// conditioning), "PowerControl" for any other; a policy switching fans does not switch heating.
class PowerSwitchService final : public service::AdaptorOf<home::PowerSwitchPrx> {
 public:
  PowerSwitchService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf(service_type(c.name), d, c) {}
  bool keeps_state() const override { return true; }
  static std::string service_type(std::string_view capability);

 protected:
  bool is_command(std::string_view method) const override;
  void read_state(std::function<void(std::exception_ptr, service::DeviceState)> done) override;
  void apply_state(const service::DeviceState& wanted, std::function<void(std::exception_ptr)> done) override;
};

}  // namespace icars::home
