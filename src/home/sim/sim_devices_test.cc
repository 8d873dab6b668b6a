// The simulated devices over real PLANET connections, with the simulated clock advanced by
// hand: every capability answers as its IDL says, sensors publish when the simulated user
// does something, out-of-range commands are refused with a typed exception, actuators report
// what they did, the wheels turn in place, and simulated speech round-trips through the speech
// engine only when it is loud enough. With a state file, every acknowledged command is on
// disk, a restart starts from it (a driving robot drives on with the clock), and a corrupt or
// mismatching file is set aside with the reason.
#include <gtest/gtest.h>

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <future>
#include <mutex>
#include <nlohmann/json.hpp>
#include <numbers>
#include <thread>

#include "child_process.h"
#include "test_directory.h"
#include "icars/audio/acoustics.h"
#include "icars/audio/audio_stream.h"
#include "icars/audio/pcm.h"
#include "icars/audio/recognizer.h"
#include "icars/audio/synthesizer.h"
#include "home.planet.h"
#include "icars/device/device_manager.h"
#include "icars/home/sim/sim_devices.h"
#include "icars/home/sim/sim_state_file.h"
#include "icars/home/sim/simulated_house.h"
#include "icars/planet/stream.h"
#include "icars/sim/house.h"

namespace icars::home {
namespace {

using namespace std::chrono_literals;
namespace p = icars::planet;

// The paper's house plus a motion sensor in the bedroom and a clock, hosted on one
// communicator; the test calls the capabilities through a second one, over loopback.
class SimDevices : public ::testing::Test {
 protected:
  static sim::House house() {
    sim::House h = sim::load_house(ICARS_PAPER_HOUSE);
    sim::DeviceSpec motion;
    motion.id = "bedroom_motion";
    motion.type = "MotionSensor";
    motion.room = "bedroom";
    motion.pose = {7.0, 1.0, 0};
    sim::DeviceSpec clock;
    clock.id = "clock";
    clock.type = "Clock";
    clock.room = "living_room";
    h.devices.push_back(motion);
    h.devices.push_back(clock);
    return h;
  }

  void SetUp() override {
    const SimContext context{world_, devices_, [this](const DeviceEffect& e) {
                               std::lock_guard lock(effects_mutex_);
                               effects_.push_back(e);
                             }};
    for (const auto& spec : world_.house().devices) manager_.add(make_sim_device(spec, context));
    for (auto& d : make_sim_engines(context)) manager_.add(d);
    manager_.add(make_simulator_device(context));
    peer_ = client_.connect("127.0.0.1", devices_.listen("127.0.0.1", 0));
    ASSERT_TRUE(peer_->wait_connected(20s));
  }
  template <class Prx>
  Prx capability(const std::string& device, const std::string& name) {
    return Prx(client_, peer_, "/devices/" + device + "/" + name);
  }

  std::vector<DeviceEffect> effects() {
    std::lock_guard lock(effects_mutex_);
    return effects_;
  }

