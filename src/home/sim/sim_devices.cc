#include "icars/home/sim/sim_devices.h"

#include <fmt/format.h>

#include <asio/co_spawn.hpp>
#include <asio/detached.hpp>
#include <asio/use_awaitable.hpp>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <mutex>
#include <numbers>
#include <set>
#include <sstream>
#include <stdexcept>

#include "home.planet.h"
#include "icars/planet/publisher.h"
#include "icars/planet/stream.h"

namespace icars::home {

namespace p = icars::planet;

namespace {

constexpr std::string_view kSpeechMagic = "SIMSPEECH1";
constexpr double kHearingThresholdDb = 25.0;  // default: quieter sounds are not detected
constexpr double kRecognitionThresholdDb = 35.0;  // quieter speech is not understood

std::int64_t ms(Time t) { return static_cast<std::int64_t>(t.count()); }

void check_range(const char* what, std::int32_t v, std::int32_t lo, std::int32_t hi) {
  if (v < lo || v > hi) throw home::OutOfRange(what, v, lo, hi, fmt::format("{} {} is outside {}..{}", what, v, lo, hi));
}

std::string room_of(const sim::World& world, sim::Point at) {
  const auto* room = world.house().room_at(at);
  return room ? room->name : std::string();
}

// --- Actuators -------------------------------------------------------------------------------

// Tells SimContext::effects what an actuator did, stamped with the clock's time. Call it after
// the state changed, with the device's lock released.
class EffectReporter {
 public:
  EffectReporter(std::string device, const SimContext& context)
      : device_(std::move(device)), world_(context.world), observer_(context.effects) {}
  void operator()(std::string what, std::string value, const p::Current& current) const {
    if (!observer_) return;
    observer_(DeviceEffect{world_.clock().now(), device_, std::move(what), std::move(value),
                           current.request_id});
  }

 private:
  std::string device_;
  sim::World& world_;
  EffectObserver observer_;
};

std::string on_off(bool on) { return on ? "on" : "off"; }

// An actuator's state, kept in the state file when there is one: a change is recorded there
// under the actuator's lock (so the file never holds an older state than the device) and on
// disk before change() returns, so before the command's reply.
template <class State>
class KeptState {
 public:
  KeptState(std::string id, SimStateFile* file, State initial)
      : id_(std::move(id)), file_(file), state_(std::move(initial)) {}
  template <class Change>
  void change(Change&& change) {
    {
      std::lock_guard lock(mutex_);
      change(state_);
      if (file_) file_->set(id_, state_);
    }
    if (file_) file_->commit();
  }
  State get() const {
    std::lock_guard lock(mutex_);
    return state_;
  }

 private:
  std::string id_;
  SimStateFile* file_;
  mutable std::mutex mutex_;
  State state_;
};

class SimTV final : public home::TVControlServant {
 public:
  SimTV(const std::string& id, const SimContext& context)
      : report_(id, context), state_(id, context.state, context.state ? context.state->tv(id) : SimTVState{}) {}
  void set_power(bool on, const p::Current& current) override {
    state_.change([&](SimTVState& s) { s.on = on; });
    report_("power", on_off(on), current);
  }
  void set_channel(std::int32_t channel, const p::Current& current) override {
    check_range("channel", channel, 1, 99);
    state_.change([&](SimTVState& s) { s.channel = channel; });
    report_("channel", std::to_string(channel), current);
  }
  void set_volume(std::int32_t volume, const p::Current& current) override {
    check_range("volume", volume, 0, 100);
    state_.change([&](SimTVState& s) { s.volume = volume; });
    report_("volume", std::to_string(volume), current);
  }
  home::TVState state(const p::Current&) override {
    const auto s = state_.get();
    return home::TVState{s.on, s.channel, s.volume};
  }

