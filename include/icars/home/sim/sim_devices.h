// Simulated devices of the house (ICARS paper 5.1, Table 3), built on the simulated world
// (icars::sim): a device provider's implementations of the capability interfaces of
// idl/home.idl for devices that exist only in simulation. They are ordinary DF devices: a
// DeviceManager serves and registers them exactly as it would real ones.
//
// Device types (the `type` of a <device> in the house file) and their capabilities:
//   TV            tv_control     home::TVControl
//   Light         light          home::Light
//   Speaker       speaker        home::Speaker
//   Microphone    sound_sensor   home::Microphone        (sound events with speech audio)
//   Wheels        wheels         home::Wheels            (go_to, position events; effects too)
//   Camera        camera         home::Camera            (a "sim/scene" image)
//   MotionSensor  motion         home::MotionSensor      (param room: the room it watches)
//   BedOccupancy, SofaOccupancy, Occupancy
//                 occupancy      home::OccupancySensor   (param furniture)
//   Clock         clock          home::Clock
//   SpeechEngine  speech_recognizer  home::SpeechRecognizer (a software device)
//   VisionEngine  face_recognizer    home::FaceRecognizer   (a software device)
// and the pseudo-device "simulator" (Simulation) through which tests and demos drive the world.
// The actuators (TV, Light, Speaker, Wheels) report what they did to SimContext::effects and
// keep their state in SimContext::state (sim_state_file.h) when there is one.
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "icars/clock/sim_clock.h"
#include "icars/device/device.h"
#include "icars/home/sim/sim_state_file.h"
#include "icars/planet/communicator.h"
#include "icars/sim/world.h"

namespace icars::home {

// What a simulated actuator did, as the house would show it ("tv: power on"), independent of
// what any client believes: one per accepted command, after the device's state changed (or
// was confirmed: turning on a TV that is on is reported too). Refused commands report nothing.
// The request id names the command, so a caller's record of the calls it sent can be matched
// with what the devices executed (each command exactly once).
struct DeviceEffect {
  Time time{0};  // the clock's time when the command took effect
  std::string device;    // "tv"
  std::string what;      // "power", "channel", "volume", "intensity", "playing", "stopped",
                         // "spoke"; the wheels: "heading" (go_to...), "halted", "turned"
  std::string value;     // "on"/"off", "5", the track, the spoken text, the target, the angle;
                         // "" for "stopped" and "halted"
  std::uint32_t request_id = 0;  // the PLANET request id of the call that commanded it
};
// Called on the thread of the communicator serving the device, with no lock of the device
// held; it must not block for long (it delays that communicator's other calls).
using EffectObserver = std::function<void(const DeviceEffect&)>;

// Everything a simulated device needs: the world, the communicator that serves the device
// (for streams), who hears the actuators' effects (empty: nobody), and the state file that
// keeps the actuators' state across restarts (null: none). With a state file, an actuator
// starts from the state it holds and has every accepted command's state on disk before it
// replies; the wheels restore their robot when the file starts (SimStateFile::start).
struct SimContext {
  SimContext(sim::World& w, planet::Communicator& c, EffectObserver e = {},
             SimStateFile* s = nullptr)
      : world(w), communicator(c), effects(std::move(e)), state(s) {}
  sim::World& world;
  planet::Communicator& communicator;
  EffectObserver effects;
  SimStateFile* state;  // not owned; outlives the devices
};

// Builds the simulated device for a <device> of the house file; throws std::invalid_argument
// for parameters it cannot use.
using MakeSimDevice = std::function<std::shared_ptr<device::Device>(const sim::DeviceSpec&, SimContext)>;

// The device types a simulated house can hold, by the `type` of a <device>: the home's
// (sim_device_types()) and any a plugin adds (registrar.extension<home::SimDeviceTypes>(),
// docs/plugins.md).
class SimDeviceTypes {
 public:
  // Throws std::invalid_argument when `type` is already there.
  void add(const std::string& type, std::string description, MakeSimDevice make);
  bool has(const std::string& type) const;
  std::vector<std::string> names() const;  // in the order added
  const std::string& description(const std::string& type) const;  // "" for an unknown type
  // Adds the other's types (none of which may be here already).
  void merge(SimDeviceTypes&& other);

  // Throws sim::HouseError at the line of the house's first device of an unknown type.
  void check(const sim::House& house) const;

  // The device of `spec`; throws std::invalid_argument for an unknown type (naming the known
  // ones) or parameters the type cannot use.
  std::shared_ptr<device::Device> make(const sim::DeviceSpec& spec, SimContext context) const;

 private:
  struct Type {
    std::string name, description;
    MakeSimDevice make;
  };
  std::vector<Type> types_;
};

// The home's device types, listed above.
const SimDeviceTypes& sim_device_types();

// The device for a device of the house, of one of the home's types (sim_device_types());
// throws std::invalid_argument for an unknown type.
std::shared_ptr<device::Device> make_sim_device(const sim::DeviceSpec& spec, SimContext context);
// The ids of the devices every simulated house has besides its own: the engines and the
// simulator below.
inline constexpr std::string_view kSpeechEngineId = "speech_engine";
inline constexpr std::string_view kVisionEngineId = "vision_engine";
inline constexpr std::string_view kSimulatorId = "simulator";
// The speech model the simulated house decodes with by default: PocketSphinx's en-us model
// adapted to the simulation's espeak-ng voices in its room (tools/speech-model/adapt.sh,
// docs/speech.md), when the build made it; "" (the stock model) otherwise. A real microphone's
// voices are people's: they keep the stock model.
std::string sim_speech_model_dir();
// The reverberation time the simulated house's speech engine suppresses before decoding
// (RecognizerOptions::room_rt60): the shortest of its simulated microphones' rooms (their rt60
// param, audio::RoomSound's by default), so that no room's sound loses more than its own tail;
// 0 (none) when no microphone is simulated.
double sim_room_rt60(const sim::House& house);
// The software devices every simulated house gets: a speech engine (decoding with the model in
// `speech_model_dir`, RecognizerOptions::model_dir; "": the stock one; suppressing
// sim_room_rt60's reverberation) and a vision engine.
std::vector<std::shared_ptr<device::Device>> make_sim_engines(SimContext context,
                                                              const std::string& speech_model_dir = sim_speech_model_dir());
// The pseudo-device "simulator" with its Simulation capability.
std::shared_ptr<device::Device> make_simulator_device(SimContext context);

}  // namespace icars::home