  std::mutex effects_mutex_;
  std::vector<DeviceEffect> effects_;  // what the actuators reported, in order
  SimClock clock_{at_time(0, 18, 0)};
  sim::World world_{house(), clock_};
  p::Communicator devices_;
  device::DeviceManager manager_{devices_};
  p::Communicator client_;
  std::shared_ptr<p::Peer> peer_;
};

TEST_F(SimDevices, ActuatorsKeepTheirStateAndRefuseOutOfRangeCommands) {
  auto tv = capability<home::TVControlPrx>("tv", "tv_control");
  tv.set_power(true);
  tv.set_channel(42);
  tv.set_volume(30);
  const auto state = tv.state();
  EXPECT_TRUE(state.on);
  EXPECT_EQ(state.channel, 42);
  EXPECT_EQ(state.volume, 30);
  try {
    tv.set_channel(120);
    FAIL() << "channel 120 accepted";
  } catch (const home::OutOfRange& e) {
    EXPECT_EQ(e.what_is(), "channel");
    EXPECT_EQ(e.requested(), 120);
    EXPECT_EQ(e.max(), 99);
  }
  auto light = capability<home::LightPrx>("bedroom_light", "light");
  light.set_intensity(30);
  EXPECT_EQ(light.state().intensity, 30);
  EXPECT_THROW(light.set_intensity(-1), home::OutOfRange);
  auto speaker = capability<home::SpeakerPrx>("robot1_speaker", "speaker");
  speaker.play("calm music");
  speaker.speak("good night");
  EXPECT_EQ(speaker.state().playing, "calm music");
  EXPECT_EQ(speaker.state().last_spoken, "good night");
  speaker.stop();
  EXPECT_EQ(speaker.state().playing, "");
}

// An effect as "time device: what value", for comparing lists.
std::string describe(const DeviceEffect& e) {
  return format_time(e.time) + " " + e.device + ": " + e.what +
         (e.value.empty() ? "" : " " + e.value);
}

TEST_F(SimDevices, ActuatorsReportWhatTheyDidWithTheClocksTime) {
  auto tv = capability<home::TVControlPrx>("tv", "tv_control");
  tv.set_power(true);
  tv.set_power(true);  // confirmed: reported again
  tv.set_channel(5);
  EXPECT_THROW(tv.set_channel(120), home::OutOfRange);  // refused: nothing happened
  tv.set_volume(30);
  clock_.advance_by(5min);
  auto light = capability<home::LightPrx>("living_light", "light");
  light.set_power(false);
  light.set_intensity(30);
  EXPECT_THROW(light.set_intensity(101), home::OutOfRange);
  clock_.advance_by(90s);
  auto speaker = capability<home::SpeakerPrx>("robot1_speaker", "speaker");
  speaker.play("calm");
  speaker.set_volume(55);
  speaker.speak("good night & sleep well");
  speaker.stop();
  (void)tv.state();  // reading a state is no effect
  (void)speaker.state();

  std::vector<std::string> got;
  for (const auto& e : effects()) got.push_back(describe(e));
  EXPECT_EQ(got, (std::vector<std::string>{
                     "d0 18:00:00 tv: power on",
                     "d0 18:00:00 tv: power on",
                     "d0 18:00:00 tv: channel 5",
                     "d0 18:00:00 tv: volume 30",
                     "d0 18:05:00 living_light: power off",
                     "d0 18:05:00 living_light: intensity 30",
                     "d0 18:06:30 robot1_speaker: playing calm",
                     "d0 18:06:30 robot1_speaker: volume 55",
                     "d0 18:06:30 robot1_speaker: spoke good night & sleep well",
                     "d0 18:06:30 robot1_speaker: stopped",
                 }));
}

TEST(SimDeviceEffects, NobodyListeningIsFineAndTheSimulatedHousePassesTheObserverOn) {
  std::mutex mutex;
  std::vector<DeviceEffect> effects;
  SimulatedHouseOptions options;
  options.effects = [&](const DeviceEffect& e) {
    std::lock_guard lock(mutex);
    effects.push_back(e);
  };
  SimulatedHouse house(sim::load_house(ICARS_PAPER_HOUSE), options);
  p::Communicator client;
  const auto peer =
      client.connect("127.0.0.1", house.communicator().listen("127.0.0.1", 0));
  ASSERT_TRUE(peer->wait_connected(20s));
  home::LightPrx(client, peer, "/devices/bedroom_light/light").set_power(true);
  {
    std::lock_guard lock(mutex);
    ASSERT_EQ(effects.size(), 1u);
    EXPECT_EQ(effects[0].device, "bedroom_light");
    EXPECT_EQ(effects[0].what, "power");
    EXPECT_EQ(effects[0].value, "on");
    EXPECT_EQ(effects[0].time, at_time(0, 18, 0));  // the house's start, clock not started
  }

  // Without an observer the actuators work as before.
  SimClock clock;
  sim::World world(sim::load_house(ICARS_PAPER_HOUSE), clock);
  p::Communicator devices;
  device::DeviceManager manager(devices);
  sim::DeviceSpec tv = *world.house().device("tv");
  manager.add(make_sim_device(tv, SimContext{world, devices}));
  const auto tv_peer = client.connect("127.0.0.1", devices.listen("127.0.0.1", 0));
  ASSERT_TRUE(tv_peer->wait_connected(20s));
  home::TVControlPrx remote(client, tv_peer, "/devices/tv/tv_control");
  remote.set_power(true);
  EXPECT_TRUE(remote.state().on);
}

TEST_F(SimDevices, TheSimulationTellsItsTimeInMilliseconds) {
  auto simulation = capability<home::SimulationPrx>("simulator", "simulation");
  EXPECT_EQ(simulation.now_ms(), clock_.now().count());
  EXPECT_EQ(simulation.now_ms(), at_time(0, 18, 0).count());
  clock_.advance_by(90min + 250ms);
  EXPECT_EQ(simulation.now_ms(), clock_.now().count());
  EXPECT_EQ(simulation.now_ms(), at_time(0, 19, 30).count() + 250);
  EXPECT_EQ(simulation.now(), "d0 19:30:00.250");
}

TEST_F(SimDevices, TheClockTellsSimulatedTime) {
  auto clock = capability<home::ClockPrx>("clock", "clock");
  EXPECT_EQ(clock.time_of_day(), "18:00:00");
  clock_.advance_by(90min);
  EXPECT_EQ(clock.now_ms(), at_time(0, 19, 30).count());
  EXPECT_EQ(clock.time_of_day(), "19:30:00");
}

TEST_F(SimDevices, SensorsPublishWhatTheUserDoes) {
  std::mutex mutex;
  std::vector<home::MotionEvent> motion;
  std::vector<home::OccupancyEvent> occupancy;
  auto motion_listener = std::make_shared<p::Servant>(std::string(home::MotionListener::type_id));
  motion_listener->implement(home::MotionListener::on_motion, [&](const home::MotionEvent& e) {
    std::lock_guard lock(mutex);
    motion.push_back(e);
  });
  auto bed_listener = std::make_shared<p::Servant>(std::string(home::OccupancyListener::type_id));
  bed_listener->implement(home::OccupancyListener::on_occupancy, [&](const home::OccupancyEvent& e) {
    std::lock_guard lock(mutex);
    occupancy.push_back(e);
  });
  client_.adapter().add("/motion", motion_listener);
  client_.adapter().add("/bed", bed_listener);
  auto sensor = capability<home::MotionSensorPrx>("bedroom_motion", "motion");
  auto bed = capability<home::OccupancySensorPrx>("bed_sensor", "occupancy");
  sensor.subscribe(client_.reference<home::MotionListener>("/motion"));
  bed.subscribe(client_.reference<home::OccupancyListener>("/bed"));
  EXPECT_FALSE(sensor.motion());
  EXPECT_FALSE(bed.occupied());

  clock_.advance_to(at_time(0, 23, 0));  // 22:00 to the bedroom, 22:30 in bed
  EXPECT_TRUE(sensor.motion());
  EXPECT_TRUE(bed.occupied());
  ASSERT_TRUE(planet_test::wait_until([&] {
    std::lock_guard lock(mutex);
    return !motion.empty() && !occupancy.empty();
  }));
  std::lock_guard lock(mutex);
  EXPECT_TRUE(motion.front().motion);
  EXPECT_EQ(motion.front().room, "bedroom");
  EXPECT_GE(motion.front().time_ms, at_time(0, 21, 59).count());
  EXPECT_TRUE(occupancy.back().occupied);
  EXPECT_EQ(occupancy.back().furniture, "bed");
}

// The robot's microphone array streams what it hears as real audio: the user's sentence,
// synthesized and rendered at each of its four microphones, in 20 ms frames on the clock's
// timeline, nothing while nobody speaks; the speech engine (PocketSphinx) recognizes it against
// a vocabulary and refuses audio it cannot decode, saying why.
TEST_F(SimDevices, TheMicrophoneArrayStreamsWhatItHearsAndTheEngineRecognizesIt) {
  auto mic = capability<home::MicrophonePrx>("robot1_mic", "sound_sensor");
  const auto info = mic.info();
  EXPECT_EQ(info.sample_rate, 16000);
  ASSERT_EQ(info.channels, 4);
  ASSERT_EQ(info.mic_x.size(), 4u);
  EXPECT_NEAR(std::hypot(info.mic_x[1], info.mic_y[1]), 0.08, 1e-9);
  EXPECT_EQ(info.source, "sim");
  auto capture = mic.capture(0);
  ASSERT_TRUE(planet_test::wait_until([&] { return capture->buffered() == 0; }));

  const auto said = clock_.now();
  world_.say("user1", "turn on the TV");
  for (int i = 0; i < 50; ++i) clock_.advance_by(100ms);  // 5 s: the sentence and its tail
  world_.say("user1", "stop");                            // the next sound, after a silence
  for (int i = 0; i < 50; ++i) clock_.advance_by(100ms);

  // The first sentence, up to the gap before the next: the silence between them is not sent.
  audio::AudioStreamDecoder decoder;
  audio::AudioBlock heard;
  heard.format = {16000, 4};
  bool first = true, gap = false;
  while (!gap) {
    const auto bytes = capture->read();
    ASSERT_FALSE(bytes.empty());
    for (const auto& f : decoder.feed(bytes)) {
      EXPECT_EQ(f.format.channels, 4);
      EXPECT_LE(f.frames(), 320u) << "a frame is 20 ms";
      if (first) heard.start = f.start;
      first = false;
      if (f.start != heard.end()) {
        gap = true;
        EXPECT_GE(f.start, heard.end() + 16 * 1000) << "seconds of silence were left out";
        break;
      }
      heard.samples.insert(heard.samples.end(), f.samples.begin(), f.samples.end());
    }
  }
  EXPECT_GT(heard.seconds(), 1.0);
  EXPECT_LT(heard.seconds(), 4.0);
  // A reader that comes back asks for what it missed: the microphone sends it again.
  auto again = mic.capture(static_cast<std::int64_t>(heard.start));
  audio::AudioStreamDecoder replay;
  std::vector<audio::AudioBlock> replayed;
  while (replayed.empty()) {
    const auto bytes = again->read();
    ASSERT_FALSE(bytes.empty());
    replayed = replay.feed(bytes);
  }
  EXPECT_EQ(replayed.front().start, heard.start);
  // The stream starts a little before the words (the room before the voice), on the clock's timeline.
  EXPECT_NEAR(static_cast<double>(heard.start) / 16.0, static_cast<double>(said.count()) - 200, 1.0);

  auto engine = capability<home::SpeechRecognizerPrx>("speech_engine", "speech_recognizer");
  const p::Binary audio{audio::pcm_bytes(heard.samples)};
  const auto recognition = engine.recognize(audio, 16000, 4, {"turn on the tv", "turn off the tv", "channel 5"});
  EXPECT_EQ(recognition.text, "turn on the tv");
  EXPECT_GT(recognition.confidence, 0.3);
  EXPECT_GT(recognition.decode_ms, 0.0);
  // Not one of the phrases: not recognized, with the reason.
  EXPECT_THROW(engine.recognize(audio, 16000, 4, {"play music", "stop"}), home::NotRecognized);
  // Audio it cannot decode at all.
  EXPECT_THROW(engine.recognize(p::Binary{std::vector<std::byte>(63)}, 16000, 1, {}), home::BadAudio);
  EXPECT_THROW(engine.recognize(audio, 1000, 4, {"stop"}), home::BadAudio);
  EXPECT_THROW(engine.recognize(audio, 16000, 0, {"stop"}), home::BadAudio);
}

// Decoding takes hundreds of milliseconds of CPU a sentence: it runs beside the device
// manager's io thread, which meanwhile answers every other call (a house's clock polled by the
// server, a command to the TV) instead of keeping them waiting behind the decoder.
TEST_F(SimDevices, TheSpeechEngineDecodesWhileTheOtherDevicesKeepAnswering) {
  audio::Synthesizer synthesizer;
  const auto sentence = audio::to_block(synthesizer.speak("turn on the tv and then play some relaxing music please"));
  audio::AudioBlock speech;  // half a minute of talking: seconds of decoding
  while (static_cast<double>(speech.samples.size()) / audio::kSpeechRate < 30.0) {
    speech.samples.insert(speech.samples.end(), sentence.samples.begin(), sentence.samples.end());
  }
  auto engine = capability<home::SpeechRecognizerPrx>("speech_engine", "speech_recognizer");
  auto simulation = capability<home::SimulationPrx>("simulator", "simulation");
  auto tv = capability<home::TVControlPrx>("tv", "tv_control");
  std::promise<void> decoded;
  auto done = decoded.get_future();
  engine.recognize_async(p::Binary{audio::pcm_bytes(speech.samples)}, audio::kSpeechRate, 1,
                         {"turn on the tv", "play music"},
                         [&decoded](std::exception_ptr, home::Recognition) { decoded.set_value(); });
  // Sent after the audio on the same connection, answered before the decoder is done with it.
  for (int i = 0; i < 20; ++i) {
    EXPECT_EQ(simulation.now_ms(), at_time(0, 18, 0).count());
    tv.set_power(i % 2 == 0);
  }
  EXPECT_EQ(done.wait_for(0s), std::future_status::timeout) << "the decoding held up the other devices' calls";
  EXPECT_EQ(done.wait_for(120s), std::future_status::ready);
}

TEST_F(SimDevices, TheCameraSeesTheUserInItsRoomAndTheVisionEngineReadsIt) {
  // Drive the robot to the middle of the living room, where the user is at 18:00, and look.
  auto wheels = capability<home::WheelsPrx>("robot1_wheels", "wheels");
  EXPECT_THROW(wheels.go_to_waypoint("garage"), home::UnknownTarget);
  wheels.go_to_waypoint("living_room");
  clock_.advance_by(60s);
  EXPECT_EQ(wheels.room(), "living_room");
  const auto image = capability<home::CameraPrx>("robot1_camera", "camera").capture();
  EXPECT_EQ(image.encoding, "sim/scene");
  const auto faces =
      capability<home::FaceRecognizerPrx>("vision_engine", "face_recognizer").recognize(image);
  ASSERT_EQ(faces.size(), 1u);
  EXPECT_EQ(faces[0].person, "user1");
  EXPECT_NEAR(faces[0].x, 0.6, 0.01);
}

TEST_F(SimDevices, TheWheelsTurnInPlaceAndStopAMotion) {
  std::mutex mutex;
  std::vector<home::PositionEvent> positions;
  auto listener = std::make_shared<p::Servant>(std::string(home::PositionListener::type_id));
  listener->implement(home::PositionListener::on_position, [&](const home::PositionEvent& e) {
    std::lock_guard lock(mutex);
    positions.push_back(e);
  });
  client_.adapter().add("/positions", listener);
  auto wheels = capability<home::WheelsPrx>("robot1_wheels", "wheels");
  wheels.subscribe(client_.reference<home::PositionListener>("/positions"));
  const auto heading_reported = [&](double theta) {
    return planet_test::wait_until([&] {
      std::lock_guard lock(mutex);
      return !positions.empty() && std::abs(positions.back().theta - theta) < 1e-9 &&
             !positions.back().moving;
    });
  };

  // Standing at the dock, facing -x: turn to face +y.
  const auto start = wheels.position();
  EXPECT_NEAR(start.theta, std::numbers::pi, 1e-9);
  wheels.turn_to(std::numbers::pi / 2);
  EXPECT_NEAR(wheels.position().theta, std::numbers::pi / 2, 1e-12);
  clock_.advance_by(0ms);
  ASSERT_TRUE(heading_reported(std::numbers::pi / 2));
  {
    std::lock_guard lock(mutex);
    EXPECT_FALSE(positions.back().arrived);
    EXPECT_EQ(positions.back().robot, "robot1");
    EXPECT_EQ(positions.back().room, "living_room");
    EXPECT_EQ(positions.back().time_ms, clock_.now().count());
    EXPECT_NEAR(positions.back().x, start.x, 1e-12);
    EXPECT_NEAR(positions.back().y, start.y, 1e-12);
  }

  // Turning while driving stops the drive where the robot is; it never arrives.
  wheels.go_to_waypoint("bedroom_window");
  clock_.advance_by(2s);
  EXPECT_GT(sim::distance({wheels.position().x, wheels.position().y}, {start.x, start.y}), 0.5);
  wheels.turn_to(-3 * std::numbers::pi / 4 + 2 * std::numbers::pi);  // normalised
  clock_.advance_by(0ms);
  const auto stopped = wheels.position();
  EXPECT_NEAR(stopped.theta, -3 * std::numbers::pi / 4, 1e-9);
  ASSERT_TRUE(heading_reported(-3 * std::numbers::pi / 4));
  clock_.advance_by(60s);
  const auto later = wheels.position();
  EXPECT_EQ(later.x, stopped.x);
  EXPECT_EQ(later.y, stopped.y);
  // A last turn: once its event is in, every event before it is too; none said "arrived".
  wheels.turn_to(0);
  clock_.advance_by(0ms);
  ASSERT_TRUE(heading_reported(0));
  std::lock_guard lock(mutex);
  for (const auto& e : positions) EXPECT_FALSE(e.arrived) << e.x << ", " << e.y;
}

// --- The state file ----------------------------------------------------------------------------

// A device manager's part for the state-file tests: the paper's house on a clock started at
// `now`, every house device hosted with the state file `file`, called over loopback.
class KeptHouse {
 public:
  KeptHouse(const std::filesystem::path& file, Time now,
            std::chrono::milliseconds min_interval = 100ms)
      : clock_(now) {
    std::vector<std::string> ids;
    for (const auto& spec : world_.house().devices) ids.push_back(spec.id);
    state_ = std::make_unique<SimStateFile>(file, world_, ids, nullptr, min_interval);
    const SimContext context{world_, devices_, {}, state_.get()};
    for (const auto& spec : world_.house().devices) manager_.add(make_sim_device(spec, context));
    state_->start();
    peer_ = client_.connect("127.0.0.1", devices_.listen("127.0.0.1", 0));
    EXPECT_TRUE(peer_->wait_connected(20s));
  }
  template <class Prx>
  Prx capability(const std::string& device, const std::string& name) {
    return Prx(client_, peer_, "/devices/" + device + "/" + name);
  }
  SimClock& clock() { return clock_; }
  sim::World& world() { return world_; }
  SimStateFile& state() { return *state_; }