 private:
  EffectReporter report_;
  KeptState<SimTVState> state_;
};

class SimLight final : public home::LightServant {
 public:
  SimLight(const std::string& id, const SimContext& context)
      : report_(id, context),
        state_(id, context.state, context.state ? context.state->light(id) : SimLightState{}) {}
  void set_power(bool on, const p::Current& current) override {
    state_.change([&](SimLightState& s) { s.on = on; });
    report_("power", on_off(on), current);
  }
  void set_intensity(std::int32_t percent, const p::Current& current) override {
    check_range("intensity", percent, 0, 100);
    state_.change([&](SimLightState& s) { s.intensity = percent; });
    report_("intensity", std::to_string(percent), current);
  }
  home::LightState state(const p::Current&) override {
    const auto s = state_.get();
    return home::LightState{s.on, s.intensity};
  }

 private:
  EffectReporter report_;
  KeptState<SimLightState> state_;
};

class SimSpeaker final : public home::SpeakerServant {
 public:
  SimSpeaker(const std::string& id, const SimContext& context)
      : report_(id, context),
        state_(id, context.state, context.state ? context.state->speaker(id) : SimSpeakerState{}) {}
  void play(const std::string& track, const p::Current& current) override {
    state_.change([&](SimSpeakerState& s) { s.playing = track; });
    report_("playing", track, current);
  }
  void stop(const p::Current& current) override {
    state_.change([](SimSpeakerState& s) { s.playing.clear(); });
    report_("stopped", "", current);
  }
  void set_volume(std::int32_t volume, const p::Current& current) override {
    check_range("volume", volume, 0, 100);
    state_.change([&](SimSpeakerState& s) { s.volume = volume; });
    report_("volume", std::to_string(volume), current);
  }
  void speak(const std::string& text, const p::Current& current) override {
    state_.change([&](SimSpeakerState& s) { s.last_spoken = text; });
    report_("spoke", text, current);
  }
  home::SpeakerState state(const p::Current&) override {
    const auto s = state_.get();
    return home::SpeakerState{s.playing, s.volume, s.last_spoken};
  }

 private:
  EffectReporter report_;
  KeptState<SimSpeakerState> state_;
};

// --- Sensors ---------------------------------------------------------------------------------

// Removes its World listener when destroyed.
class WorldListener {
 public:
  explicit WorldListener(sim::World& world) : world_(world) {}
  ~WorldListener() {
    if (id_ != 0) world_.remove_listener(id_);
  }
  WorldListener(const WorldListener&) = delete;
  WorldListener& operator=(const WorldListener&) = delete;
  void set(std::uint64_t id) { id_ = id; }

 private:
  sim::World& world_;
  std::uint64_t id_ = 0;
};

class SimMicrophone final : public home::MicrophoneServant {
 public:
  SimMicrophone(std::string id, SimContext context, double threshold_db)
      : id_(std::move(id)), threshold_db_(threshold_db), world_(context.world),
        communicator_(context.communicator), listener_(context.world) {
    listener_.set(world_.on_utterance([this](const sim::Utterance& u) { hear(u); }));
  }
  void subscribe(home::SoundListenerPrx listener, const p::Current&) override {
    sounds_.subscribe(listener);
  }
  void unsubscribe(home::SoundListenerPrx listener, const p::Current&) override {
    sounds_.unsubscribe(listener);
  }
  // Ambient sound: silence with a little noise, `milliseconds` of 16 kHz 16-bit PCM, written at
  // the speed the reader pulls.
  p::StreamRef record(std::int32_t milliseconds, const p::Current&) override {
    check_range("milliseconds", milliseconds, 1, 600000);
    auto out = p::OutputStream::create(communicator_);
    asio::co_spawn(communicator_.executor(), write_ambient(out, milliseconds), asio::detached);
    return out->ref();
  }

 private:
  static asio::awaitable<void> write_ambient(std::shared_ptr<p::OutputStream> out, std::int32_t ms_total) {
    std::uint32_t noise = 12345;
    try {
      for (std::int32_t done = 0; done < ms_total; done += 100) {
        std::vector<std::byte> block(32 * static_cast<std::size_t>(std::min(100, ms_total - done)));
        for (auto& b : block) {
          noise = noise * 1103515245u + 12345u;
          b = static_cast<std::byte>((noise >> 16) & 0x07);
        }
        co_await out->async_write(std::move(block), asio::use_awaitable);
      }
      out->close();
    } catch (const p::Error&) {
      // The reader went away.
    }
  }

