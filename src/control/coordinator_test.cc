// The Coordinator running statecharts of tasks from policy text: task events drive
// transitions, hierarchical states, guards, failure and timeout transitions, and leaving a
// state destroys its task's whole behavior tree. Time is a SimClock advanced by hand.
#include <gtest/gtest.h>

#include "icars/behavior/composite.h"
#include "coordinator_fixture.h"

#include <unistd.h>

#include <filesystem>
#include <future>
#include <fstream>

namespace b = icars::behavior;
namespace c = icars::control;
using icars::Time;
using namespace std::chrono_literals;

namespace {

using Fixture = icars_test::CoordinatorFixture;
using icars_test::g_alive;

// An in-process sensor: publishes Knock events, from whichever thread calls knock().
struct Knock {
  std::int32_t n = 0;
};

}  // namespace

PLANET_EVENT(Knock, n);

namespace {

class Door final : public icars::service::Service {
 public:
  Door() : Service("door", "Door", {}) { set_available(true); }
  std::uint64_t subscribe(std::function<void(const Knock&)> fn) { return listeners_.add(std::move(fn)); }
  void unsubscribe(std::uint64_t id) { listeners_.remove(id); }
  void knock(std::int32_t n) { listeners_.notify(Knock{n}); }

 private:
  icars::service::Listeners<Knock> listeners_;
};

// Passes the door's knocks on to its parent.
class Hear final : public b::Behavior {
 public:
  explicit Hear(const b::Params&) {}

 protected:
  void entry() override { listen(require<Door>(of_type("Door"))); }
  void handle_event(const b::Event& e) override { propagate(e); }
};

}  // namespace

TEST(Coordinator, TaskEventsMoveTheStatechartAndLeavingAStateDestroysItsTask) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Watch" events="Ring">
        <concurrent>
          <behavior type="Alive"/>
          <behavior type="Emit" event="Ring" delay="10min"/>
        </concurrent>
      </task>
      <task name="Answer" events="Hangup">
        <concurrent>
          <behavior type="Alive"/>
          <behavior type="Alive"/>
          <behavior type="Emit" event="Hangup" delay="5min"/>
        </concurrent>
      </task>
      <statechart initial="Idle">
        <state name="Idle" task="Watch"><transition event="Ring" target="Talking"/></state>
        <state name="Talking" task="Answer"><transition event="Hangup" target="Idle"/></state>
      </statechart>
    </policy>)xml");
  EXPECT_EQ(coordinator->current(), "Idle");
  EXPECT_EQ(g_alive.load(), 1);
  f.advance(10min);
  EXPECT_EQ(coordinator->current(), "Talking");
  EXPECT_EQ(g_alive.load(), 2);  // Watch's tree is gone, Answer's is running
  f.advance(5min);
  EXPECT_EQ(coordinator->current(), "Idle");
  EXPECT_EQ(g_alive.load(), 1);
  EXPECT_EQ(f.transitions(), (std::vector<std::string>{"Idle -> Talking on Ring", "Talking -> Idle on Hangup"}));
  coordinator->stop();
  EXPECT_EQ(g_alive.load(), 0);
}

TEST(Coordinator, GuardsChooseBetweenTransitionsOnTheSameEvent) {
  Fixture f;
  f.clock.advance_to(icars::at_time(0, 20, 0));
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Tick" events="Tick">
        <sequential repeat="forever"><behavior type="Emit" event="Tick" delay="1h"/></sequential>
      </task>
      <statechart>
        <state name="Day" task="Tick">
          <transition event="Tick" target="Night" guard="between(time, 22:00, 06:00)"/>
          <transition event="Tick" target="Day" guard="time &lt; 22:00 and time &gt;= 06:00"/>
        </state>
        <state name="Night"/>
      </statechart>
    </policy>)xml");
  f.advance(1h);  // 21:00: self-transition (re-enters Day)
  EXPECT_EQ(coordinator->current(), "Day");
  f.advance(1h);  // 22:00
  EXPECT_EQ(coordinator->current(), "Night");
  EXPECT_EQ(f.transitions(), (std::vector<std::string>{"Day -> Day on Tick", "Day -> Night on Tick"}));
}

