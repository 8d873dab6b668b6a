// The knowledge base: the neighbour table expires silent agents and ignores reordered HELLOs,
// the task table only moves forward, configurations are checked with clear errors and written
// back as they were read, and costs come from the planner, not straight lines.
#include "icars/coros/knowledge.h"

#include <gtest/gtest.h>

#include <thread>

#include "icars/coros/robot.h"

namespace icars::coros {
namespace {

using namespace std::chrono_literals;

AgentState agent(const std::string& id, double timestamp, Clock::time_point heard,
                 const std::string& status = "idle") {
  AgentState s;
  s.id = id;
  s.role = "robot";
  s.status = status;
  s.timestamp = timestamp;
  s.last_heard = heard;
  return s;
}

TEST(CorosNeighborMonitor, JoinsUpdatesAndExpires) {
  NeighborMonitor m(1000ms);
  std::vector<std::string> changes;
  m.on_change(
      [&](const AgentState& s, bool joined) { changes.push_back((joined ? "+" : "-") + s.id); });
  const auto t0 = Clock::now();
  EXPECT_TRUE(m.update(agent("robot1", 1, t0)));
  EXPECT_TRUE(m.update(agent("robot2", 1, t0)));
  EXPECT_FALSE(m.update(agent("robot1", 2, t0 + 600ms, "busy")));
  EXPECT_EQ(m.find("robot1")->status, "busy");
  // A reordered, older HELLO keeps the newer state but still proves the agent is alive.
  EXPECT_FALSE(m.update(agent("robot1", 1.5, t0 + 900ms, "idle")));
  EXPECT_EQ(m.find("robot1")->status, "busy");
  const auto gone = m.expire(t0 + 1500ms);
  ASSERT_EQ(gone.size(), 1u);
  EXPECT_EQ(gone[0].id, "robot2");
  EXPECT_EQ(m.size(), 1u);
  EXPECT_TRUE(m.update(agent("robot2", 5, t0 + 1600ms)));  // back again: joins anew
  EXPECT_EQ(changes, (std::vector<std::string>{"+robot1", "+robot2", "-robot2", "+robot2"}));
}

TaskState task(int round, TaskStage stage, double distance = 0) {
  TaskState t;
  t.id = "user-1";
  t.round = round;
  t.stage = stage;
  t.distance = distance;
  return t;
}

TEST(CorosTaskMonitor, OnlyMovesForward) {
  TaskMonitor m;
  int changes = 0;
  m.on_change([&](const TaskState&) { ++changes; });
  EXPECT_TRUE(m.update(task(1, TaskStage::announced)));
  EXPECT_TRUE(m.update(task(1, TaskStage::to_pickup, 1)));
  EXPECT_FALSE(m.update(task(1, TaskStage::assigned)));      // late, reordered
  EXPECT_TRUE(m.update(task(1, TaskStage::to_pickup, 2)));   // progress within a stage
  EXPECT_TRUE(m.update(task(2, TaskStage::announced)));      // a new round wins
  EXPECT_FALSE(m.update(task(1, TaskStage::delivered, 9)));  // the old round is stale
  EXPECT_EQ(m.find("user-1")->round, 2);
  EXPECT_EQ(m.find("user-1")->stage, TaskStage::announced);
  EXPECT_EQ(changes, 4);
  EXPECT_EQ(parse_task_stage("picked_up"), TaskStage::picked_up);
  EXPECT_FALSE(parse_task_stage("lost"));
}

std::string config_error(const std::string& json) {
  try {
    AgentConfiguration::parse(json, "/maps", "robot.json");
  } catch (const CorosError& e) {
    return e.what();
  }
  return "";
}

TEST(CorosConfiguration, ReadsEverySetting) {
  const auto c = AgentConfiguration::parse(R"({
    "id": "user", "role": "user", "ip": "127.0.0.1", "port": 0,
    "broadcast": {"address": "127.255.255.255", "port": 47999},
    "hello_period_ms": 100, "neighbor_expiry_ms": 500, "bid_window_ms": 300,
    "retry_period_ms": 50, "max_retries": 7, "map": "office.xml", "field_cache": "fields",
    "user": {"deliveries": [["a", "b"], ["c", "d"]], "expect_robots": 5, "start_after_ms": 2000,
             "delivery_interval_ms": 100, "exit_when_done": false},
    "faults": "drop=0.1,seed=3",
    "key": "00112233445566778899aabbccddeeff00112233445566778899AABBCCDDEEFF"})",
                                           "/maps", "user.json");
  EXPECT_EQ(c.id, "user");
  EXPECT_EQ(c.role, "user");
  EXPECT_EQ(c.transport.broadcast_port, 47999);
  EXPECT_EQ(c.hello_period, 100ms);
  EXPECT_EQ(c.neighbor_expiry, 500ms);
  EXPECT_EQ(c.bid_window, 300ms);
  EXPECT_EQ(c.max_retries, 7);
  EXPECT_EQ(c.map, std::filesystem::path("/maps/office.xml"));
  EXPECT_EQ(c.field_cache, std::filesystem::path("/maps/fields"));
  ASSERT_EQ(c.deliveries.size(), 2u);
  EXPECT_EQ(c.deliveries[1].second, "d");
  EXPECT_EQ(c.expect_robots, 5);
  EXPECT_FALSE(c.exit_when_done);
  EXPECT_DOUBLE_EQ(c.transport.faults.drop, 0.1);
  ASSERT_TRUE(c.transport.key);
  EXPECT_EQ(c.transport.key->to_hex(),
            "00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff");
  EXPECT_FALSE(c.transport.insecure);
}