  void hear(const sim::Utterance& u) {
    const sim::Pose at = world_.device_pose(id_);
    const double level = world_.sound_level(u, at.position());
    if (level < threshold_db_) return;
    home::SoundEvent e;
    e.device = id_;
    e.direction = std::atan2(u.at.y - at.y, u.at.x - at.x);
    e.level_db = level;
    e.room = room_of(world_, at.position());
    e.time_ms = ms(u.time);
    e.audio = SimulatedSpeech::encode(u.text, level);
    sounds_.publish(e);
  }

  std::string id_;
  double threshold_db_;
  sim::World& world_;
  p::Communicator& communicator_;
  p::Publisher<home::SoundEvent> sounds_{home::SoundListener::on_sound};
  WorldListener listener_;
};

class SimWheels final : public home::WheelsServant {
 public:
  SimWheels(std::string robot, std::string device, SimContext context)
      : robot_(std::move(robot)), world_(context.world), report_(std::move(device), context),
        file_(context.state), listener_(context.world) {
    listener_.set(world_.on_robot_pose(
        [this](const std::string& which, const sim::Pose& pose, bool moving) {
          if (which != robot_) return;
          // A motion is kept as its path (the clock carries it on): only its end is a change.
          if (!moving && file_) file_->changed();
          {
            // Stopping at the goal is reported once, as the arrival (by move's done), so a
            // listener never mistakes the arrival's last pose for a stop short of the goal.
            std::lock_guard lock(mutex_);
            if (!moving && goal_ && sim::distance(pose.position(), *goal_) < 1e-3) return;
          }
          publish(pose, moving, false);
        }));
    if (file_) file_->on_restore_robot(robot_, [this](const sim::RobotState& s) { restore(s); });
  }
  double go_to(const home::Pose& target, const p::Current& current) override {
    const auto name = fmt::format("({:.2f}, {:.2f})", target.x, target.y);
    const double length = move({target.x, target.y}, name);
    if (file_) file_->commit();
    report_("going_to", name, current);
    return length;
  }
  double go_to_waypoint(const std::string& waypoint, const p::Current& current) override {
    const auto at = world_.house().locate(waypoint);
    if (!at) throw home::UnknownTarget(waypoint, "no waypoint, furniture or room '" + waypoint + "'");
    const double length = move(*at, waypoint);
    if (file_) file_->commit();
    report_("going_to", waypoint, current);
    return length;
  }
  void stop(const p::Current& current) override {
    forget_goal();
    world_.stop_robot(robot_);
    if (file_) file_->commit();
    report_("halted", "", current);
  }
  // The position event that follows (from the clock) has the new heading, not moving.
  void turn_to(double theta, const p::Current& current) override {
    forget_goal();
    world_.turn_robot(robot_, theta);
    if (file_) file_->commit();
    report_("turned", fmt::format("{:.2f}", theta), current);
  }
  home::Pose position(const p::Current&) override {
    const auto pose = world_.robot_pose(robot_);
    return home::Pose{pose.x, pose.y, pose.theta};
  }
  std::string room(const p::Current&) override { return world_.robot_room(robot_); }
  void subscribe(home::PositionListenerPrx listener, const p::Current&) override {
    positions_.subscribe(listener);
  }
  void unsubscribe(home::PositionListenerPrx listener, const p::Current&) override {
    positions_.unsubscribe(listener);
  }

 private:
  double move(sim::Point target, const std::string& name) {
    std::lock_guard lock(mutex_);  // the first report comes from the clock, after goal_ is set
    auto path = world_.move_robot(robot_, target, [this](bool arrived) {
      if (arrived) publish(world_.robot_pose(robot_), false, true);
    });
    if (!path) throw home::UnknownTarget(name, "no path from the robot to " + name);
    goal_ = path->empty() ? target : path->back();
    double length = 0;
    for (std::size_t i = 1; i < path->size(); ++i) length += sim::distance((*path)[i - 1], (*path)[i]);
    return length;
  }
  void publish(const sim::Pose& pose, bool moving, bool arrived) {
    positions_.publish(home::PositionEvent{robot_, pose.x, pose.y, pose.theta,
                                           room_of(world_, pose.position()), moving, arrived,
                                           ms(world_.clock().now())});
  }

