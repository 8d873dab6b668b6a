// The statechart constructs beyond states and transitions (docs/policy.md): parallel regions,
// final states and `done`, shallow and deep history, delayed transitions and <send>, run by the
// Coordinator from policy text on a SimClock advanced by hand.
#include <gtest/gtest.h>

#include "coordinator_fixture.h"

namespace b = icars::behavior;
namespace c = icars::control;
using icars::Time;
using namespace std::chrono_literals;

namespace {

using Fixture = icars_test::CoordinatorFixture;
using icars_test::g_alive;
using Names = std::vector<std::string>;

}  // namespace

TEST(Statechart, ParallelRegionsAreEnteredTogetherAndCompleteWithDoneWhenEveryRegionIsFinal) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Door"><behavior type="Wait" duration="20min"/></task>
      <task name="Help"><behavior type="Wait" duration="10min"/></task>
      <statechart>
        <parallel name="Assist">
          <transition event="done" target="After"/>
          <region name="DoorSide">
            <state name="Watching" task="Door"><transition event="done" target="DoorDone"/></state>
            <final name="DoorDone"/>
          </region>
          <region name="HelpSide">
            <state name="Helping" task="Help"><transition event="done" target="HelpDone"/></state>
            <final name="HelpDone"/>
          </region>
        </parallel>
        <state name="After"/>
      </statechart>
    </policy>)xml");
  EXPECT_EQ(coordinator->configuration(), (Names{"Assist", "DoorSide", "Watching", "HelpSide", "Helping"}));
  EXPECT_EQ(f.texts("task"), (Names{"task Door started", "task Help started"}));
  f.advance(10min);  // one region final: the parallel state waits for the other
  EXPECT_EQ(coordinator->configuration(), (Names{"Assist", "DoorSide", "Watching", "HelpSide", "HelpDone"}));
  f.advance(10min);
  EXPECT_EQ(coordinator->configuration(), Names{"After"});
  EXPECT_EQ(f.transitions(), (Names{"HelpSide: Helping -> HelpDone on done", "DoorSide: Watching -> DoorDone on done",
                                    "Assist -> After on done"}));
  const auto done = f.log.of_kind("transition").back();
  EXPECT_EQ(done.field("declared_in"), "Assist");
  EXPECT_EQ(done.time, 20min);
}

TEST(Statechart, ATransitionOutOfOneRegionLeavesEveryRegionAndHaltsTheirTasks) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Watch" events="Opened">
        <concurrent><behavior type="Alive"/><behavior type="Emit" event="Opened" delay="5min"/></concurrent>
      </task>
      <task name="Help"><concurrent><behavior type="Alive"/><behavior type="Alive"/></concurrent></task>
      <statechart>
        <parallel name="Assist">
          <region name="Door"><state name="Watching" task="Watch"><transition event="Opened" target="Out"/></state></region>
          <region name="Robot" task="Help"/>
        </parallel>
        <state name="Out"/>
      </statechart>
    </policy>)xml");
  EXPECT_EQ(g_alive.load(), 3);  // both regions' trees run at once
  f.advance(5min);
  EXPECT_EQ(coordinator->configuration(), Names{"Out"});
  EXPECT_EQ(g_alive.load(), 0);
  EXPECT_EQ(f.transitions(), Names{"Door: Watching -> Out on Opened"});
  // Left innermost first, the regions in reverse document order.
  EXPECT_EQ(f.texts("state"), (Names{"entered Assist", "entered Door", "entered Watching", "entered Robot", "left Robot",
                                     "left Watching", "left Door", "left Assist", "entered Out"}));
}

TEST(Statechart, AnEventFiresOneTransitionPerRegionAndATransitionInsideARegionLeavesTheOthersRunning) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Clock" events="Tick">
        <sequential repeat="forever"><behavior type="Emit" event="Tick" delay="1min"/></sequential>
      </task>
      <task name="Keep"><behavior type="Alive"/></task>
      <statechart>
        <parallel name="Both" task="Clock">
          <region name="A">
            <state name="A1" task="Keep"><transition event="Tick" target="A2"/></state>
            <state name="A2"/>
          </region>
          <region name="B">
            <state name="B1"><transition event="Tick" target="B2"/></state>
            <state name="B2"><transition event="Tick" target="B1"/></state>
          </region>
        </parallel>
      </statechart>
    </policy>)xml");
  f.advance(1min);
  // Document order: region A's transition, then region B's.
  EXPECT_EQ(f.transitions(), (Names{"A: A1 -> A2 on Tick", "B: B1 -> B2 on Tick"}));
  EXPECT_EQ(coordinator->configuration(), (Names{"Both", "A", "A2", "B", "B2"}));
  EXPECT_EQ(g_alive.load(), 0);
  f.advance(1min);  // only B moves; the parallel state's task was never restarted
  EXPECT_EQ(coordinator->configuration(), (Names{"Both", "A", "A2", "B", "B1"}));
  int clock_starts = 0;
  for (const auto& t : f.texts("task")) clock_starts += t == "task Clock started";
  EXPECT_EQ(clock_starts, 1);
  coordinator->stop();
}