TEST(CorosConfiguration, BrokenFilesSayWhatIsWrong) {
  const std::pair<const char*, const char*> cases[] = {
      {"{", "not valid JSON"},
      {R"({"role": "robot", "map": "m.xml"})", "'id' must be"},
      {R"({"id": "r", "role": "boss"})", "expected robot, user or monitor"},
      {R"({"id": "r", "map": "m.xml", "speeed": 1})", "unknown setting 'speeed'"},
      {R"({"id": "r", "map": "m.xml", "hello_period_ms": 500, "neighbor_expiry_ms": 400})",
       "must be longer"},
      {R"({"id": "r", "map": "m.xml", "faults": "drop=7"})", "probability"},
      {R"({"id": "r"})", "a robot needs a 'map'"},
      {R"({"id": "r", "map": "m.xml", "robot": {"kind": "lego"}})", "expected sim or ros"},
      {R"({"id": "u", "role": "user", "map": "m.xml", "user": {"deliveries": [["a"]]}})",
       "must be [pickup, dropoff]"},
      {R"({"id": "r", "map": "m.xml", "port": 70000})", "outside"},
      {R"({"id": "r", "map": 5})", "'map' must be a string"},
  };
  for (const auto& [json, expected] : cases) {
    const std::string error = config_error(json);
    EXPECT_NE(error.find("robot.json: "), std::string::npos) << json << " -> " << error;
    EXPECT_NE(error.find(expected), std::string::npos) << json << " -> " << error;
  }
  EXPECT_THROW(AgentConfiguration::load("/nonexistent/agent.json"), CorosError);
}

// Every field parse() reads, compared one by one.
void expect_same(const AgentConfiguration& a, const AgentConfiguration& b) {
  EXPECT_EQ(a.id, b.id);
  EXPECT_EQ(a.role, b.role);
  EXPECT_EQ(a.transport.ip, b.transport.ip);
  EXPECT_EQ(a.transport.port, b.transport.port);
  EXPECT_EQ(a.transport.broadcast_address, b.transport.broadcast_address);
  EXPECT_EQ(a.transport.broadcast_port, b.transport.broadcast_port);
  EXPECT_EQ(a.hello_period, b.hello_period);
  EXPECT_EQ(a.neighbor_expiry, b.neighbor_expiry);
  EXPECT_EQ(a.bid_window, b.bid_window);
  EXPECT_EQ(a.retry_period, b.retry_period);
  EXPECT_EQ(a.max_retries, b.max_retries);
  EXPECT_EQ(a.map, b.map);
  EXPECT_EQ(a.field_cache, b.field_cache);
  EXPECT_EQ(a.start, b.start);
  EXPECT_EQ(a.speed, b.speed);
  EXPECT_EQ(a.radius, b.radius);
  EXPECT_EQ(a.speedup, b.speedup);
  EXPECT_EQ(a.robot_kind, b.robot_kind);
  EXPECT_EQ(a.ros_namespace, b.ros_namespace);
  EXPECT_EQ(a.track_file, b.track_file);
  EXPECT_EQ(a.deliveries, b.deliveries);
  EXPECT_EQ(a.expect_robots, b.expect_robots);
  EXPECT_EQ(a.start_after, b.start_after);
  EXPECT_EQ(a.delivery_interval, b.delivery_interval);
  EXPECT_EQ(a.exit_when_done, b.exit_when_done);
  EXPECT_EQ(a.transport.faults.spec(), b.transport.faults.spec());
  EXPECT_TRUE(a.transport.faults == b.transport.faults);
  ASSERT_EQ(a.transport.key.has_value(), b.transport.key.has_value());
  if (a.transport.key) {
    EXPECT_EQ(a.transport.key->to_hex(), b.transport.key->to_hex());
  }
  EXPECT_EQ(a.transport.insecure, b.transport.insecure);
}