  void forget_goal() {
    std::lock_guard lock(mutex_);
    goal_.reset();
  }

  // Back to the state file's pose or motion; a restored motion's arrival is published as a
  // go_to's is.
  void restore(const sim::RobotState& state) {
    std::lock_guard lock(mutex_);
    goal_.reset();
    if (state.moving()) goal_ = state.path.back();
    world_.restore_robot(state, [this](bool arrived) {
      if (arrived) publish(world_.robot_pose(robot_), false, true);
    });
  }

  std::string robot_;
  sim::World& world_;
  EffectReporter report_;
  SimStateFile* file_;
  p::Publisher<home::PositionEvent> positions_{home::PositionListener::on_position};
  std::mutex mutex_;
  std::optional<sim::Point> goal_;  // where the current move ends
  WorldListener listener_;
};

class SimMotionSensor final : public home::MotionSensorServant {
 public:
  SimMotionSensor(std::string id, std::string room, SimContext context)
      : id_(std::move(id)), room_(std::move(room)), world_(context.world), listener_(context.world) {
    listener_.set(world_.on_user([this](const sim::UserState& u) { update(u); }));
  }
  bool motion(const p::Current&) override {
    std::lock_guard lock(mutex_);
    return !present_.empty();
  }
  void subscribe(home::MotionListenerPrx l, const p::Current&) override { events_.subscribe(l); }
  void unsubscribe(home::MotionListenerPrx l, const p::Current&) override { events_.unsubscribe(l); }

 private:
  void update(const sim::UserState& u) {
    bool changed = false;
    bool motion = false;
    {
      std::lock_guard lock(mutex_);
      const bool was = !present_.empty();
      if (u.room == room_) {
        present_.insert(u.user);
      } else {
        present_.erase(u.user);
      }
      motion = !present_.empty();
      changed = was != motion;
    }
    if (changed) events_.publish(home::MotionEvent{id_, room_, motion, ms(world_.clock().now())});
  }

  std::string id_;
  std::string room_;
  sim::World& world_;
  std::mutex mutex_;
  std::set<std::string> present_;
  p::Publisher<home::MotionEvent> events_{home::MotionListener::on_motion};
  WorldListener listener_;
};

class SimOccupancySensor final : public home::OccupancySensorServant {
 public:
  SimOccupancySensor(std::string id, std::string furniture, SimContext context)
      : id_(std::move(id)), furniture_(std::move(furniture)), world_(context.world),
        listener_(context.world), occupied_(world_.occupied(furniture_)) {
    listener_.set(world_.on_user([this](const sim::UserState&) { update(); }));
  }
  bool occupied(const p::Current&) override { return world_.occupied(furniture_); }
  std::string furniture(const p::Current&) override { return furniture_; }
  void subscribe(home::OccupancyListenerPrx l, const p::Current&) override { events_.subscribe(l); }
  void unsubscribe(home::OccupancyListenerPrx l, const p::Current&) override { events_.unsubscribe(l); }

 private:
  void update() {
    const bool now = world_.occupied(furniture_);
    if (occupied_.exchange(now) == now) return;
    events_.publish(home::OccupancyEvent{id_, furniture_, now, ms(world_.clock().now())});
  }

  std::string id_;
  std::string furniture_;
  sim::World& world_;
  WorldListener listener_;
  std::atomic<bool> occupied_;
  p::Publisher<home::OccupancyEvent> events_{home::OccupancyListener::on_occupancy};
};

// The camera sees the users in its room within `range` metres; its image lists them.
class SimCamera final : public home::CameraServant {
 public:
  SimCamera(std::string id, SimContext context, double range)
      : id_(std::move(id)), world_(context.world), range_(range) {}
  home::Image capture(const p::Current&) override {
    const sim::Pose at = world_.device_pose(id_);
    const std::string room = room_of(world_, at.position());
    std::ostringstream scene;
    for (const auto& spec : world_.house().users) {
      const auto user = world_.user(spec.id);
      if (user.room != room || sim::distance(user.at, at.position()) > range_) continue;
      scene << spec.id << ' ' << user.at.x << ' ' << user.at.y << '\n';
    }
    const std::string text = scene.str();
    home::Image image;
    image.width = 640;
    image.height = 480;
    image.encoding = "sim/scene";
    image.time_ms = ms(world_.clock().now());
    image.camera = home::Pose{at.x, at.y, at.theta};
    image.data.bytes.resize(text.size());
    if (!text.empty()) std::memcpy(image.data.bytes.data(), text.data(), text.size());
    return image;
  }

