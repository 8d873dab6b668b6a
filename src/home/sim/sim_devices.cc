#include "icars/home/sim/sim_devices.h"

#include <fmt/format.h>

#include <asio/co_spawn.hpp>
#include <asio/detached.hpp>
#include <asio/use_awaitable.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <numbers>
#include <optional>
#include <set>
#include <sstream>
#include <stdexcept>

#include "home.planet.h"
#include "icars/planet/publisher.h"
#include "icars/planet/stream.h"
#include "icars/audio/acoustics.h"
#include "icars/audio/audio_stream.h"
#include "icars/audio/synthesizer.h"
#include "icars/home/microphone.h"
#include "icars/home/speech_recognizer.h"

namespace icars::home {

namespace p = icars::planet;

namespace {

constexpr double kHearingThresholdDb = 25.0;  // default: quieter sounds are not detected

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
      : report_(id, context), state_(id, context.state, context.state ? context.state->tv(id) : SimTVState{}) {
    if (context.state) run_on(context.state->command_executor());  // commands wait for the disk
  }
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
        state_(id, context.state, context.state ? context.state->light(id) : SimLightState{}) {
    if (context.state) run_on(context.state->command_executor());  // commands wait for the disk
  }
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
        state_(id, context.state, context.state ? context.state->speaker(id) : SimSpeakerState{}) {
    if (context.state) run_on(context.state->command_executor());  // commands wait for the disk
  }
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

// What a simulated microphone array is: where its microphones are and the room it hears.
struct MicSetup {
  double threshold_db = kHearingThresholdDb;
  std::vector<audio::MicPosition> mics{{0, 0}};
  audio::RoomSound room;
};

// A simulated microphone (or array): every utterance of the world is synthesized with the
// speaker's voice (espeak-ng) and rendered as each of its microphones hears it (distance,
// walls, the room's reverberation and noise; audio::render), then delivered on its captures in
// frames as the clock passes their time, like a sound card. Stretches in which it hears nobody
// are left out of the stream (the reader takes the gap for silence): a night of silence costs
// nothing.
class SimMicrophone final : public home::MicrophoneServant {
 public:
  SimMicrophone(std::string id, SimContext context, MicSetup setup)
      : core_(std::make_shared<Core>(std::move(id), context, std::move(setup))), listener_(context.world) {
    listener_.set(context.world.on_utterance([core = std::weak_ptr<Core>(core_)](const sim::Utterance& u) {
      if (auto c = core.lock()) c->hear(u);
    }));
  }
  ~SimMicrophone() override {
    std::lock_guard lock(core_->mutex);
    if (core_->timer != 0) core_->world.clock().cancel(core_->timer);
    core_->timer = 0;
  }
  home::MicrophoneInfo info(const p::Current&) override {
    return microphone_info({audio::kSpeechRate, static_cast<int>(core_->setup.mics.size())}, core_->setup.mics,
                           core_->setup.threshold_db, "sim");
  }
  p::StreamRef capture(std::int64_t since, const p::Current&) override {
    return core_->captures.open(static_cast<std::uint64_t>(std::max<std::int64_t>(0, since)));
  }

 private:
  static constexpr std::uint64_t kFramesPerMs = audio::kSpeechRate / 1000;
  static constexpr Time kDeliveryPeriod{100};  // frames go out in batches of this much audio

  struct Core : std::enable_shared_from_this<Core> {
    Core(std::string i, SimContext c, MicSetup s)
        : id(std::move(i)), world(c.world), setup(std::move(s)), captures(c.communicator) {}

    void hear(const sim::Utterance& u) {
      if (!captures.listened_to()) return;  // nobody ever listened: nothing to render
      const sim::Pose at = world.device_pose(id);
      if (world.sound_level(u, at.position()) < setup.threshold_db - 20.0) return;  // far out of hearing
      std::vector<audio::Path> paths;
      for (const auto& m : setup.mics) {
        const sim::Point p{at.x + std::cos(at.theta) * m.x - std::sin(at.theta) * m.y,
                           at.y + std::sin(at.theta) * m.x + std::cos(at.theta) * m.y};
        paths.push_back({std::hypot(p.x - u.at.x, p.y - u.at.y), world.sound_level(u, p)});
      }
      const auto* user = world.house().user(u.user);
      audio::Voice voice;
      if (user) voice.name = user->voice;
      audio::AudioBlock heard;
      try {
        const auto speech = synthesizer.speak(u.text, voice);
        auto room = setup.room;
        room.seed = setup.room.seed ^ std::hash<std::string>{}(u.user + "|" + u.text) ^
                    static_cast<std::uint64_t>(u.time.count());
        heard = audio::render(speech, paths, room, kLead, kTail);
      } catch (const std::exception& e) {
        std::fprintf(stderr, "microphone %s: could not render \"%s\": %s\n", id.c_str(), u.text.c_str(), e.what());
        return;
      }
      const auto lead_frames = static_cast<std::uint64_t>(kLead * audio::kSpeechRate);
      const auto said = static_cast<std::uint64_t>(std::max<std::int64_t>(0, u.time.count())) * kFramesPerMs;
      heard.start = said > lead_frames ? said - lead_frames : 0;
      std::lock_guard lock(mutex);
      mix(std::move(heard));
      schedule();
    }

