// check_policy: the events declared by behavior types flow up each task's tree to the
// conditions that read them, and the names of a world are checked where parameters and
// conditions use them — each mistake reported at its line, with the nearest known name.
#include <gtest/gtest.h>

#include "icars/control/policy.h"
#include "icars/control/policy_check.h"

namespace b = icars::behavior;
namespace c = icars::control;

namespace {

class Quiet final : public b::Behavior {
 public:
  explicit Quiet(const b::Params&) {}
};

// Generic behaviors plus: Watch (propagates DoorEvent{door, open} and Chime{}), Go (a place and
// a robot), Lights (a list of rooms) and Legacy (declares nothing).
b::BehaviorRegistry registry() {
  b::BehaviorRegistry r;
  b::register_generic_behaviors(r);
  r.add<Quiet>("Watch", "door events", {b::param("room", b::ParamType::string, "", "where").naming("room")});
  r.declare_events("Watch", {{"DoorEvent", {"door", "open", "room"}}, {"Chime", {}}});
  r.add<Quiet>("Go", "drives", {b::param("target", b::ParamType::string, std::nullopt, "where").naming("place"),
                                b::param("robot", b::ParamType::string, "", "which").naming("robot")});
  r.declare_events("Go", {});
  r.add<Quiet>("Lights", "switches", {b::param("rooms", b::ParamType::list, "", "which").naming("room")});
  r.declare_events("Lights", {});
  r.add<Quiet>("Legacy", "declares nothing");
  return r;
}

b::Vocabulary flat() {
  b::Vocabulary v;
  v.source = "flat.xml";
  v.names["room"] = {"hall", "study", "kitchen"};
  v.names["place"] = {"hall", "study", "kitchen", "dock", "bed"};
  v.names["robot"] = {"r1"};
  v.names["door"] = {"front", "back"};
  v.property_kinds = {{"room", "room"}, {"door", "door"}};
  return v;
}

std::string policy(const std::string& tasks) {
  return R"(<policy name="p">
)" + tasks + R"(
  <statechart initial="A"><state name="A" task="T"/></statechart>
</policy>
)";
}

std::vector<std::string> problems(const std::string& tasks, const b::Vocabulary& world = flat()) {
  const auto r = registry();
  const auto parsed = c::parse_policy(policy(tasks), "p.xml", r);
  std::vector<std::string> out;
  for (const auto& d : c::check_policy(parsed.policy, r, world)) {
    EXPECT_EQ(d.file, "p.xml");
    EXPECT_FALSE(d.warning);
    out.push_back(std::to_string(d.line) + ": " + d.message);
  }
  return out;
}

TEST(PolicyCheck, AFittingPolicyHasNoProblems) {
  EXPECT_EQ(problems(R"(<task name="T" events="Opened">
    <concurrent>
      <interpret>
        <rule when="event == 'DoorEvent' and open and door == 'front' and room != 'hall'" emit="Opened">
          <set name="where" value="room"/>
        </rule>
        <behavior type="Watch" room="study"/>
      </interpret>
      <sequential>
        <behavior type="Go" target="dock" robot="r1"/>
        <behavior type="Lights" rooms="hall, kitchen"/>
      </sequential>
    </concurrent>
  </task>)"),
            std::vector<std::string>{});
}

TEST(PolicyCheck, ParametersNamingWhatTheWorldLacksAreErrorsWithTheNearestName) {
  const auto found = problems(R"(<task name="T">
    <sequential>
      <behavior type="Lights" rooms="hall, studdy"/>
      <behavior type="Go" target="dok"/>
      <behavior type="Go" target="hall" robot="robot9"/>
      <behavior type="Watch" room="garage"/>
    </sequential>
  </task>)");
  ASSERT_EQ(found.size(), 4u) << ::testing::PrintToString(found);
  EXPECT_EQ(found[0], "4: Lights rooms: 'studdy' is not a room of flat.xml (did you mean 'study'?)");
  EXPECT_EQ(found[1], "5: Go target: 'dok' is not a place of flat.xml (did you mean 'dock'?)");
  EXPECT_EQ(found[2], "6: Go robot: 'robot9' is not a robot of flat.xml (known: r1)");
  EXPECT_EQ(found[3], "7: Watch room: 'garage' is not a room of flat.xml (known: hall, kitchen, study)");
}

TEST(PolicyCheck, AConditionReadingAPropertyNoEventCarriesIsAnError) {
  const auto found = problems(R"(<task name="T" events="Opened">
    <interpret>
      <rule when="event == 'DoorEvent' and opne" emit="Opened"/>
      <behavior type="Watch"/>
    </interpret>
  </task>)");
  ASSERT_EQ(found.size(), 1u) << ::testing::PrintToString(found);
  EXPECT_EQ(found[0], "4: <rule> when \"event == 'DoorEvent' and opne\": no event reaching it carries 'opne' "
                      "(did you mean 'open'?)");
}

TEST(PolicyCheck, ComparingEventWithAnEventThatCannotArriveIsAnError) {
  const auto found = problems(R"(<task name="T" events="Opened">
    <interpret>
      <rule when="event == 'DorEvent'" emit="Opened"/>
      <rule when="event == 'Chime'" emit="Opened"/>
      <behavior type="Watch"/>
    </interpret>
  </task>)");
  ASSERT_EQ(found.size(), 1u) << ::testing::PrintToString(found);
  EXPECT_NE(found[0].find("no event 'DorEvent' reaches it (did you mean 'DoorEvent'?)"), std::string::npos) << found[0];
}