 private:
  SimClock clock_;
  sim::World world_{sim::load_house(ICARS_PAPER_HOUSE), clock_};
  std::unique_ptr<SimStateFile> state_;
  p::Communicator devices_;
  device::DeviceManager manager_{devices_};
  p::Communicator client_;
  std::shared_ptr<p::Peer> peer_;
};

class SimStateFileTest : public ::testing::Test {
 protected:
  void SetUp() override { file_ = dir_ / "house.state.json"; }

  static std::string read(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), {}};
  }
  static void write(const std::filesystem::path& path, const std::string& text) {
    std::ofstream(path, std::ios::binary | std::ios::trunc) << text;
  }
  nlohmann::json on_disk() const { return nlohmann::json::parse(read(file_)); }

  planet_test::TestDirectory dir_{"icars_state"};
  std::filesystem::path file_;
  const Time t18_ = at_time(0, 18, 0);
};

TEST_F(SimStateFileTest, EveryAcknowledgedCommandIsOnDiskAndARestartStartsFromIt) {
  std::string killed;  // the file as a SIGKILL right after the last reply would leave it
  {
    KeptHouse house(file_, t18_);
    EXPECT_EQ(house.state().loaded(), SimStateFile::Loaded::none);
    auto tv = house.capability<home::TVControlPrx>("tv", "tv_control");
    for (int volume = 21; volume <= 30; ++volume) {
      tv.set_volume(volume);  // on disk before the reply
      EXPECT_EQ(on_disk()["devices"]["tv"]["volume"], volume);
    }
    tv.set_power(true);
    tv.set_channel(5);
    tv.set_volume(25);
    EXPECT_THROW(tv.set_channel(100), home::OutOfRange);  // refused: nothing changes
    house.capability<home::LightPrx>("living_light", "light").set_intensity(30);
    auto speaker = house.capability<home::SpeakerPrx>("robot1_speaker", "speaker");
    speaker.play("calm music");
    speaker.speak("good night");
    killed = read(file_);
  }
  write(file_, killed);
  KeptHouse again(file_, t18_);
  EXPECT_EQ(again.state().loaded(), SimStateFile::Loaded::restored);
  const auto tv = again.capability<home::TVControlPrx>("tv", "tv_control").state();
  EXPECT_TRUE(tv.on);
  EXPECT_EQ(tv.channel, 5);
  EXPECT_EQ(tv.volume, 25);
  const auto light = again.capability<home::LightPrx>("living_light", "light").state();
  EXPECT_FALSE(light.on);
  EXPECT_EQ(light.intensity, 30);
  const auto bedroom = again.capability<home::LightPrx>("bedroom_light", "light").state();
  EXPECT_EQ(bedroom.intensity, 100);  // never commanded: as a new light
  const auto speaker = again.capability<home::SpeakerPrx>("robot1_speaker", "speaker").state();
  EXPECT_EQ(speaker.playing, "calm music");
  EXPECT_EQ(speaker.volume, 40);
  EXPECT_EQ(speaker.last_spoken, "good night");
}