    // Adds `block` to what is still to be delivered (several voices at once add up).
    void mix(audio::AudioBlock block) {
      const auto channels = static_cast<std::size_t>(block.format.channels);
      if (block.start < delivered_until) {  // what was already delivered cannot change
        const auto skip = std::min<std::uint64_t>(delivered_until - block.start, block.frames());
        block.samples.erase(block.samples.begin(), block.samples.begin() + static_cast<std::ptrdiff_t>(skip * channels));
        block.start += skip;
      }
      if (block.frames() == 0) return;
      if (pending.samples.empty()) {
        pending = std::move(block);
        return;
      }
      const auto start = std::min(pending.start, block.start);
      const auto end = std::max(pending.end(), block.end());
      if (end - start > kMaxPendingSeconds * audio::kSpeechRate) {
        // Voices over voices faster than the clock delivers them (a flood of Simulation.say):
        // what would not fit is not heard, rather than kept without bound.
        std::fprintf(stderr, "microphone %s: more than %d s of sound waiting; an utterance is dropped\n", id.c_str(),
                     kMaxPendingSeconds);
        return;
      }
      audio::AudioBlock merged;
      merged.format = pending.format;
      merged.start = start;
      merged.samples.assign((end - start) * channels, 0);
      for (const auto* part : {&pending, &block}) {
        const auto offset = (part->start - start) * channels;
        for (std::size_t i = 0; i < part->samples.size(); ++i) {
          const int sum = merged.samples[offset + i] + part->samples[i];
          merged.samples[offset + i] = static_cast<std::int16_t>(std::clamp(sum, -32768, 32767));
        }
      }
      pending = std::move(merged);
    }

    void schedule() {
      if (timer != 0 || pending.samples.empty()) return;
      timer = world.clock().schedule_at(world.clock().now(), [weak = weak_from_this()] {
        if (auto self = weak.lock()) self->deliver();
      });
    }

    // Sends what the clock has passed, and comes back for the rest.
    void deliver() {
      audio::AudioBlock out;
      {
        std::lock_guard lock(mutex);
        timer = 0;
        if (pending.samples.empty()) return;
        const auto now = static_cast<std::uint64_t>(std::max<std::int64_t>(0, world.clock().now().count())) * kFramesPerMs;
        const auto until = std::min(pending.end(), std::max(now, pending.start));
        const auto channels = static_cast<std::size_t>(pending.format.channels);
        const auto count = (until - pending.start) * channels;
        out.format = pending.format;
        out.start = pending.start;
        out.samples.assign(pending.samples.begin(), pending.samples.begin() + static_cast<std::ptrdiff_t>(count));
        pending.samples.erase(pending.samples.begin(), pending.samples.begin() + static_cast<std::ptrdiff_t>(count));
        pending.start = until;
        delivered_until = std::max(delivered_until, until);
        if (!pending.samples.empty()) {
          timer = world.clock().schedule_at(world.clock().now() + kDeliveryPeriod, [weak = weak_from_this()] {
            if (auto self = weak.lock()) self->deliver();
          });
        }
      }
      captures.push(out);
    }

    static constexpr int kMaxPendingSeconds = 60;
    static constexpr double kLead = 0.2;  // s of the room before the voice
    static constexpr double kTail = 0.6;  // s after it: its reverberation, and quiet for the detector

    std::string id;
    sim::World& world;
    MicSetup setup;
    CaptureStreams captures;
    audio::Synthesizer synthesizer;
    std::mutex mutex;
    audio::AudioBlock pending;           // rendered, not yet delivered
    std::uint64_t delivered_until = 0;   // frame index
    std::uint64_t timer = 0;             // the delivery scheduled on the clock, 0: none
  };