 private:
  std::string id_;
  sim::World& world_;
  double range_;
};

class SimClockDevice final : public home::ClockServant {
 public:
  explicit SimClockDevice(sim::World& world) : world_(world) {}
  std::int64_t now_ms(const p::Current&) override { return ms(world_.clock().now()); }
  std::string time_of_day(const p::Current&) override {
    const std::string full = format_time(world_.clock().now());  // "dN HH:MM:SS"
    return full.substr(full.find(' ') + 1);
  }

 private:
  sim::World& world_;
};

// --- Software devices ------------------------------------------------------------------------

class SimSpeechRecognizer final : public home::SpeechRecognizerServant {
 public:
  home::Recognition recognize(const p::Binary& audio, const p::Current&) override {
    const auto speech = SimulatedSpeech::decode(audio);
    if (!speech) throw home::NotRecognized("no speech in the audio", "not speech");
    if (speech->level_db < kRecognitionThresholdDb) {
      throw home::NotRecognized(fmt::format("speech too quiet ({:.0f} dB)", speech->level_db),
                                "speech too quiet");
    }
    const double confidence = std::min(0.99, 0.5 + (speech->level_db - kRecognitionThresholdDb) / 50);
    return home::Recognition{speech->text, confidence};
  }
};

class SimFaceRecognizer final : public home::FaceRecognizerServant {
 public:
  std::vector<home::Face> recognize(const home::Image& image, const p::Current&) override {
    if (image.encoding != "sim/scene") return {};
    std::istringstream scene(std::string(reinterpret_cast<const char*>(image.data.bytes.data()),
                                         image.data.bytes.size()));
    std::vector<home::Face> faces;
    home::Face f;
    while (scene >> f.person >> f.x >> f.y) {
      f.confidence = 0.95;
      faces.push_back(f);
    }
    return faces;
  }
};

class SimulationControl final : public home::SimulationServant {
 public:
  explicit SimulationControl(SimContext context) : world_(context.world) {}
  void say(const std::string& user, const std::string& text, const p::Current&) override {
    if (!world_.house().user(user)) {
      throw p::RemoteException("icars::home::UnknownUser", "no user '" + user + "' in the house");
    }
    world_.say(user, text);
  }
  std::string now(const p::Current&) override { return format_time(world_.clock().now()); }
  std::int64_t now_ms(const p::Current&) override { return ms(world_.clock().now()); }