TEST(PolicyCheck, ComparingANamePropertyWithANameTheWorldLacksIsAnError) {
  const auto found = problems(R"(<task name="T" events="Opened">
    <filter pass="door == 'frnt' or room == 'hall'">
      <behavior type="Watch"/>
    </filter>
  </task>)");
  ASSERT_EQ(found.size(), 1u) << ::testing::PrintToString(found);
  EXPECT_NE(found[0].find("'frnt' is not a door of flat.xml (did you mean 'front'?)"), std::string::npos) << found[0];
}

TEST(PolicyCheck, EventsFlowThroughInterpretAndAggregateNodes) {
  // Opened carries the DoorEvent's properties (copy) and `where`; Many adds count.
  EXPECT_EQ(problems(R"(<task name="T" events="Many">
    <interpret>
      <rule when="event == 'Many' and count >= 2 and door == 'back' and where == 'hall'" emit="Many"/>
      <aggregate when="event == 'Opened'" emit="Many" count="2">
        <interpret>
          <rule when="event == 'DoorEvent'" emit="Opened"><set name="where" value="room"/></rule>
          <behavior type="Watch"/>
        </interpret>
      </aggregate>
    </interpret>
  </task>)"),
            std::vector<std::string>{});
  // Without copy="true", Opened carries only what the rule sets.
  const auto found = problems(R"(<task name="T" events="Back">
    <interpret>
      <rule when="door == 'back'" emit="Back"/>
      <interpret>
        <rule when="event == 'DoorEvent'" emit="Opened" copy="false"/>
        <behavior type="Watch"/>
      </interpret>
    </interpret>
  </task>)");
  ASSERT_EQ(found.size(), 1u) << ::testing::PrintToString(found);
  EXPECT_NE(found[0].find("no event reaching it carries 'door'"), std::string::npos) << found[0];
}

TEST(PolicyCheck, EmitRaisesTheEventItsParameterNames) {
  EXPECT_EQ(problems(R"(<task name="T" events="Go">
    <interpret>
      <rule when="event == 'Tick'" emit="Go"/>
      <behavior type="Emit" event="Tick"/>
    </interpret>
  </task>)"),
            std::vector<std::string>{});
}

TEST(PolicyCheck, UndeclaredBehaviorsAndKindsTheWorldDoesNotListAreNotGuessedAt) {
  // Legacy declares nothing: any event may come from it.
  EXPECT_EQ(problems(R"(<task name="T" events="X">
    <interpret>
      <rule when="event == 'Whatever' and anything" emit="X"/>
      <behavior type="Legacy"/>
    </interpret>
  </task>)"),
            std::vector<std::string>{});
  // Without a world, names are not checked; the events still are.
  const auto found = problems(R"(<task name="T" events="X">
    <interpret>
      <rule when="event == 'DoorEvent' and door == 'nowhere' and opne" emit="X"/>
      <behavior type="Watch" room="nowhere"/>
    </interpret>
  </task>)",
                              b::Vocabulary{});
  ASSERT_EQ(found.size(), 1u) << ::testing::PrintToString(found);
  EXPECT_NE(found[0].find("'opne'"), std::string::npos);
}

TEST(PolicyCheck, WhenAndConditionsHearTheirSiblingsThroughDecorators) {
  // <when> beside Watch, a decorator between them and the events; conditions of a reactive
  // composite hear what reaches the composite; decorators pass their child's events up.
  EXPECT_EQ(problems(R"(<task name="T" events="Opened">
    <concurrent>
      <behavior type="Watch"/>
      <timeout after="1h">
        <when event="DoorEvent" if="open and door == 'front'" running="restart">
          <retry times="2"><behavior type="Go" target="hall"/></retry>
        </when>
      </timeout>
      <reactive_fallback>
        <condition event="DoorEvent" if="not open and room == 'hall'"/>
        <behavior type="Lights" rooms="hall"/>
      </reactive_fallback>
      <interpret>
        <rule when="event == 'Chime'" emit="Opened"/>
        <invert><behavior type="Watch"/></invert>
      </interpret>
    </concurrent>
  </task>)"),
            std::vector<std::string>{});
}

TEST(PolicyCheck, WhenAndConditionMistakesAreCheckedAgainstTheEventsReachingThem) {
  const auto found = problems(R"(<task name="T">
    <concurrent>
      <behavior type="Watch"/>
      <when event="DoorEvnt"><behavior type="Go" target="hall"/></when>
      <when event="DoorEvent" if="opn"><behavior type="Go" target="hall"/></when>
      <when event="Chime" if="open"><behavior type="Go" target="hall"/></when>
      <reactive_sequence>
        <condition event="DoorEvent" if="room == 'hal'"/>
        <behavior type="Go" target="hall"/>
      </reactive_sequence>
    </concurrent>
  </task>
  <task name="Alone">
    <when event="DoorEvent"><behavior type="Watch"/></when>
  </task>)");
  ASSERT_EQ(found.size(), 5u) << ::testing::PrintToString(found);
  EXPECT_EQ(found[0], "5: <when> event=\"DoorEvnt\": no event 'DoorEvnt' reaches it (did you mean 'DoorEvent'?)");
  EXPECT_EQ(found[1], "6: <when> if \"opn\": no event reaching it carries 'opn' (did you mean 'open'?)");
  // `if` reads the properties of the event type it is about: a Chime carries none.
  EXPECT_EQ(found[2], "7: <when> if \"open\": no event reaching it carries 'open' (there are none)");
  EXPECT_EQ(found[3], "9: <condition> if \"room == 'hal'\": 'hal' is not a room of flat.xml (did you mean 'hall'?)");
  // A task's root has no siblings: nothing reaches it (its own child's events do not).
  EXPECT_EQ(found[4], "15: <when> event=\"DoorEvent\": no event 'DoorEvent' reaches it (nothing reaches it: a "
                      "<when> hears the events its siblings propagate; put it in a <concurrent> beside a behavior "
                      "that propagates them)");
}

}  // namespace