TEST(Statechart, ReachingAFinalStateOfTheStatechartEndsThePolicy) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Step"><behavior type="Wait" duration="1min"/></task>
      <task name="Keep"><behavior type="Alive"/></task>
      <statechart>
        <state name="Work" task="Keep">
          <transition event="done" target="End" guard="completed == 'Work'"/>
          <state name="One" task="Step"><transition event="done" target="Two"/></state>
          <state name="Two" task="Step"><transition event="done" target="Finished"/></state>
          <final name="Finished"/>
        </state>
        <final name="End"/>
      </statechart>
    </policy>)xml");
  f.advance(1min);
  EXPECT_EQ(coordinator->configuration(), (Names{"Work", "Two"}));
  EXPECT_FALSE(coordinator->finished());
  f.advance(1min);
  EXPECT_TRUE(coordinator->finished());
  EXPECT_TRUE(coordinator->configuration().empty());
  EXPECT_EQ(g_alive.load(), 0);  // every task halted
  EXPECT_EQ(f.transitions(), (Names{"One -> Two on done", "Two -> Finished on done", "Work -> End on done"}));
  EXPECT_EQ(f.texts("policy").back(), "policy p finished in End");
  coordinator->stop();  // nothing left to stop: no second record
  EXPECT_EQ(f.texts("policy").back(), "policy p finished in End");
}

// Work: Step1, then Step2 (itself Inner1 then Inner2); Break interrupts it at 10min and returns
// at 15min. What Work enters again depends on its history.
std::string history_policy(const std::string& history) {
  return R"xml(
    <policy name="p">
      <statechart>
        <state name="Work" )xml" + history + R"xml(>
          <transition after="10min" target="Break"/>
          <state name="Step1"><transition after="3min" target="Step2"/></state>
          <state name="Step2">
            <state name="Inner1"><transition after="2min" target="Inner2"/></state>
            <state name="Inner2"/>
          </state>
        </state>
        <state name="Break"><transition after="5min" target="Work"/></state>
      </statechart>
    </policy>)xml";
}

TEST(Statechart, HistoryReentersWhatWasActiveShallowOrDeep) {
  for (const auto& [history, expected] : std::vector<std::pair<std::string, Names>>{
           {"", {"Work", "Step1"}},
           {R"(history="shallow")", {"Work", "Step2", "Inner1"}},
           {R"(history="deep")", {"Work", "Step2", "Inner2"}}}) {
    SCOPED_TRACE(history);
    Fixture f;
    auto coordinator = f.start(history_policy(history));
    f.advance(3min);  // in steps: a timer starts when the runtime enters its state
    f.advance(2min);
    EXPECT_EQ(coordinator->configuration(), (Names{"Work", "Step2", "Inner2"}));
    f.advance(5min);
    EXPECT_EQ(coordinator->configuration(), Names{"Break"});
    f.advance(5min);
    EXPECT_EQ(coordinator->configuration(), expected);
    coordinator->stop();
  }
}

TEST(Statechart, DeepHistoryRestoresEveryRegionOfAParallelState) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <statechart>
        <state name="Work" history="deep">
          <transition after="10min" target="Break"/>
          <parallel name="Both">
            <region name="A"><state name="A1"><transition after="1min" target="A2"/></state><state name="A2"/></region>
            <region name="B"><state name="B1"><transition after="2min" target="B2"/></state><state name="B2"/></region>
          </parallel>
        </state>
        <state name="Break"><transition after="1min" target="Work"/></state>
      </statechart>
    </policy>)xml");
  f.advance(10min);
  EXPECT_EQ(coordinator->configuration(), Names{"Break"});
  f.advance(1min);
  EXPECT_EQ(coordinator->configuration(), (Names{"Work", "Both", "A", "A2", "B", "B2"}));
}