TEST_F(SimStateFileTest, ARobotThatArrivedComesBackWhereItStopped) {
  home::Pose arrived;
  std::string killed;
  {
    KeptHouse house(file_, t18_);
    auto wheels = house.capability<home::WheelsPrx>("robot1_wheels", "wheels");
    wheels.go_to(home::Pose{1.58, 3.78, 0});
    EXPECT_TRUE(on_disk()["robots"]["robot1"].contains("path"));  // the motion, at once
    const auto writes = house.state().writes();
    house.clock().advance_by(60s);
    arrived = wheels.position();
    EXPECT_NEAR(arrived.x, 1.58, 0.05);
    // The arrival is written within min_interval of wall time, without a command.
    ASSERT_TRUE(planet_test::wait_until([&] { return house.state().writes() > writes; }));
    killed = read(file_);
  }
  write(file_, killed);
  EXPECT_FALSE(nlohmann::json::parse(killed)["robots"]["robot1"].contains("path"));
  KeptHouse again(file_, t18_);  // no common epoch: the clock starts over; the robot stays
  const auto pose = again.capability<home::WheelsPrx>("robot1_wheels", "wheels").position();
  EXPECT_EQ(pose.x, arrived.x);
  EXPECT_EQ(pose.y, arrived.y);
  EXPECT_EQ(pose.theta, arrived.theta);
  EXPECT_FALSE(again.world().robot_moving("robot1"));
}