TEST(Coordinator, AFailedTaskTakesTheFailureTransitionInheritedFromItsParentState) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Try" events=""><behavior type="FailLater" after="3min"/></task>
      <task name="Rest" events=""><behavior type="Alive"/></task>
      <statechart initial="Working">
        <state name="Working" initial="Trying">
          <transition event="failed" target="Recovering"/>
          <state name="Trying" task="Try"/>
        </state>
        <state name="Recovering" task="Rest"/>
      </statechart>
    </policy>)xml");
  EXPECT_EQ(coordinator->configuration(), (std::vector<std::string>{"Working", "Trying"}));
  f.advance(3min);
  EXPECT_EQ(coordinator->configuration(), std::vector<std::string>{"Recovering"});
  ASSERT_EQ(f.transitions().size(), 1u);
  EXPECT_EQ(f.transitions()[0], "Trying -> Recovering on failed (FailLater failed: gave up)");
  coordinator->stop();
}

TEST(Coordinator, AStuckTaskFailsAtItsTimeout) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Stuck" timeout="30min"><behavior type="Alive"/></task>
      <statechart>
        <state name="Waiting" task="Stuck"><transition event="failed" target="Giving_up"/></state>
        <state name="Giving_up"/>
      </statechart>
    </policy>)xml");
  f.advance(29min);
  EXPECT_EQ(coordinator->current(), "Waiting");
  f.advance(1min);
  EXPECT_EQ(coordinator->current(), "Giving_up");
  EXPECT_EQ(g_alive.load(), 0);
}

TEST(Coordinator, ADoneTaskWithoutTransitionLeavesTheStateIdleAndAnUnhandledFailureIsReported) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Once"><behavior type="Wait" duration="1min"/></task>
      <task name="Bad"><behavior type="FailLater" after="1min"/></task>
      <statechart>
        <state name="A" task="Once"><transition event="done" target="B"/></state>
        <state name="B" task="Bad"/>
      </statechart>
    </policy>)xml");
  f.advance(1min);
  EXPECT_EQ(coordinator->current(), "B");
  f.advance(1min);
  EXPECT_EQ(coordinator->current(), "B");
  bool reported = false;
  for (const auto& r : f.log.of_kind("note")) {
    reported |= r.text == "task Bad failed and no transition handles it: staying in B";
  }
  EXPECT_TRUE(reported);
}

TEST(Coordinator, TransitionsBetweenNestedStatesExitAndEnterOnlyWhatChanges) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Home" events=""><behavior type="Alive"/></task>
      <task name="Step" events="Next"><behavior type="Emit" event="Next" delay="1min"/></task>
      <statechart>
        <state name="AtHome" task="Home">
          <state name="One" task="Step"><transition event="Next" target="Two"/></state>
          <state name="Two" task="Step"><transition event="Next" target="Out"/></state>
        </state>
        <state name="Out"/>
      </statechart>
    </policy>)xml");
  EXPECT_EQ(coordinator->configuration(), (std::vector<std::string>{"AtHome", "One"}));
  EXPECT_EQ(g_alive.load(), 1);
  f.advance(1min);
  EXPECT_EQ(coordinator->configuration(), (std::vector<std::string>{"AtHome", "Two"}));
  int home_starts = 0;
  for (const auto& r : f.log.of_kind("task")) home_starts += r.text == "task Home started";
  EXPECT_EQ(home_starts, 1);  // the parent state's task kept running
  f.advance(1min);
  EXPECT_EQ(coordinator->configuration(), std::vector<std::string>{"Out"});
  EXPECT_EQ(g_alive.load(), 0);
}

