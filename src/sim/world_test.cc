// The simulated house in motion: robots drive along planned paths in simulated time, the
// paper house's user lives the schedule (utterances, room changes, postures), runs are
// deterministic for a seed, and listeners may call back into the World.
#include "icars/sim/world.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <array>
#include <atomic>
#include <cmath>
#include <numbers>
#include <thread>

#include "icars/sim/planner.h"

namespace icars::sim {
namespace {

using namespace std::chrono_literals;

const std::filesystem::path kPaperHouse =
    std::filesystem::path(ICARS_HOUSES_DIR) / "paper_house.xml";

House paper_house() { return load_house(kPaperHouse); }

struct PoseEvent {
  Time time;
  Pose pose;
  bool moving;
};

TEST(World, RobotReachesAWaypointInTheOtherRoomInPathTime) {
  const auto house = paper_house();
  SimClock clock(house.start_time);
  World world(house, clock);
  const OccupancyGrid grid(house, house.robot("robot1")->radius);
  std::vector<PoseEvent> poses;
  world.on_robot_pose([&](const std::string& robot, const Pose& pose, bool moving) {
    EXPECT_EQ(robot, "robot1");
    poses.push_back({clock.now(), pose, moving});
  });
  EXPECT_EQ(world.robot_room("robot1"), "living_room");
  const auto target = *house.locate("bedroom_window");
  std::optional<Time> arrived_at;
  std::optional<bool> result;
  const auto start = clock.now();
  const auto path = world.move_robot("robot1", target, [&](bool arrived) {
    result = arrived;
    arrived_at = clock.now();
  });
  ASSERT_TRUE(path);
  EXPECT_FALSE(result);  // never inside the call
  EXPECT_TRUE(world.robot_moving("robot1"));
  const double expected_s = path_length(*path) / house.robot("robot1")->speed;
  EXPECT_GT(expected_s, 8.0);  // it is a real trip, through the door

  while (!result && clock.now() < start + 1min) clock.advance_by(1s);
  ASSERT_TRUE(result);
  EXPECT_TRUE(*result);
  const double took_s = std::chrono::duration<double>(*arrived_at - start).count();
  EXPECT_NEAR(took_s, expected_s, 0.002);
  EXPECT_FALSE(world.robot_moving("robot1"));
  EXPECT_EQ(world.robot_room("robot1"), "bedroom");
  EXPECT_NEAR(world.robot_pose("robot1").x, target.x, 1e-9);
  EXPECT_NEAR(world.robot_pose("robot1").y, target.y, 1e-9);

  // Reports: at the start, every 500 ms while moving, and a last one (not moving) on arrival;
  // every reported position is free space, and the robot never jumps.
  ASSERT_GE(poses.size(), static_cast<std::size_t>(expected_s / 0.5));
  EXPECT_EQ(poses.front().time, start);
  for (std::size_t i = 0; i + 1 < poses.size(); ++i) {
    EXPECT_TRUE(poses[i].moving);
    EXPECT_EQ(poses[i].time, start + Time(500) * static_cast<int>(i));
  }
  EXPECT_FALSE(poses.back().moving);
  EXPECT_EQ(poses.back().time, *arrived_at);
  bool saw_bedroom = false;
  for (std::size_t i = 0; i < poses.size(); ++i) {
    const auto p = poses[i].pose.position();
    EXPECT_TRUE(grid.free(p)) << "pose " << i << " at (" << p.x << ", " << p.y << ")";
    if (i > 0) {
      EXPECT_LE(distance(p, poses[i - 1].pose.position()), 0.5 * 0.5 + 1e-9);
    }
    saw_bedroom |= house.room_at(p)->name == "bedroom" && p.x > 6.1;
  }
  EXPECT_TRUE(saw_bedroom);
  // Carried devices move with the robot; static ones stay.
  EXPECT_EQ(world.device_pose("robot1_mic"), world.robot_pose("robot1"));
  EXPECT_EQ(world.device_pose("tv"), house.device("tv")->pose);
}

TEST(World, RobotPoseIsExactMidMotion) {
  const auto house = paper_house();
  SimClock clock(house.start_time);
  World world(house, clock);
  const auto path = world.move_robot("robot1", *house.locate("entrance"));
  ASSERT_TRUE(path);
  clock.advance_by(3s);
  const auto expected = point_along(*path, 1.5);  // 3 s at 0.5 m/s
  const auto pose = world.robot_pose("robot1");
  EXPECT_NEAR(pose.x, expected.x, 1e-9);
  EXPECT_NEAR(pose.y, expected.y, 1e-9);
  EXPECT_NEAR(pose.theta, expected.theta, 1e-9);
}

TEST(World, StopAndSupersedeEndAMotionWithDoneFalse) {
  const auto house = paper_house();
  SimClock clock(house.start_time);
  World world(house, clock);
  std::vector<std::string> log;
  std::vector<bool> stops;
  world.on_robot_pose([&](const std::string&, const Pose&, bool moving) {
    if (!moving) stops.push_back(moving);
  });
  ASSERT_TRUE(world.move_robot("robot1", *house.locate("bedroom_center"),
                               [&](bool ok) { log.push_back(ok ? "a:arrived" : "a:ended"); }));
  clock.advance_by(2s);
  const auto at = world.robot_pose("robot1");
  world.stop_robot("robot1");
  EXPECT_FALSE(world.robot_moving("robot1"));
  EXPECT_TRUE(log.empty());  // delivered from the clock
  clock.advance_by(0s);
  EXPECT_EQ(log, (std::vector<std::string>{"a:ended"}));
  EXPECT_EQ(stops.size(), 1u);
  clock.advance_by(30s);
  EXPECT_EQ(world.robot_pose("robot1"), at);  // stays stopped
  world.stop_robot("robot1");                 // no-op when not moving
  clock.advance_by(1s);
  EXPECT_EQ(stops.size(), 1u);

  // A new move supersedes the running one.
  ASSERT_TRUE(world.move_robot("robot1", *house.locate("entrance"),
                               [&](bool ok) { log.push_back(ok ? "b:arrived" : "b:ended"); }));
  clock.advance_by(1s);
  ASSERT_TRUE(world.move_robot("robot1", *house.locate("kitchen_corner"),
                               [&](bool ok) { log.push_back(ok ? "c:arrived" : "c:ended"); }));
  clock.advance_by(1min);
  EXPECT_EQ(log, (std::vector<std::string>{"a:ended", "b:ended", "c:arrived"}));
  EXPECT_LT(distance(world.robot_pose("robot1").position(), *house.locate("kitchen_corner")), 1e-9);
}

TEST(World, TurnRobotStopsAMotionAndReportsTheNewHeadingFromTheClock) {
  const auto house = paper_house();
  SimClock clock(house.start_time);
  World world(house, clock);
  std::vector<PoseEvent> poses;
  world.on_robot_pose([&](const std::string& robot, const Pose& pose, bool moving) {
    EXPECT_EQ(robot, "robot1");
    poses.push_back({clock.now(), pose, moving});
  });
  std::vector<bool> done;
  ASSERT_TRUE(world.move_robot("robot1", *house.locate("bedroom_window"),
                               [&](bool arrived) { done.push_back(arrived); }));
  clock.advance_by(2s);
  const auto at = world.robot_pose("robot1");
  poses.clear();
  world.turn_robot("robot1", std::numbers::pi / 2);
  EXPECT_FALSE(world.robot_moving("robot1"));
  EXPECT_NEAR(world.robot_pose("robot1").theta, std::numbers::pi / 2, 1e-12);
  EXPECT_EQ(world.robot_pose("robot1").position(), at.position());  // in place
  EXPECT_TRUE(poses.empty());  // never inside the call
  EXPECT_TRUE(done.empty());
  clock.advance_by(0s);
  EXPECT_EQ(done, std::vector<bool>{false});
  ASSERT_EQ(poses.size(), 1u);
  EXPECT_FALSE(poses[0].moving);
  EXPECT_EQ(poses[0].time, clock.now());
  EXPECT_EQ(poses[0].pose.position(), at.position());
  EXPECT_NEAR(poses[0].pose.theta, std::numbers::pi / 2, 1e-12);
  clock.advance_by(30s);
  EXPECT_EQ(poses.size(), 1u);  // no more reports: the motion is over
  EXPECT_EQ(done.size(), 1u);

  // Turning a standing robot reports too; headings are normalised to (-pi, pi].
  const std::vector<std::pair<double, double>> turns = {
      {-std::numbers::pi, std::numbers::pi}, {3 * std::numbers::pi, std::numbers::pi},
      {-std::numbers::pi / 2 + 4 * std::numbers::pi, -std::numbers::pi / 2}, {0.25, 0.25}};
  for (const auto& [asked, expected] : turns) {
    world.turn_robot("robot1", asked);
    clock.advance_by(0s);
    EXPECT_NEAR(world.robot_pose("robot1").theta, expected, 1e-9) << asked;
    EXPECT_NEAR(poses.back().pose.theta, expected, 1e-9) << asked;
    EXPECT_FALSE(poses.back().moving);
  }
  EXPECT_EQ(poses.size(), 1 + turns.size());
  EXPECT_EQ(world.robot_pose("robot1").position(), at.position());

  // The robot moves on normally after a turn.
  ASSERT_TRUE(world.move_robot("robot1", *house.locate("entrance")));
  clock.advance_by(1min);
  EXPECT_LT(distance(world.robot_pose("robot1").position(), *house.locate("entrance")), 1e-9);

  EXPECT_THROW(world.turn_robot("robot9", 0), std::invalid_argument);
  EXPECT_THROW(world.turn_robot("robot1", std::nan("")), std::invalid_argument);
}

TEST(World, UnreachableOrBlockedTargets) {
  const auto house = paper_house();
  SimClock clock(house.start_time);
  World world(house, clock);
  bool called = false;
  EXPECT_FALSE(world.move_robot("robot1", {30, 30}, [&](bool) { called = true; }));
  clock.advance_by(10s);
  EXPECT_FALSE(called);
  EXPECT_FALSE(world.robot_moving("robot1"));
  // A target on the sofa (where the user sits) means "next to the sofa".
  const auto sofa = house.find_furniture("sofa")->area.center();
  const auto path = world.move_robot("robot1", sofa, [&](bool ok) { called = ok; });
  ASSERT_TRUE(path);
  EXPECT_LT(distance(path->back(), sofa), 1.5);
  clock.advance_by(1min);
  EXPECT_TRUE(called);
  EXPECT_THROW(world.move_robot("robot9", {1, 1}), std::invalid_argument);
  EXPECT_THROW((void)world.robot_pose("robot9"), std::invalid_argument);
  EXPECT_THROW((void)world.user("nobody"), std::invalid_argument);
  EXPECT_THROW((void)world.device_pose("nothing"), std::invalid_argument);
}

// What the paper house's user does in a day, as a listener sees it.
struct Trace {
  std::vector<std::pair<Time, UserState>> states;
  std::vector<Utterance> utterances;
  std::vector<std::string> lines;  // everything, formatted, for comparing runs
};

Trace run_day(House house, Time until,
              std::function<void(World&, const Utterance&)> check = {}) {
  SimClock clock(house.start_time);
  World world(std::move(house), clock);
  Trace trace;
  world.on_user([&](const UserState& s) {
    trace.states.emplace_back(clock.now(), s);
    trace.lines.push_back(fmt::format("{} {} {} {} {} {:.3f} {:.3f}", format_time(clock.now()),
                                      s.user, s.room, to_string(s.posture), s.furniture, s.at.x,
                                      s.at.y));
  });
  world.on_utterance([&](const Utterance& u) {
    trace.utterances.push_back(u);
    trace.lines.push_back(fmt::format("{} {} says \"{}\" in {} at {:.3f} dB", format_time(u.time),
                                      u.user, u.text, u.room, u.loudness_db));
    if (check) check(world, u);
  });
  clock.advance_to(until);
  return trace;
}

TEST(World, PaperHouseUserLivesTheScheduleAtTheScheduledTimes) {
  const auto house = paper_house();
  const auto jitter = house.users[0].time_jitter;
  int checked = 0;
  const auto trace = run_day(house, at_time(1, 9, 0), [&](World& world, const Utterance& u) {
    // Listeners may call back into the World: the user is on the sofa as they speak.
    const auto state = world.user(u.user);
    EXPECT_EQ(state.furniture, "sofa");
    EXPECT_EQ(state.posture, Posture::sitting);
    EXPECT_TRUE(world.occupied("sofa"));
    EXPECT_FALSE(world.occupied("bed"));
    EXPECT_EQ(u.at, state.at);
    ++checked;
  });

  // The five voice commands, in order, each at its time (± jitter), from the sofa.
  const std::vector<std::pair<std::string, Time>> said = {{"turn on the TV", at_time(0, 18, 12)},
                                                             {"channel 5", at_time(0, 18, 15)},
                                                             {"volume up", at_time(0, 18, 20)},
                                                             {"play music", at_time(0, 19, 0)},
                                                             {"stop", at_time(0, 19, 30)}};
  ASSERT_EQ(trace.utterances.size(), said.size());
  EXPECT_EQ(checked, 5);
  const auto sofa = house.find_furniture("sofa")->area.center();
  for (std::size_t i = 0; i < said.size(); ++i) {
    const auto& u = trace.utterances[i];
    EXPECT_EQ(u.user, "user1");
    EXPECT_EQ(u.text, said[i].first);
    EXPECT_EQ(u.room, "living_room");
    EXPECT_EQ(u.at, sofa);
    EXPECT_GE(u.time, said[i].second - jitter) << u.text;
    EXPECT_LE(u.time, said[i].second + jitter) << u.text;
    EXPECT_NEAR(u.loudness_db, 60.0, 3.0);
  }

  // Room changes and postures, each in its window.
  const auto first = [&](Time from, auto pred) -> std::optional<std::pair<Time, UserState>> {
    for (const auto& e : trace.states) {
      if (e.first >= from && pred(e.second)) return e;
    }
    return std::nullopt;
  };
  const auto sits = first(at_time(0, 18, 0), [](const UserState& s) {
    return s.posture == Posture::sitting && s.furniture == "sofa";
  });
  ASSERT_TRUE(sits);
  EXPECT_GE(sits->first, at_time(0, 18, 10) - jitter);
  EXPECT_LE(sits->first, at_time(0, 18, 10) + jitter + 15s);  // plus the walk to the sofa
  EXPECT_EQ(sits->second.at, sofa);

  const auto to_bedroom =
      first(at_time(0, 18, 0), [](const UserState& s) { return s.room == "bedroom"; });
  ASSERT_TRUE(to_bedroom);
  EXPECT_GE(to_bedroom->first, at_time(0, 22, 0) - jitter);
  EXPECT_LE(to_bedroom->first, at_time(0, 22, 0) + jitter + 15s);
  EXPECT_EQ(to_bedroom->second.posture, Posture::walking);
  EXPECT_GT(to_bedroom->second.at.x, 6.0);  // just through the door

  const auto lies =
      first(at_time(0, 18, 0), [](const UserState& s) { return s.posture == Posture::lying; });
  ASSERT_TRUE(lies);
  EXPECT_EQ(lies->second.furniture, "bed");
  EXPECT_EQ(lies->second.room, "bedroom");
  EXPECT_GE(lies->first, at_time(0, 22, 30) - jitter);
  EXPECT_LE(lies->first, at_time(0, 22, 30) + jitter + 15s);

  // Next morning: up at 7, into the living room for breakfast.
  const auto up =
      first(at_time(1, 0, 0), [](const UserState& s) { return s.posture == Posture::standing; });
  ASSERT_TRUE(up);
  EXPECT_EQ(up->second.room, "bedroom");
  EXPECT_EQ(up->second.furniture, "");
  EXPECT_GE(up->first, at_time(1, 7, 0) - jitter);
  EXPECT_LE(up->first, at_time(1, 7, 0) + jitter);
  const auto breakfast = first(at_time(1, 0, 0), [](const UserState& s) {
    return s.posture == Posture::sitting && s.furniture == "dining_table";
  });
  ASSERT_TRUE(breakfast);
  EXPECT_EQ(breakfast->second.room, "living_room");
  // Nothing is said on the morning of day 1 and nothing happens before 18:00 on day 0.
  EXPECT_GE(trace.states.front().first, at_time(0, 18, 5) - jitter);
}

TEST(World, PostureAndRoomFollowTheUserThroughTheEvening) {
  const auto house = paper_house();
  SimClock clock(house.start_time);
  World world(house, clock);
  EXPECT_EQ(world.user("user1").room, "living_room");
  EXPECT_EQ(world.user("user1").posture, Posture::standing);
  EXPECT_EQ(world.user("user1").at, house.users[0].start);
  clock.advance_to(at_time(0, 18, 14));
  EXPECT_TRUE(world.occupied("sofa"));
  EXPECT_EQ(world.user("user1").posture, Posture::sitting);
  clock.advance_to(at_time(0, 21, 0));
  EXPECT_TRUE(world.occupied("sofa"));  // back on the sofa after dinner
  clock.advance_to(at_time(0, 22, 10));
  EXPECT_FALSE(world.occupied("sofa"));
  EXPECT_EQ(world.user("user1").room, "bedroom");
  EXPECT_EQ(world.user("user1").posture, Posture::standing);
  clock.advance_to(at_time(0, 23, 0));
  EXPECT_TRUE(world.occupied("bed"));
  EXPECT_EQ(world.user("user1").posture, Posture::lying);
  EXPECT_EQ(world.user("user1").at, house.find_furniture("bed")->area.center());
}

TEST(World, AnActivityDueDuringAWalkStartsOnArrivalAndOnceMeansOnce) {
  const auto house = parse_house(R"(<house name="hall" start="07:59">
      <room name="hall" x0="0" y0="0" x1="12" y1="3"/>
      <waypoint name="far_end" x="11" y="1.5"/>
      <user id="u" x="1" y="1.5" speed="1" repeat="once">
        <go_to at="08:00" target="far_end"/>
        <say at="08:00:01" text="made it"/>
      </user>
    </house>)",
                                 "hall.xml");
  SimClock clock(house.start_time);
  World world(house, clock);
  std::vector<Utterance> heard;
  world.on_utterance([&](const Utterance& u) { heard.push_back(u); });
  clock.advance_to(at_time(0, 8, 0, 5));
  EXPECT_TRUE(heard.empty());  // still walking the 10 m
  EXPECT_EQ(world.user("u").posture, Posture::walking);
  EXPECT_NEAR(world.user("u").at.x, 6.0, 1e-9);
  clock.advance_to(at_time(0, 8, 1));
  ASSERT_EQ(heard.size(), 1u);
  EXPECT_EQ(heard[0].time, at_time(0, 8, 0, 10));
  EXPECT_EQ(heard[0].at, (Point{11, 1.5}));
  clock.advance_to(at_time(3, 12, 0));  // never again
  EXPECT_EQ(heard.size(), 1u);
  EXPECT_EQ(clock.pending(), 0u);
}

TEST(World, SameSeedSameRunDifferentSeedDifferentRun) {
  auto house = paper_house();
  const auto a = run_day(house, at_time(1, 9, 0));
  const auto b = run_day(house, at_time(1, 9, 0));
  ASSERT_GT(a.lines.size(), 20u);
  EXPECT_EQ(a.lines, b.lines);
  house.seed = 43;
  const auto c = run_day(house, at_time(1, 9, 0));
  EXPECT_NE(a.lines, c.lines);
  EXPECT_EQ(a.utterances.size(), c.utterances.size());  // same schedule, other timing
  EXPECT_NE(a.utterances[0].time, c.utterances[0].time);
}

TEST(World, SayIsHeardAtTheUsersPositionFromTheClock) {
  const auto house = paper_house();
  SimClock clock(house.start_time);
  World world(house, clock);
  std::vector<Utterance> heard;
  const auto id = world.on_utterance([&](const Utterance& u) { heard.push_back(u); });
  world.say("user1", "hello robot");
  EXPECT_TRUE(heard.empty());
  clock.advance_by(0s);
  ASSERT_EQ(heard.size(), 1u);
  EXPECT_EQ(heard[0].text, "hello robot");
  EXPECT_EQ(heard[0].room, "living_room");
  EXPECT_EQ(heard[0].at, house.users[0].start);
  EXPECT_EQ(heard[0].time, house.start_time);
  EXPECT_DOUBLE_EQ(heard[0].loudness_db, 60.0);
  world.remove_listener(id);
  world.say("user1", "anyone?");
  clock.advance_by(1s);
  EXPECT_EQ(heard.size(), 1u);
}

// A trace registered after the devices still records a change before any device acts on it.
TEST(World, ObserversHearAChangeBeforeReactorsWhateverTheOrderOfRegistration) {
  const auto house = paper_house();
  SimClock clock(house.start_time);
  World world(house, clock);
  std::vector<std::string> calls;
  const auto r1 = world.on_utterance([&](const Utterance&) { calls.push_back("device 1"); });
  const auto o1 = world.on_utterance([&](const Utterance&) { calls.push_back("trace"); }, World::Listening::observing);
  const auto r2 = world.on_utterance([&](const Utterance&) { calls.push_back("device 2"); });
  const auto o2 = world.on_utterance([&](const Utterance&) { calls.push_back("plot"); }, World::Listening::observing);
  world.say("user1", "hello robot");
  clock.advance_by(0s);
  EXPECT_EQ(calls, (std::vector<std::string>{"trace", "plot", "device 1", "device 2"}));
  world.remove_listener(o1);
  world.remove_listener(r1);
  calls.clear();
  world.say("user1", "again");
  clock.advance_by(0s);
  EXPECT_EQ(calls, (std::vector<std::string>{"plot", "device 2"}));
  world.remove_listener(o2);
  world.remove_listener(r2);

  std::vector<std::string> poses;
  const auto device = world.on_robot_pose([&](const std::string&, const Pose&, bool) { poses.push_back("device"); });
  const auto trace = world.on_robot_pose([&](const std::string&, const Pose&, bool) { poses.push_back("trace"); },
                                         World::Listening::observing);
  world.turn_robot(house.robots.at(0).id, 1.0);
  clock.advance_by(0s);
  EXPECT_EQ(poses, (std::vector<std::string>{"trace", "device"}));
  world.remove_listener(device);
  world.remove_listener(trace);
}

TEST(World, SoundFadesWithDistanceAndWalls) {
  const auto house = paper_house();
  SimClock clock(house.start_time);
  World world(house, clock);
  Utterance u{"user1", "hi", "living_room", {3, 1}, Time{0}, 60};
  EXPECT_DOUBLE_EQ(world.sound_level(u, {3, 1.5}), 60.0);  // within a metre
  EXPECT_NEAR(world.sound_level(u, {5, 1}), 60.0 - 20 * std::log10(2.0), 1e-9);
  // Through the wall between the rooms: 10 dB less than the same distance in the open...
  EXPECT_NEAR(world.sound_level(u, {7, 1}), 60.0 - 20 * std::log10(4.0) - 10, 1e-9);
  // ...but not through the open door.
  Utterance near_door{"user1", "hi", "living_room", {5, 2.5}, Time{0}, 60};
  EXPECT_NEAR(world.sound_level(near_door, {7, 2.5}), 60.0 - 20 * std::log10(2.0), 1e-9);
}

TEST(World, RunsUnderARealTimeDriver) {
  const auto house = paper_house();
  SimClock clock(house.start_time);
  World world(house, clock);
  std::atomic<bool> done{false};
  std::atomic<bool> on_driver_thread{false};
  const auto test_thread = std::this_thread::get_id();
  RealTimeDriver driver(clock, 1000.0, 50ms);
  driver.start();
  ASSERT_TRUE(world.move_robot("robot1", *house.locate("bed_side"), [&](bool ok) {
    on_driver_thread = std::this_thread::get_id() != test_thread;
    done = ok;
  }));
  const auto deadline = std::chrono::steady_clock::now() + 20s;
  while (!done && std::chrono::steady_clock::now() < deadline) {
    (void)world.robot_pose("robot1");  // concurrent reads while the driver advances
    std::this_thread::sleep_for(1ms);
  }
  driver.stop();
  EXPECT_TRUE(done);
  EXPECT_TRUE(on_driver_thread);
  EXPECT_EQ(world.robot_room("robot1"), "bedroom");
}

TEST(World, ARemovedListenerIsNeitherRunningNorCalledAgain) {
  const auto house = paper_house();
  SimClock clock(house.start_time);
  World world(house, clock);
  std::atomic<int> calls{0};
  std::atomic<int> in_flight{0};
  const auto id = world.on_robot_pose([&](const std::string&, const Pose&, bool) {
    ++in_flight;
    std::this_thread::sleep_for(2ms);  // slow, so that removal often overlaps a call
    ++calls;
    --in_flight;
  });
  // A listener may remove itself without deadlocking.
  std::atomic<std::uint64_t> self{0};
  std::atomic<int> self_calls{0};
  self = world.on_robot_pose([&](const std::string&, const Pose&, bool) {
    ++self_calls;
    world.remove_listener(self);
  });
  RealTimeDriver driver(clock, 1000.0, 10ms);
  driver.start();
  // A late driver catches up in one advance, which can cover a whole trip in two reports (start
  // and arrival), so the robot is sent back and forth until the listener has run a few times.
  const std::array<Point, 2> ends{*house.locate("bedroom_window"), *house.locate("bed_side")};
  std::size_t trips = 0;
  const auto deadline = std::chrono::steady_clock::now() + 20s;
  while (calls < 3 && std::chrono::steady_clock::now() < deadline) {
    if (!world.robot_moving("robot1")) {
      ASSERT_TRUE(world.move_robot("robot1", ends[trips++ % ends.size()]));
    }
    std::this_thread::sleep_for(1ms);
  }
  ASSERT_GE(calls.load(), 3);
  world.remove_listener(id);
  EXPECT_EQ(in_flight.load(), 0);
  const int after = calls.load();
  std::this_thread::sleep_for(30ms);
  driver.stop();
  EXPECT_EQ(calls.load(), after);
  EXPECT_EQ(self_calls.load(), 1);
}

TEST(World, DestroyingTheWorldCancelsItsEvents) {
  const auto house = paper_house();
  SimClock clock(house.start_time);
  {
    World world(house, clock);
    world.move_robot("robot1", *house.locate("bed_side"));
    EXPECT_GT(clock.pending(), 0u);
  }
  EXPECT_EQ(clock.pending(), 0u);
  clock.advance_by(24h);  // nothing left to run
}



// --- Several robots in one world -------------------------------------------------------------------

const std::filesystem::path kTwoRobotHouse = std::filesystem::path(ICARS_HOUSES_DIR) / "two_robot_house.xml";

double distance_to_door(Point p, const Door& d) {
  const double dx = d.b.x - d.a.x, dy = d.b.y - d.a.y;
  const double t = std::clamp(((p.x - d.a.x) * dx + (p.y - d.a.y) * dy) / (dx * dx + dy * dy), 0.0, 1.0);
  return std::hypot(p.x - (d.a.x + t * dx), p.y - (d.a.y + t * dy));
}

TEST(World, ARobotPlansAroundAnotherOneStandingInItsWay) {
  const auto house = load_house(kTwoRobotHouse);
  SimClock clock(house.start_time);
  World world(house, clock);
  // robot2 stands in the middle of the living room; robot1 crosses the room through that spot.
  const Point middle{3.0, 2.2};
  world.place_robot("robot2", Pose{middle.x, middle.y, 0});
  world.restore_robot(RobotState{"robot1", clock.now(), Pose{0.8, 2.2, 0}, {}, Time{0}});
  clock.advance_by(0s);
  const auto path = world.move_robot("robot1", Point{5.3, 2.2});
  ASSERT_TRUE(path);
  const double clear = house.robot("robot1")->radius + house.robot("robot2")->radius;
  for (double d = 0; d <= path_length(*path); d += 0.02) {
    EXPECT_GE(distance(point_along(*path, d).position(), middle), clear) << "at " << d << " m along the path";
  }
  EXPECT_GT(path_length(*path), 4.5 + 0.1);  // a detour, not the straight line
  // Alone, the same trip is the straight line.
  World alone(load_house(kPaperHouse), clock);
  alone.restore_robot(RobotState{"robot1", clock.now(), Pose{0.8, 2.2, 0}, {}, Time{0}});
  clock.advance_by(0s);
  const auto straight = alone.move_robot("robot1", Point{5.3, 2.2});
  ASSERT_TRUE(straight);
  EXPECT_NEAR(path_length(*straight), 4.5, 1e-6);
}

TEST(World, TwoRobotsTakeTurnsAtANarrowDoor) {
  const auto house = load_house(kTwoRobotHouse);
  const auto* door = &house.doors.front();
  SimClock clock(house.start_time);
  World world(house, clock);
  // Both robots near the door, on either side, each driving to the other side at once.
  world.restore_robot(RobotState{"robot1", clock.now(), Pose{5.0, 2.5, 0}, {}, Time{0}});
  world.restore_robot(RobotState{"robot2", clock.now(), Pose{7.0, 2.5, 0}, {}, Time{0}});
  clock.advance_by(0s);
  bool arrived1 = false, arrived2 = false;
  ASSERT_TRUE(world.move_robot("robot1", Point{7.5, 1.2}, [&](bool a) { arrived1 = a; }));
  ASSERT_TRUE(world.move_robot("robot2", Point{4.5, 3.8}, [&](bool a) { arrived2 = a; }));
  // Never both in the doorway; both get through.
  const auto in_door = [&](const std::string& robot) {
    return distance_to_door(world.robot_pose(robot).position(), *door) < house.robot(robot)->radius;
  };
  bool one_waited = false;
  const auto start = clock.now();
  while (!(arrived1 && arrived2) && clock.now() < start + 2min) {
    clock.advance_by(100ms);
    EXPECT_FALSE(in_door("robot1") && in_door("robot2")) << "both in the door at " << format_time(clock.now());
    for (const auto& state : world.robot_states()) one_waited = one_waited || state.pause.count() > 0;
  }
  EXPECT_TRUE(arrived1 && arrived2);
  EXPECT_TRUE(one_waited);
  // The waiting motion is kept by the state: restored, it waits the same.
}

TEST(World, ARobotWaitingForADoorIsRestoredWithItsWait) {
  const auto house = load_house(kTwoRobotHouse);
  SimClock clock(house.start_time);
  World world(house, clock);
  world.restore_robot(RobotState{"robot1", clock.now(), Pose{5.0, 2.5, 0}, {}, Time{0}});
  world.restore_robot(RobotState{"robot2", clock.now(), Pose{7.0, 2.5, 0}, {}, Time{0}});
  clock.advance_by(0s);
  ASSERT_TRUE(world.move_robot("robot1", Point{7.5, 1.2}));
  ASSERT_TRUE(world.move_robot("robot2", Point{4.5, 3.8}));
  clock.advance_by(1s);
  const auto states = world.robot_states();
  const auto waiting = std::find_if(states.begin(), states.end(), [](const RobotState& s) { return s.pause.count() > 0; });
  ASSERT_NE(waiting, states.end());
  // Another world restores the waiting robot: it is where the first world has it, at every step.
  SimClock clock2(clock.now());
  World copy(house, clock2);
  copy.restore_robot(*waiting);
  for (int i = 0; i < 40; ++i) {
    clock.advance_by(250ms);
    clock2.advance_by(250ms);
    EXPECT_NEAR(copy.robot_pose(waiting->robot).x, world.robot_pose(waiting->robot).x, 1e-6);
    EXPECT_NEAR(copy.robot_pose(waiting->robot).y, world.robot_pose(waiting->robot).y, 1e-6);
  }
}

TEST(World, APlacedRobotIsNotReportedAndEndsAMotionItHad) {
  const auto house = load_house(kTwoRobotHouse);
  SimClock clock(house.start_time);
  World world(house, clock);
  std::vector<std::string> reported;
  world.on_robot_pose([&](const std::string& robot, const Pose&, bool) { reported.push_back(robot); });
  std::optional<bool> done;
  ASSERT_TRUE(world.move_robot("robot2", Point{7.5, 3.0}, [&](bool a) { done = a; }));
  clock.advance_by(0s);
  reported.clear();
  world.place_robot("robot2", Pose{9.0, 1.0, 0});
  clock.advance_by(1s);
  EXPECT_EQ(done, std::optional<bool>(false));
  EXPECT_TRUE(reported.empty());
  EXPECT_FALSE(world.robot_moving("robot2"));
  EXPECT_NEAR(world.robot_pose("robot2").x, 9.0, 1e-9);
  EXPECT_THROW(world.place_robot("robot2", Pose{std::nan(""), 1.0, 0}), std::invalid_argument);
  EXPECT_THROW(world.place_robot("robot9", Pose{1.0, 1.0, 0}), std::invalid_argument);
}

}  // namespace
}  // namespace icars::sim