TEST_F(SimStateFileTest, ADrivingRobotDrivesOnWithTheClockAndArrivesWhereItWould) {
  // The reference: the same command in a house that is never restarted.
  SimClock clock(t18_);
  sim::World reference(sim::load_house(ICARS_PAPER_HOUSE), clock);
  ASSERT_TRUE(reference.move_robot("robot1", *reference.house().locate("bedroom_window")));

  std::string at_command;  // killed right after the go_to's reply
  std::string mid_drive;   // killed 2 s into the drive, after a write of the moving robot
  {
    KeptHouse house(file_, t18_);
    auto wheels = house.capability<home::WheelsPrx>("robot1_wheels", "wheels");
    wheels.go_to_waypoint("bedroom_window");
    at_command = read(file_);
    house.clock().advance_by(2s);
    house.state().commit();
    mid_drive = read(file_);
  }
  clock.advance_by(2s);
  const auto reference_at_2s = reference.robot_pose("robot1");

  // Restarted on the same simulated time (--epoch): where the drive puts it now.
  write(file_, at_command);
  {
    KeptHouse again(file_, t18_ + 2s);
    EXPECT_TRUE(again.world().robot_moving("robot1"));
    EXPECT_EQ(again.world().robot_pose("robot1"), reference_at_2s);
    again.clock().advance_by(60s);
    clock.advance_by(60s);
    EXPECT_FALSE(again.world().robot_moving("robot1"));
    EXPECT_EQ(again.world().robot_pose("robot1"), reference.robot_pose("robot1"));
  }
  // Restarted long after the drive would have ended: arrived.
  write(file_, at_command);
  {
    KeptHouse again(file_, t18_ + 10min);
    EXPECT_FALSE(again.world().robot_moving("robot1"));
    EXPECT_EQ(again.world().robot_pose("robot1"), reference.robot_pose("robot1"));
  }
  // Restarted on a clock behind the file (no epoch): it resumes from where it was written.
  write(file_, mid_drive);
  {
    KeptHouse again(file_, t18_);
    EXPECT_TRUE(again.world().robot_moving("robot1"));
    EXPECT_EQ(again.world().robot_pose("robot1"), reference_at_2s);
    again.clock().advance_by(60s);
    EXPECT_EQ(again.world().robot_pose("robot1"), reference.robot_pose("robot1"));
  }
}