TEST(CollaborationManager, LoadsPoliciesByNameFromTheRepositoryAndKeepsTheRunningOneOnError) {
  Fixture f;
  const auto dir = std::filesystem::temp_directory_path() / ("icars_policies_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  {
    std::ofstream(dir / "good.xml") << R"xml(<policy name="good"><task name="T"><behavior type="Alive"/></task>
      <statechart><state name="S" task="T"/></statechart></policy>)xml";
    std::ofstream(dir / "broken.xml") << R"xml(<policy name="broken"><statechart><state name="S" task="Nope"/></statechart></policy>)xml";
  }
  c::CollaborationManager manager(c::PolicyRepository(dir.string()), f.registry, f.env);
  EXPECT_EQ(manager.repository().names(), (std::vector<std::string>{"broken", "good"}));
  manager.run("good");
  f.settle();
  ASSERT_NE(manager.coordinator(), nullptr);
  EXPECT_EQ(manager.coordinator()->current(), "S");
  EXPECT_THROW(manager.run("broken"), c::PolicyError);
  EXPECT_EQ(manager.coordinator()->policy().name, "good");
  EXPECT_EQ(g_alive.load(), 1);
  manager.stop();
  EXPECT_EQ(g_alive.load(), 0);
  std::filesystem::remove_all(dir);
}

// The Service Framework's device events reach every state's transitions, whatever its tasks
// raise: a policy can react to a device that came back with another state.
TEST(Coordinator, DeviceEventsDriveTransitionsWithGuardsOnTheirProperties) {
  Fixture f;
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Watch"><behavior type="Alive"/></task>
      <task name="Apologize"><behavior type="Alive"/></task>
      <statechart initial="Watching">
        <state name="Watching" task="Watch">
          <transition event="DeviceRestored" guard="device == 'tv' and not reapplied" target="Apologizing"/>
        </state>
        <state name="Apologizing" task="Apologize"/>
      </statechart>
    </policy>)xml");
  const auto restored = [&](const std::string& device, bool reapplied) {
    icars::planet::Event e("DeviceRestored");
    e.set("device", device).set("differences", std::string("channel 5 -> 0")).set("reapplied", reapplied);
    f.services.publish_device_event(e);
    f.settle();
  };
  restored("living_light", false);
  restored("tv", true);
  EXPECT_EQ(coordinator->current(), "Watching");
  restored("tv", false);
  EXPECT_EQ(coordinator->current(), "Apologizing");
  EXPECT_EQ(f.transitions(), (std::vector<std::string>{"Watching -> Apologizing on DeviceRestored"}));
  coordinator->stop();
}

// Run to completion: a knock that arrives right behind the one that moved the statechart is
// heard by the new state's task, not lost with the old one's — however close behind it comes.
// The runtime is held while four knocks arrive, so all four wait in its queue together.
TEST(Coordinator, AnEventRightBehindTheOneThatMovedTheStatechartReachesTheNewState) {
  Fixture f;
  f.registry.add<Hear>("Hear", "passes the door's knocks on");
  auto door = std::make_shared<Door>();
  f.services.add(door);
  auto coordinator = f.start(R"xml(
    <policy name="p">
      <task name="Idle" events="Come">
        <interpret name="Listen">
          <rule when="event == 'Knock' and n == 1" emit="Come"/>
          <behavior type="Hear"/>
        </interpret>
      </task>
      <task name="Answer" events="Gone">
        <interpret name="Listen">
          <rule when="event == 'Knock' and n == 2" emit="Gone"/>
          <behavior type="Hear"/>
        </interpret>
      </task>
      <statechart initial="Idle">
        <state name="Idle" task="Idle"><transition event="Come" target="Answering"/></state>
        <state name="Answering" task="Answer"><transition event="Gone" target="Idle"/></state>
      </statechart>
    </policy>)xml");
  std::promise<void> go;
  f.runtime.post([held = go.get_future().share()] { held.wait(); });
  for (const std::int32_t n : {1, 2, 1, 2}) door->knock(n);
  go.set_value();
  f.settle();
  EXPECT_EQ(f.transitions(), (std::vector<std::string>{"Idle -> Answering on Come", "Answering -> Idle on Gone",
                                                       "Idle -> Answering on Come", "Answering -> Idle on Gone"}));
  EXPECT_EQ(coordinator->current(), "Idle");
  coordinator->stop();
}