AgentConfiguration read_back(const AgentConfiguration& c) {
  return AgentConfiguration::parse(c.to_json().dump(2), "/elsewhere", c.id + ".json");
}

const std::string kHex = "00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff";

TEST(CorosConfiguration, ToJsonIsReadBackAsTheSameConfiguration) {
  AgentConfiguration robot;
  robot.id = "robot7";
  robot.role = "robot";
  robot.transport.ip = "10.0.0.7";
  robot.transport.port = 40007;
  robot.transport.broadcast_address = "10.0.0.255";
  robot.transport.broadcast_port = 47999;
  robot.hello_period = 150ms;
  robot.neighbor_expiry = 900ms;
  robot.bid_window = 425ms;
  robot.retry_period = 70ms;
  robot.max_retries = 9;
  robot.map = "/maps/office_floor.xml";  // absolute: parse's base_dir does not apply
  robot.field_cache = "/tmp/fields";
  robot.start = "1.25,3.50";
  robot.speed = 0.35;
  robot.radius = 0.3;
  robot.speedup = 12.5;
  robot.robot_kind = "ros";
  robot.ros_namespace = "tb3_7";
  robot.track_file = "/tmp/robot7-track.json";
  robot.transport.faults = FaultInjection::parse("drop=0.1,duplicate=0.05,delay=0.3,seed=42");
  robot.transport.faults.seed = 0xFFFFFFFFFFFFFFFFULL;  // the whole range of a seed
  robot.transport.key = FleetKey::from_hex(kHex);
  const nlohmann::json robot_json = robot.to_json();
  EXPECT_TRUE(robot_json.contains("robot"));
  EXPECT_FALSE(robot_json.contains("user"));  // a section only for its role
  EXPECT_EQ(robot_json.value("key", ""), kHex);
  EXPECT_FALSE(robot_json.contains("insecure"));
  expect_same(read_back(robot), robot);

  AgentConfiguration user;
  user.id = "user";
  user.role = "user";
  user.map = "/maps/office_floor.xml";
  user.deliveries = {{"office_101", "office_112"}, {"office_104", "office_109"}};
  user.expect_robots = 5;
  user.start_after = 0ms;
  user.delivery_interval = 250ms;
  user.exit_when_done = false;
  user.transport.faults.delay = 0.2;
  user.transport.faults.max_delay_ms = 80;
  user.transport.key = FleetKey::from_hex(kHex);
  const nlohmann::json user_json = user.to_json();
  EXPECT_FALSE(user_json.contains("robot"));
  EXPECT_FALSE(user_json.contains("track_file"));
  EXPECT_EQ(user_json.value("faults", ""), "drop=0,duplicate=0,delay=0.2,max_delay_ms=80,seed=1");
  expect_same(read_back(user), user);

  // A monitor without a key: insecure, no faults, no sections unless they hold something.
  AgentConfiguration monitor;
  monitor.id = "monitor";
  monitor.role = "monitor";
  monitor.transport.insecure = true;
  const nlohmann::json monitor_json = monitor.to_json();
  EXPECT_FALSE(monitor_json.contains("faults"));
  EXPECT_FALSE(monitor_json.contains("robot"));
  EXPECT_FALSE(monitor_json.contains("user"));
  EXPECT_FALSE(monitor_json.contains("map"));
  EXPECT_FALSE(monitor_json.contains("key"));
  EXPECT_TRUE(monitor_json.value("insecure", false));
  expect_same(read_back(monitor), monitor);
  monitor.radius = 0.4;  // loads its map with it: kept
  EXPECT_EQ(monitor.to_json()["robot"].value("radius", 0.0), 0.4);
  expect_same(read_back(monitor), monitor);
}