// A robot that waits for a door on the way (another robot holds it) keeps its wait in the file:
// restarted mid-wait it waits the rest, then drives on; a negative wait is refused.
TEST_F(SimStateFileTest, ARobotWaitingOnItsWayWaitsTheRestAfterARestart) {
  std::string at_command;
  {
    KeptHouse house(file_, t18_);
    house.capability<home::WheelsPrx>("robot1_wheels", "wheels").go_to_waypoint("bedroom_window");
    at_command = read(file_);
  }
  auto doc = nlohmann::json::parse(at_command);
  doc["robots"]["robot1"]["pause_ms"] = 5000;
  doc["robots"]["robot1"]["pause_at"] = 1.0;  // 2 s along, at 0.5 m/s
  write(file_, doc.dump());
  {
    KeptHouse again(file_, t18_ + 3s);  // on the same simulated time: 1 s into the wait
    const auto waiting = again.world().robot_pose("robot1");
    again.clock().advance_by(3s);  // still waiting
    EXPECT_EQ(again.world().robot_pose("robot1"), waiting);
    EXPECT_TRUE(again.world().robot_moving("robot1"));
    again.clock().advance_by(2s);  // the wait is over at 7 s: on its way again
    EXPECT_NE(again.world().robot_pose("robot1"), waiting);
    const auto states = again.world().robot_states();
    EXPECT_EQ(states.front().pause, Time(5000));
    EXPECT_DOUBLE_EQ(states.front().pause_at, 1.0);
  }
  doc["robots"]["robot1"]["pause_ms"] = -1;
  write(file_, doc.dump());
  KeptHouse refused(file_, t18_);
  EXPECT_EQ(refused.state().loaded(), SimStateFile::Loaded::rejected);
  EXPECT_NE(refused.state().rejection().find("negative pause"), std::string::npos) << refused.state().rejection();
}

TEST_F(SimStateFileTest, ACorruptFileIsSetAsideWithAWarningAndTheHouseStartsFresh) {
  {
    KeptHouse house(file_, t18_);
    house.capability<home::TVControlPrx>("tv", "tv_control").set_channel(7);
  }
  const std::string good = read(file_);
  write(file_, good.substr(0, good.size() / 2));  // truncated, as a torn write would be
  KeptHouse house(file_, t18_);
  EXPECT_EQ(house.state().loaded(), SimStateFile::Loaded::rejected);
  EXPECT_NE(house.state().rejection().find("not valid JSON"), std::string::npos)
      << house.state().rejection();
  EXPECT_EQ(read(std::filesystem::path(file_.string() + ".rejected")), good.substr(0, good.size() / 2));
  EXPECT_EQ(house.capability<home::TVControlPrx>("tv", "tv_control").state().channel, 1);
  EXPECT_EQ(on_disk()["devices"]["tv"]["channel"], 1);  // a fresh, whole file
}