 private:
  sim::World& world_;
};

std::string param(const sim::DeviceSpec& spec, const std::string& name, std::string fallback) {
  auto it = spec.params.find(name);
  return it == spec.params.end() ? fallback : it->second;
}

double number_param(const sim::DeviceSpec& spec, const std::string& name, double fallback) {
  auto it = spec.params.find(name);
  if (it == spec.params.end()) return fallback;
  try {
    std::size_t used = 0;
    const double v = std::stod(it->second, &used);
    if (used == it->second.size()) return v;
  } catch (const std::exception&) {
  }
  throw std::invalid_argument("device " + spec.id + ": parameter " + name + " = '" + it->second +
                              "' is not a number");
}

}  // namespace

// --- Simulated speech audio ------------------------------------------------------------------

planet::Binary SimulatedSpeech::encode(const std::string& text, double level_db) {
  // Header, level, text; then ~60 ms of low noise per character, like a real utterance's length.
  planet::Binary audio;
  std::vector<std::byte>& b = audio.bytes;
  const std::size_t samples = 960 * text.size();
  b.reserve(kSpeechMagic.size() + 12 + text.size() + 2 * samples);
  b.resize(kSpeechMagic.size());
  std::memcpy(b.data(), kSpeechMagic.data(), kSpeechMagic.size());
  planet::Writer w(b);
  w.f64(level_db);
  w.str(text);
  std::uint32_t noise = 0x9E3779B9u ^ static_cast<std::uint32_t>(text.size());
  for (std::size_t i = 0; i < 2 * samples; ++i) {
    noise = noise * 1664525u + 1013904223u;
    b.push_back(static_cast<std::byte>((noise >> 24) & 0x0F));
  }
  return audio;
}

std::optional<SimulatedSpeech::Decoded> SimulatedSpeech::decode(const planet::Binary& audio) {
  if (audio.bytes.size() < kSpeechMagic.size() + 12 ||
      std::memcmp(audio.bytes.data(), kSpeechMagic.data(), kSpeechMagic.size()) != 0) {
    return std::nullopt;
  }
  try {
    planet::Reader r(std::span(audio.bytes).subspan(kSpeechMagic.size()));
    Decoded d;
    d.level_db = r.f64();
    d.text = r.str();
    return d;
  } catch (const planet::Error&) {
    return std::nullopt;
  }
}

// --- Factories -------------------------------------------------------------------------------

void SimDeviceTypes::add(const std::string& type, std::string description, MakeSimDevice make) {
  if (has(type)) throw std::invalid_argument("simulated device type '" + type + "' is already registered");
  if (!make) throw std::invalid_argument("simulated device type '" + type + "' has no factory");
  types_.push_back({type, std::move(description), std::move(make)});
}

bool SimDeviceTypes::has(const std::string& type) const {
  return std::any_of(types_.begin(), types_.end(), [&](const Type& t) { return t.name == type; });
}

std::vector<std::string> SimDeviceTypes::names() const {
  std::vector<std::string> names;
  for (const auto& t : types_) names.push_back(t.name);
  return names;
}

const std::string& SimDeviceTypes::description(const std::string& type) const {
  static const std::string none;
  for (const auto& t : types_) {
    if (t.name == type) return t.description;
  }
  return none;
}

void SimDeviceTypes::merge(SimDeviceTypes&& other) {
  for (auto& t : other.types_) add(t.name, std::move(t.description), std::move(t.make));
  other.types_.clear();
}

namespace {

std::string unknown_type(const sim::DeviceSpec& spec, const std::vector<std::string>& types) {
  std::string known;
  for (std::size_t i = 0; i < types.size(); ++i) {
    known += (i == 0 ? "" : i + 1 == types.size() ? " or " : ", ") + types[i];
  }
  return "device " + spec.id + " has type '" + spec.type +
         "', which has no simulated implementation (expected " + known + ")";
}

}  // namespace

void SimDeviceTypes::check(const sim::House& house) const {
  for (const auto& spec : house.devices) {
    if (!has(spec.type)) throw sim::HouseError(house.source, spec.line, unknown_type(spec, names()));
  }
}

std::shared_ptr<device::Device> SimDeviceTypes::make(const sim::DeviceSpec& spec, SimContext context) const {
  for (const auto& t : types_) {
    if (t.name == spec.type) return t.make(spec, context);
  }
  throw std::invalid_argument(unknown_type(spec, names()));
}

namespace {

// A device of the house with one capability, made by `make(spec, context)`.
template <class Make>
MakeSimDevice one_capability(std::string capability, Make make) {
  return [capability = std::move(capability), make = std::move(make)](const sim::DeviceSpec& spec, SimContext context) {
    auto device = std::make_shared<device::Device>(spec.id, spec.type, spec.room, spec.carrier);
    device->add(capability, make(spec, context));
    return device;
  };
}

SimDeviceTypes make_home_types() {
  SimDeviceTypes types;
  types.add("TV", "a television: tv_control (home::TVControl)", one_capability("tv_control", [](const sim::DeviceSpec& spec, SimContext c) {
    return std::make_shared<SimTV>(spec.id, c);
  }));
  types.add("Light", "a dimmable light: light (home::Light)", one_capability("light", [](const sim::DeviceSpec& spec, SimContext c) {
    return std::make_shared<SimLight>(spec.id, c);
  }));
  types.add("Speaker", "a speaker: speaker (home::Speaker)", one_capability("speaker", [](const sim::DeviceSpec& spec, SimContext c) {
    return std::make_shared<SimSpeaker>(spec.id, c);
  }));
  types.add("Microphone", "a microphone hearing speech: sound_sensor (home::Microphone); param threshold_db",
            one_capability("sound_sensor", [](const sim::DeviceSpec& spec, SimContext c) {
              return std::make_shared<SimMicrophone>(spec.id, c, number_param(spec, "threshold_db", kHearingThresholdDb));
            }));
  types.add("Wheels", "a robot's wheels: wheels (home::Wheels); carried by a robot",
            one_capability("wheels", [](const sim::DeviceSpec& spec, SimContext c) {
              if (spec.carrier.empty()) throw std::invalid_argument("wheels " + spec.id + " belong to no robot");
              return std::make_shared<SimWheels>(spec.carrier, spec.id, c);
            }));
  types.add("Camera", "a camera: camera (home::Camera); param range",
            one_capability("camera", [](const sim::DeviceSpec& spec, SimContext c) {
              return std::make_shared<SimCamera>(spec.id, c, number_param(spec, "range", 6.0));
            }));
  types.add("MotionSensor", "a motion sensor: motion (home::MotionSensor); param room",
            one_capability("motion", [](const sim::DeviceSpec& spec, SimContext c) {
              return std::make_shared<SimMotionSensor>(spec.id, param(spec, "room", spec.room), c);
            }));
  for (const std::string t : {"BedOccupancy", "SofaOccupancy", "Occupancy"}) {
    const std::string fallback = t == "BedOccupancy" ? "bed" : t == "SofaOccupancy" ? "sofa" : "";
    types.add(t, "an occupancy sensor: occupancy (home::OccupancySensor); param furniture",
              one_capability("occupancy", [fallback](const sim::DeviceSpec& spec, SimContext c) {
                const std::string furniture = param(spec, "furniture", fallback);
                if (!c.world.house().find_furniture(furniture)) {
                  throw std::invalid_argument("occupancy sensor " + spec.id + " watches unknown furniture '" +
                                              furniture + "'");
                }
                return std::make_shared<SimOccupancySensor>(spec.id, furniture, c);
              }));
  }
  types.add("Clock", "the house's clock: clock (home::Clock)", one_capability("clock", [](const sim::DeviceSpec&, SimContext c) {
    return std::make_shared<SimClockDevice>(c.world);
  }));
  types.add("SpeechEngine", "a speech recognizer: speech_recognizer (home::SpeechRecognizer)",
            one_capability("speech_recognizer", [](const sim::DeviceSpec&, SimContext) {
              return std::make_shared<SimSpeechRecognizer>();
            }));
  types.add("VisionEngine", "a face recognizer: face_recognizer (home::FaceRecognizer)",
            one_capability("face_recognizer", [](const sim::DeviceSpec&, SimContext) {
              return std::make_shared<SimFaceRecognizer>();
            }));
  return types;
}

}  // namespace

const SimDeviceTypes& sim_device_types() {
  static const SimDeviceTypes types = make_home_types();
  return types;
}

std::shared_ptr<device::Device> make_sim_device(const sim::DeviceSpec& spec, SimContext context) {
  return sim_device_types().make(spec, context);
}

std::vector<std::shared_ptr<device::Device>> make_sim_engines(SimContext context) {
  sim::DeviceSpec speech;
  speech.id = std::string(kSpeechEngineId);
  speech.type = "SpeechEngine";
  sim::DeviceSpec vision;
  vision.id = std::string(kVisionEngineId);
  vision.type = "VisionEngine";
  return {make_sim_device(speech, context), make_sim_device(vision, context)};
}

std::shared_ptr<device::Device> make_simulator_device(SimContext context) {
  auto device = std::make_shared<device::Device>(std::string(kSimulatorId), "Simulator");
  device->add("simulation", std::make_shared<SimulationControl>(context));
  return device;
}

}  // namespace icars::home