TEST(CorosConfiguration, ParsedFilesAreWrittenBackAsTheyWere) {
  // Every key parse() reads (but key_file, which it turns into the key), no default left out.
  const std::string robot = R"({
    "id": "robot1", "role": "robot", "ip": "127.0.0.1", "port": 0,
    "broadcast": {"address": "127.255.255.255", "port": 47800},
    "hello_period_ms": 200, "neighbor_expiry_ms": 1000, "bid_window_ms": 400,
    "retry_period_ms": 100, "max_retries": 20, "map": "/maps/office_floor.xml",
    "robot": {"start": "dock1", "speed": 0.5, "radius": 0.25, "speedup": 20, "kind": "sim"},
    "track_file": "robot1-track.json",
    "faults": "drop=0.2,duplicate=0.2,delay=0.3,max_delay_ms=50,seed=17",
    "key": ")" + kHex + R"("})";
  const std::string user = R"({
    "id": "user", "role": "user", "ip": "192.168.1.20", "port": 47001,
    "broadcast": {"address": "192.168.1.255", "port": 47999},
    "hello_period_ms": 100, "neighbor_expiry_ms": 500, "bid_window_ms": 300,
    "retry_period_ms": 50, "max_retries": 7, "map": "/maps/office_floor.xml",
    "user": {"deliveries": [["a", "b"], ["c", "d"]], "expect_robots": 5, "start_after_ms": 2000,
             "delivery_interval_ms": 100, "exit_when_done": false},
    "insecure": true})";
  for (const auto& text : {robot, user}) {
    const auto c = AgentConfiguration::parse(text, "/maps", "agent.json");
    EXPECT_EQ(c.to_json(), nlohmann::json::parse(text)) << c.to_json().dump(2);
    expect_same(read_back(c), c);
  }
  // A relative map is read relative to the file and written as read.
  const auto relative = AgentConfiguration::parse(
      R"({"id": "r", "map": "office.xml", "insecure": true})", "/maps", "r.json");
  EXPECT_EQ(relative.to_json().value("map", ""), "/maps/office.xml");
}

TEST(CorosMapPlanner, CostsArePlannedPathsNotStraightLines) {
  const auto map = MapPlanner::load(std::string(ICARS_HOUSES_DIR) + "/paper_house.xml", 0.25);
  // From the living room's sofa side to the bedroom's desk: the door is in the way.
  const sim::Point a = map->locate("sofa_side"), b = map->locate("bedroom_window");
  const auto cost = map->path_cost(a, b);
  ASSERT_TRUE(cost);
  EXPECT_GT(*cost, sim::distance(a, b) + 0.05);
  EXPECT_EQ(map->locate("3,2").x, 3.0);
  EXPECT_THROW(map->locate("office_999"), CorosError);
  EXPECT_THROW(map->locate("-5,-5"), CorosError);  // outside: not free space
  EXPECT_THROW(MapPlanner::load("/nonexistent.xml", 0.25), CorosError);
}

// A place's distance field is computed once and shared by the threads asking (robots of one
// process bid on their planner threads at once); a cost is the same whoever asks, as the
// path's length; a place that is no free space, or out of reach, costs nothing.
TEST(CorosMapPlanner, PlacesAreAskedAboutFromManyThreadsWithOneFieldEach) {
  const auto map = MapPlanner::load(std::string(ICARS_HOUSES_DIR) + "/paper_house.xml", 0.25);
  const std::vector<std::string> places = {"entrance", "bedroom_window", "kitchen_corner", "sofa_side"};
  std::vector<std::vector<double>> costs(4);
  std::vector<std::thread> threads;
  for (std::size_t t = 0; t < costs.size(); ++t) {
    threads.emplace_back([&, t] {
      for (const auto& from : places) {
        for (const auto& to : places) costs[t].push_back(map->path_cost(map->locate(from), map->locate(to)).value_or(-1));
      }
    });
  }
  for (auto& t : threads) t.join();
  for (std::size_t t = 1; t < costs.size(); ++t) EXPECT_EQ(costs[t], costs[0]);
  EXPECT_EQ(map->fields(), places.size());
  for (const double c : costs[0]) EXPECT_GE(c, 0);
  const auto a = map->locate("entrance"), b = map->locate("bedroom_window");
  const auto path = map->path(a, b);
  ASSERT_TRUE(path);
  EXPECT_NEAR(sim::path_length(*path), *map->path_cost(a, b), 0.05 * *map->path_cost(a, b));
  EXPECT_FALSE(map->path_cost(a, {-5, -5}));   // not free space
  EXPECT_FALSE(map->path_cost({-5, -5}, b));   // nowhere near the map
  EXPECT_EQ(map->fields(), places.size());
}

}  // namespace
}  // namespace icars::coros