TEST_F(SimStateFileTest, AFileOfAnotherHouseOrDeviceSetOrWithBadValuesIsRejectedSayingWhy) {
  { KeptHouse house(file_, t18_); }
  const auto good = on_disk();
  const auto rejected_for = [&](nlohmann::json doc) {
    write(file_, doc.dump());
    KeptHouse house(file_, t18_);
    EXPECT_EQ(house.state().loaded(), SimStateFile::Loaded::rejected);
    return house.state().rejection();
  };
  auto other = good;
  other["house"] = "flat";
  EXPECT_NE(rejected_for(other).find("written for house \"flat\""), std::string::npos);
  other = good;
  other["devices"].erase("tv");
  other["devices"]["lamp"] = {{"type", "Light"}, {"on", true}, {"intensity", 5}};
  EXPECT_NE(rejected_for(other).find("it lacks [tv] and has [lamp]"), std::string::npos)
      << rejected_for(other);
  other = good;
  other["devices"]["tv"]["volume"] = 101;
  EXPECT_NE(rejected_for(other).find("device \"tv\": \"volume\" is 101, expected 0 to 100"),
            std::string::npos);
  other = good;
  other["devices"]["tv"]["on"] = "yes";
  EXPECT_NE(rejected_for(other).find("device \"tv\": \"on\" is \"yes\", expected true or false"),
            std::string::npos);
  other = good;
  other["robots"]["robot1"]["x"] = 12.0;  // outside the house
  EXPECT_NE(rejected_for(other).find("robot \"robot1\" at (12, "), std::string::npos)
      << rejected_for(other);
  other = good;
  other["version"] = 9;
  EXPECT_NE(rejected_for(other).find("version 9, this program reads version 1"), std::string::npos);
}

TEST_F(SimStateFileTest, ChangesNobodyWaitsForAreThrottledCommitsAreNot) {
  KeptHouse house(file_, t18_, 200ms);
  const auto first = house.state().writes();
  const auto started = std::chrono::steady_clock::now();
  for (int i = 0; i < 200; ++i) {
    house.state().changed();
    std::this_thread::sleep_for(1ms);
  }
  ASSERT_TRUE(planet_test::wait_until([&] { return house.state().writes() > first; }));
  const double elapsed =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  EXPECT_LE(static_cast<double>(house.state().writes() - first), elapsed / 0.2 + 2);
  // A commit does not wait for the interval: four in a row are four writes (or shared ones).
  auto tv = house.capability<home::TVControlPrx>("tv", "tv_control");
  for (int channel = 2; channel <= 5; ++channel) {
    tv.set_channel(channel);
    EXPECT_EQ(on_disk()["devices"]["tv"]["channel"], channel);
  }
}

TEST_F(SimStateFileTest, AReaderNeverSeesATornFile) {
  KeptHouse house(file_, t18_, 0ms);
  std::atomic<bool> done{false};
  std::atomic<int> reads{0};
  std::string torn;
  std::thread reader([&] {
    while (!done) {
      const auto text = read(file_);
      if (!nlohmann::json::accept(text)) torn = text;
      ++reads;
    }
  });
  auto tv = house.capability<home::TVControlPrx>("tv", "tv_control");
  for (int volume = 0; volume <= 100; ++volume) tv.set_volume(volume);
  ASSERT_TRUE(planet_test::wait_until([&] { return reads > 10; }));
  done = true;
  reader.join();
  EXPECT_EQ(torn, "");
  EXPECT_FALSE(std::filesystem::exists(file_.string() + ".rejected"));
}

TEST(SimDeviceFactory, UnknownTypesAndBadParametersAreRefusedClearly) {
  SimClock clock;
  sim::World world(sim::load_house(ICARS_PAPER_HOUSE), clock);
  p::Communicator communicator;
  sim::DeviceSpec spec;
  spec.id = "toaster";
  spec.type = "Toaster";
  try {
    make_sim_device(spec, SimContext{world, communicator});
    FAIL() << "a toaster was simulated";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("type 'Toaster'"), std::string::npos) << e.what();
  }
  spec.id = "mic";
  spec.type = "Microphone";
  spec.params["threshold_db"] = "loud";
  try {
    make_sim_device(spec, SimContext{world, communicator});
    FAIL() << "a bad threshold was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("threshold_db = 'loud' is not a number"), std::string::npos)
        << e.what();
  }
  spec.params = {{"channels", "0"}};
  EXPECT_THROW(make_sim_device(spec, SimContext{world, communicator}), std::invalid_argument);
  spec.params = {{"channels", "2"}, {"array_radius", "-1"}};
  EXPECT_THROW(make_sim_device(spec, SimContext{world, communicator}), std::invalid_argument);
  spec.params = {{"source", "tape:reel"}};
  try {
    make_sim_device(spec, SimContext{world, communicator});
    FAIL() << "an unknown audio source was accepted";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("tape:reel"), std::string::npos) << e.what();
  }
}