TEST(Statechart, AfterFiresAtTheExactSimulatedTimeAndIsCancelledWhenTheStateIsLeft) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Ring" events="Ring"><behavior type="Emit" event="Ring" delay="4min"/></task>
      <statechart>
        <state name="Quiet"><transition after="10min" target="Waiting"/></state>
        <state name="Waiting" task="Ring">
          <transition after="10min" target="TimedOut"/>
          <transition event="Ring" target="Answering"/>
        </state>
        <state name="Answering"/>
        <state name="TimedOut"/>
      </statechart>
    </policy>)xml");
  f.advance(10min - 1ms);
  EXPECT_EQ(coordinator->current(), "Quiet");
  f.advance(1ms);
  EXPECT_EQ(coordinator->current(), "Waiting");
  const auto fired = f.log.of_kind("transition").at(0);
  EXPECT_EQ(fired.time, 10min);
  EXPECT_EQ(fired.text, "Quiet -> Waiting after 10min");
  EXPECT_EQ(fired.field("event"), "after 10min");
  f.advance(4min);  // Ring leaves Waiting before its 10 minutes
  EXPECT_EQ(coordinator->current(), "Answering");
  f.advance(1h);
  EXPECT_EQ(coordinator->current(), "Answering");
  EXPECT_EQ(f.transitions(), (Names{"Quiet -> Waiting after 10min", "Waiting -> Answering on Ring"}));
}

TEST(Statechart, SendRaisesAnEventAfterItsDelayUnlessTheStateWasLeft) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <statechart>
        <state name="Home" initial="First">
          <send event="Late" after="30min"/>
          <state name="First">
            <send event="Nudge" after="20min"/>
            <transition after="5min" target="Second"/>
            <transition event="Nudge" target="Nudged"/>
          </state>
          <state name="Second"><transition event="Late" target="Night"/></state>
          <state name="Nudged"/>
        </state>
        <state name="Night"/>
      </statechart>
    </policy>)xml");
  f.advance(25min);  // First was left at 5min: its Nudge never comes
  EXPECT_EQ(coordinator->current(), "Second");
  f.advance(5min);
  EXPECT_EQ(coordinator->current(), "Night");
  EXPECT_EQ(f.transitions(), (Names{"First -> Second after 5min", "Second -> Night on Late"}));
  EXPECT_EQ(f.log.of_kind("transition").back().time, 30min);
}

TEST(Statechart, ATasksDoneAndFailedReachOnlyItsOwnStateAndItsAncestors) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Short"><behavior type="Wait" duration="1min"/></task>
      <task name="Keep"><behavior type="Alive"/></task>
      <statechart>
        <parallel name="Both">
          <region name="A"><state name="A1" task="Short"/></region>
          <region name="B"><state name="B1" task="Keep"><transition event="done" target="Wrong"/></state></region>
        </parallel>
        <state name="Wrong"/>
      </statechart>
    </policy>)xml");
  f.advance(1min);  // A1's task is done; B1's `done` transition is about B1's task
  EXPECT_EQ(coordinator->configuration(), (Names{"Both", "A", "A1", "B", "B1"}));
  EXPECT_TRUE(f.transitions().empty());
  coordinator->stop();
}

TEST(Statechart, RegionsRestartAloneOrTogetherAndATransitionLeavingTheParallelStatePreemptsTheOthers) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Clock" events="Restart, Swap, Leave">
        <sequential>
          <behavior type="Emit" event="Restart" delay="1min"/>
          <behavior type="Emit" event="Swap" delay="1min"/>
          <behavior type="Emit" event="Leave" delay="1min"/>
          <behavior type="Alive"/>
        </sequential>
      </task>
      <task name="KeepA"><behavior type="Alive"/></task>
      <task name="KeepB"><behavior type="Alive"/></task>
      <statechart>
        <state name="Outer" task="Clock">
          <parallel name="Both">
            <region name="A" task="KeepA">
              <transition event="Restart" target="A1"/>
              <state name="A1"><transition event="Leave" target="Out"/></state>
            </region>
            <region name="B" task="KeepB">
              <state name="B1"><transition event="Swap" target="A1"/><transition event="Leave" target="B2"/></state>
              <state name="B2"/>
            </region>
          </parallel>
          <state name="Out"/>
        </state>
      </statechart>
    </policy>)xml");
  const auto starts = [&](const std::string& task) {
    int n = 0;
    for (const auto& t : f.texts("task")) n += t == "task " + task + " started";
    return n;
  };
  f.advance(1min);  // declared on region A: A alone is left and re-entered
  EXPECT_EQ(starts("KeepA"), 2);
  EXPECT_EQ(starts("KeepB"), 1);
  f.advance(1min);  // from region B into region A: the whole parallel state restarts
  EXPECT_EQ(starts("KeepA"), 3);
  EXPECT_EQ(starts("KeepB"), 2);
  f.advance(1min);  // A1's Leave exits both regions: B1's Leave, in document order after it, is preempted
  EXPECT_EQ(coordinator->configuration(), (Names{"Outer", "Out"}));
  EXPECT_EQ(f.transitions(), (Names{"A: A1 -> A1 on Restart", "B: B1 -> A1 on Swap", "A: A1 -> Out on Leave"}));
  EXPECT_EQ(starts("Clock"), 1);
  coordinator->stop();
}
