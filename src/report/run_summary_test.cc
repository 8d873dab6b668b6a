// The run summary reads the trace's typed fields: counts, time per state, robot distance and
// plot tracks come from numbers and flags, and records whose fields are missing or of another
// kind are skipped, never misread.
#include <gtest/gtest.h>

#include <cstdio>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "icars/report/run_summary.h"

namespace icars::report {
namespace {

behavior::TraceRecord make(Time t, std::string kind, std::string text = "") {
  behavior::TraceRecord r;
  r.time = t;
  r.kind = std::move(kind);
  r.source = "test";
  r.text = std::move(text);
  return r;
}

TEST(RunSummary, CountsFromTypedFields) {
  RunSummary summary(/*keep_plot=*/false);
  behavior::Trace trace;
  trace.add_sink(summary.sink());
  trace.record(make(at_time(0, 18, 0), "state").with("state", "Observation").with("event", "enter"));
  trace.record(make(at_time(0, 19, 0), "state").with("state", "Observation").with("event", "exit"));
  trace.record(make(at_time(0, 19, 0), "transition").with("to", "RestMode"));
  trace.record(make(at_time(0, 19, 0), "state").with("state", "RestMode").with("event", "enter"));
  trace.record(make(at_time(0, 19, 0), "call").with("call", "tv.set_power"));
  trace.record(make(at_time(0, 19, 0), "call").with("call", "tv.set_power").with("ok", false));
  trace.record(make(at_time(0, 19, 0), "behavior", "GoToUser failed").with("event", "failure"));
  trace.record(make(at_time(0, 19, 0), "behavior").with("event", "start"));
  trace.record(make(at_time(0, 19, 1), "command").with("event", "sent"));
  trace.record(make(at_time(0, 19, 1), "command").with("event", "acknowledged"));
  trace.record(make(at_time(0, 19, 1), "effect").with("device", "tv").with("what", "channel").with("value", "5"));
  trace.record(make(at_time(0, 19, 2), "robot").with("robot", "r1").with("x", 0.0).with("y", 0.0));
  trace.record(make(at_time(0, 19, 3), "robot").with("robot", "r1").with("x", 3.0).with("y", 4.0));
  // A position written as text is not a number: it is skipped, not parsed.
  trace.record(make(at_time(0, 19, 4), "robot").with("robot", "r1").with("x", "100").with("y", "100"));
  trace.record(make(at_time(0, 19, 5), "speech").with("words", "come here"));

  const auto c = summary.counts();
  EXPECT_EQ(c.transitions, 1);
  EXPECT_EQ(c.calls, 1);
  EXPECT_EQ(c.failed_calls, 1);
  EXPECT_EQ(c.behaviors_failed, 1);
  EXPECT_EQ(c.behaviors_started, 1);
  EXPECT_EQ(c.commands_sent, 1);
  EXPECT_EQ(c.commands_acknowledged, 1);
  EXPECT_EQ(c.effects, 1);
  EXPECT_EQ(c.voice_commands_heard, 1);
  EXPECT_DOUBLE_EQ(c.robot_distance_m, 5.0);
  EXPECT_EQ(summary.device_states().at("tv"), "channel 5");
  ASSERT_EQ(summary.failures().size(), 1u);
  EXPECT_EQ(summary.failures().front(), "[d0 19:00:00] GoToUser failed");

  const auto states = summary.states(at_time(0, 20, 30));
  ASSERT_EQ(states.size(), 2u);
  EXPECT_EQ(states[0].state, "Observation");
  EXPECT_EQ(states[0].spent, std::chrono::hours(1));
  EXPECT_EQ(states[1].state, "RestMode");  // still active: counted up to 20:30
  EXPECT_EQ(states[1].spent, std::chrono::minutes(90));

  char buffer[4096] = {};
  std::FILE* out = fmemopen(buffer, sizeof buffer - 1, "w");
  ASSERT_NE(out, nullptr);
  summary.print(out, "paper_home", at_time(0, 18, 0), at_time(0, 20, 30), 6.0, "lock-step at 1500x");
  std::fclose(out);
  const std::string printed = buffer;
  EXPECT_NE(printed.find("=== summary: policy paper_home, d0 18:00:00 to d0 20:30:00 (150 min simulated in 6.0 s, "
                         "1500x; lock-step at 1500x)"),
            std::string::npos) << printed;
  EXPECT_NE(printed.find("robot distance driven: 5.0 m"), std::string::npos) << printed;
  EXPECT_NE(printed.find("service calls: 1 (1 failed); voice commands heard: 1"), std::string::npos) << printed;
}

TEST(RunSummary, PlotKeepsTracksAndMarksTransitionsWhereTheRobotWas) {
  RunSummary summary(/*keep_plot=*/true);
  behavior::Trace trace;
  trace.add_sink(summary.sink());
  trace.record(make(at_time(0, 18, 0), "robot").with("robot", "r1").with("x", 1.0).with("y", 2.0));
  trace.record(make(at_time(0, 18, 5), "user").with("user", "u1").with("x", 4.0).with("y", 4.0));
  trace.record(make(at_time(0, 18, 10), "transition").with("to", "RestMode"));
  trace.record(make(at_time(0, 18, 11), "user").with("user", "u1"));  // no position: skipped
  sim::House house;
  const auto data = summary.plot("run", house, at_time(0, 18, 0), at_time(0, 18, 20));
  ASSERT_EQ(data.robots.size(), 1u);
  ASSERT_EQ(data.users.size(), 1u);
  EXPECT_EQ(data.users.front().points.size(), 1u);
  ASSERT_EQ(data.marks.size(), 1u);
  EXPECT_EQ(data.marks.front().label, "18:10 RestMode");
  EXPECT_DOUBLE_EQ(data.marks.front().at.x, 1.0);
  EXPECT_DOUBLE_EQ(data.marks.front().at.y, 2.0);
}

TEST(RunSummary, PlotBeginsTracksAtTheRunsStartWhereTheHouseStartsThem) {
  RunSummary summary(/*keep_plot=*/true);
  behavior::Trace trace;
  trace.add_sink(summary.sink());
  // The robot's first reported position is where it was at 18:05, away from its dock; the
  // user was not reported before 18:10; the second robot was reported at the run's start.
  trace.record(make(at_time(0, 18, 0), "robot").with("robot", "r2").with("x", 1.0).with("y", 1.0));
  trace.record(make(at_time(0, 18, 5), "robot").with("robot", "r1").with("x", 3.0).with("y", 2.5));
  trace.record(make(at_time(0, 18, 10), "user").with("user", "u1").with("x", 4.0).with("y", 4.0));
  sim::House house;
  for (const auto& [id, x, y] : {std::tuple{"r1", 5.0, 2.4}, std::tuple{"r2", 1.5, 1.5},
                                 std::tuple{"r3", 8.0, 1.0}}) {  // r3 never moved
    sim::RobotSpec robot;
    robot.id = id;
    robot.start = {x, y, 0.0};
    house.robots.push_back(robot);
  }
  sim::UserSpec user;
  user.id = "u1";
  user.start = {0.6, 2.0};
  house.users.push_back(user);
  const Time from = at_time(0, 18, 0);
  const Time to = at_time(0, 20, 30);
  const auto data = summary.plot("run", house, from, to);

  // The plot's subtitle shows the run, not the span of the movements.
  EXPECT_EQ(data.run_start, from);
  EXPECT_EQ(data.run_end, to);
  using Points = std::vector<std::pair<Time, sim::Point>>;
  ASSERT_EQ(data.robots.size(), 3u);
  EXPECT_EQ(data.robots[0].name, "r1");
  EXPECT_EQ(data.robots[0].points, (Points{{from, {5.0, 2.4}}, {at_time(0, 18, 5), {3.0, 2.5}}}));
  EXPECT_EQ(data.robots[1].name, "r2");
  EXPECT_EQ(data.robots[1].points, (Points{{from, {1.0, 1.0}}}));  // the trace knew better
  EXPECT_EQ(data.robots[2].name, "r3");
  EXPECT_EQ(data.robots[2].points, (Points{{from, {8.0, 1.0}}}));
  ASSERT_EQ(data.users.size(), 1u);
  EXPECT_EQ(data.users[0].points, (Points{{from, {0.6, 2.0}}, {at_time(0, 18, 10), {4.0, 4.0}}}));
}

}  // namespace
}  // namespace icars::report