TEST(SimDeviceTypes, AHouseTakesTypesAddedToTheHomesOnesAndRefusesTwoOfOneName) {
  SimClock clock;
  sim::World world(sim::load_house(ICARS_PAPER_HOUSE), clock);
  p::Communicator communicator;
  SimDeviceTypes types = sim_device_types();
  EXPECT_TRUE(types.has("TV"));
  EXPECT_FALSE(types.has("Toaster"));
  EXPECT_THROW(types.add("TV", "another television", [](const sim::DeviceSpec&, SimContext) {
    return std::shared_ptr<device::Device>();
  }), std::invalid_argument);

  // A plugin's registry, merged: its type is made with the spec it was given.
  SimDeviceTypes plugin;
  plugin.add("Toaster", "makes toast", [](const sim::DeviceSpec& spec, SimContext) {
    return std::make_shared<device::Device>(spec.id, spec.type, spec.room);
  });
  types.merge(std::move(plugin));
  EXPECT_TRUE(plugin.names().empty());
  EXPECT_EQ(types.names().back(), "Toaster");
  EXPECT_EQ(types.description("Toaster"), "makes toast");
  sim::DeviceSpec spec;
  spec.id = "toaster";
  spec.type = "Toaster";
  spec.room = "living_room";
  const auto toaster = types.make(spec, SimContext{world, communicator});
  ASSERT_NE(toaster, nullptr);
  EXPECT_EQ(toaster->id(), "toaster");
  // The home's own list knows nothing of it; an unknown type names every known one.
  EXPECT_THROW(make_sim_device(spec, SimContext{world, communicator}), std::invalid_argument);
  spec.type = "Kettle";
  try {
    types.make(spec, SimContext{world, communicator});
    FAIL() << "a kettle was simulated";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("VisionEngine or Toaster)"), std::string::npos) << e.what();
  }
}

// The simulated house's speech engine suppresses the reverberation its simulated microphones
// render: the shortest of their rooms' RT60; a real microphone's room is unknown, and a house that
// simulates none suppresses nothing.
TEST(SimSpeechEngine, SuppressesTheReverberationOfTheHousesSimulatedRooms) {
  sim::House house = sim::load_house(ICARS_PAPER_HOUSE);
  ASSERT_TRUE(std::ranges::any_of(house.devices, [](const auto& d) { return d.type == "Microphone"; }));
  EXPECT_DOUBLE_EQ(sim_room_rt60(house), audio::RoomSound{}.rt60);

  sim::DeviceSpec bathroom;
  bathroom.id = "bathroom_mic";
  bathroom.type = "Microphone";
  bathroom.params["rt60"] = "0.9";
  house.devices.push_back(bathroom);
  EXPECT_DOUBLE_EQ(sim_room_rt60(house), audio::RoomSound{}.rt60);
  sim::DeviceSpec study = bathroom;
  study.id = "study_mic";
  study.params["rt60"] = "0.25";
  house.devices.push_back(study);
  EXPECT_DOUBLE_EQ(sim_room_rt60(house), 0.25);

  for (auto& d : house.devices) {
    if (d.type == "Microphone") d.params["source"] = "file:/dev/null";
  }
  EXPECT_DOUBLE_EQ(sim_room_rt60(house), 0.0);
  house.devices.back().params = {{"rt60", "echoing"}};
  EXPECT_THROW(sim_room_rt60(house), std::invalid_argument);
}

// The simulated house decodes with the model adapted to its voices (tools/speech-model), which the
// build made: the house's commands, said by the voice the stock model hears worst, 2 m from the
// microphone in the simulated room, are recognized more often with it than with the stock model.
TEST(SimSpeechModel, TheAdaptedModelHearsTheSimulatedVoicesBetterThanTheStockOne) {
  const auto adapted = sim_speech_model_dir();
  ASSERT_FALSE(adapted.empty()) << "the build did not make the adapted model (tools/speech-model)";
  const std::vector<std::string> commands = {"turn on the TV", "channel 5",  "volume up",   "play music",
                                             "stop",           "turn off the TV", "channel 12", "volume down",
                                             "stop the music", "channel 23"};
  const std::vector<std::string> phrases = {"turn on the tv", "turn off the tv", "volume up", "volume down",
                                            "play music",     "stop",            "stop the music", "channel 5",
                                            "channel 9",      "channel 12",      "channel 23",     "channel 1"};
  audio::Synthesizer synthesizer;
  const auto correct = [&](const std::string& model_dir) {
    audio::Recognizer recognizer(audio::RecognizerOptions{.model_dir = model_dir, .min_confidence = 0.3});
    recognizer.set_phrases(phrases);
    int right = 0;
    std::uint64_t seed = 1;
    for (const auto& command : commands) {
      const auto spoken = synthesizer.speak(command, audio::Voice{.name = "en"});
      const audio::RoomSound room{.rt60 = 0.4, .critical_distance = 1.0, .noise_db = 30.0, .seed = seed++};
      const auto heard = audio::render(spoken, {{.distance = 2.0, .level_db = 60.0 - 20 * std::log10(2.0)}}, room, 0.5, 0.8);
      const auto r = recognizer.recognize(heard);
      std::string said = command;
      for (auto& c : said) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
      right += r.recognized && r.text == said;
    }
    return right;
  };
  const int stock = correct("");
  const int with_adapted = correct(adapted);
  EXPECT_GT(with_adapted, stock) << "adapted " << with_adapted << " of 10, stock " << stock << " of 10";
  EXPECT_GE(with_adapted, 7) << "adapted " << with_adapted << " of 10, stock " << stock << " of 10";
}

}  // namespace
}  // namespace icars::home
