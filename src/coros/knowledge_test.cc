// The knowledge base: the neighbour table expires silent agents and ignores reordered HELLOs,
// the task table only moves forward, configurations are checked with clear errors, and costs
// come from the planner, not straight lines.
#include "icars/coros/knowledge.h"

#include <gtest/gtest.h>

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
    "retry_period_ms": 50, "max_retries": 7, "map": "office.xml",
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

}  // namespace
}  // namespace icars::coros