  std::shared_ptr<Core> core_;
  WorldListener listener_;
};

class SimWheels final : public home::WheelsServant {
 public:
  SimWheels(std::string robot, std::string device, SimContext context)
      : robot_(std::move(robot)), world_(context.world), report_(std::move(device), context),
        file_(context.state), listener_(context.world) {
    if (file_) run_on(file_->command_executor());  // commands wait for the disk
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
  types.add("Microphone",
            "a microphone or microphone array hearing the house, or a real one: sound_sensor (home::Microphone); "
            "params threshold_db, channels, array_radius, noise_db, rt60, source (docs/speech.md)",
            one_capability("sound_sensor", [](const sim::DeviceSpec& spec, SimContext c) -> std::shared_ptr<p::Servant> {
              const double threshold = number_param(spec, "threshold_db", kHearingThresholdDb);
              const auto channels = number_param(spec, "channels", 1);
              if (channels < 1 || channels > audio::kMaxChannels || channels != std::floor(channels)) {
                throw std::invalid_argument(fmt::format("device {}: parameter channels = {} is not 1 to {}", spec.id,
                                                        channels, audio::kMaxChannels));
              }
              const double radius = number_param(spec, "array_radius", 0.05);
              if (radius <= 0 || radius > 1) {
                throw std::invalid_argument(fmt::format("device {}: parameter array_radius = {} m is not in (0, 1]", spec.id, radius));
              }
              // One microphone at the device; two, left and right (a pair tells left from right, not
              // front from back); more, on a circle with the first straight ahead.
              auto mics = channels == 1   ? std::vector<audio::MicPosition>{{0, 0}}
                          : channels == 2 ? std::vector<audio::MicPosition>{{0, radius}, {0, -radius}}
                                          : audio::circular_array(static_cast<int>(channels), radius);
              const auto source = param(spec, "source", "sim");
              if (source != "sim") {
                audio::SourceOptions options;
                options.format.channels = static_cast<int>(channels);
                auto mic = std::make_shared<SourceMicrophone>(audio::open_source(source, options), source, c.world.clock(),
                                                              c.communicator, std::move(mics), threshold);
                mic->start();
                return mic;
              }
              MicSetup setup;
              setup.threshold_db = threshold;
              setup.mics = std::move(mics);
              setup.room.noise_db = number_param(spec, "noise_db", setup.room.noise_db);
              setup.room.rt60 = number_param(spec, "rt60", setup.room.rt60);
              if (!(setup.room.rt60 >= 0 && setup.room.rt60 <= audio::kMaxRt60)) {
                throw std::invalid_argument(fmt::format("device {}: parameter rt60 = {} s is not in 0..{}", spec.id,
                                                        setup.room.rt60, audio::kMaxRt60));
              }
              setup.room.seed = c.world.house().seed ^ std::hash<std::string>{}(spec.id);
              return std::make_shared<SimMicrophone>(spec.id, c, std::move(setup));
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
  types.add("SpeechEngine",
            "a speech recognizer: speech_recognizer (home::SpeechRecognizer); params model_dir (a PocketSphinx "
            "model directory; default: the one adapted to the simulated voices, or the stock one), room_rt60 "
            "(seconds of reverberation suppressed before decoding; default 0: none)",
            one_capability("speech_recognizer", [](const sim::DeviceSpec& spec, SimContext) {
              audio::RecognizerOptions options;
              options.model_dir = param(spec, "model_dir", sim_speech_model_dir());
              options.room_rt60 = number_param(spec, "room_rt60", options.room_rt60);
              return std::make_shared<SpeechRecognizerDevice>(options);
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

std::string sim_speech_model_dir() {
  const std::filesystem::path adapted = ICARS_SIM_SPEECH_MODEL_DIR;
  return std::filesystem::exists(adapted / "en-us" / "sendump") ? adapted.string() : std::string();
}

double sim_room_rt60(const sim::House& house) {
  std::optional<double> shortest;
  for (const auto& spec : house.devices) {
    if (spec.type != "Microphone" || param(spec, "source", "sim") != "sim") continue;
    const double rt60 = number_param(spec, "rt60", audio::RoomSound{}.rt60);
    shortest = std::min(shortest.value_or(rt60), rt60);
  }
  return shortest.value_or(0.0);
}

std::vector<std::shared_ptr<device::Device>> make_sim_engines(SimContext context, const std::string& speech_model_dir) {
  sim::DeviceSpec speech;
  speech.id = std::string(kSpeechEngineId);
  speech.type = "SpeechEngine";
  speech.params["model_dir"] = speech_model_dir;
  speech.params["room_rt60"] = fmt::format("{}", sim_room_rt60(context.world.house()));
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
