// The Policy Parser: the tree and statechart it reads, and the errors a broken policy file gets
// — each naming the file, the line and what was expected, all of them at once.
#include <gtest/gtest.h>

#include "icars/control/coordinator.h"
#include "icars/control/policy.h"

namespace b = icars::behavior;
namespace c = icars::control;

namespace {

b::BehaviorRegistry registry() {
  b::BehaviorRegistry r;
  b::register_generic_behaviors(r);
  return r;
}

std::string fixture(const std::string& name) { return std::string(ICARS_CONTROL_TESTDATA) + "/" + name; }

// The errors parsing the fixture gives, as "line: error: message" without the directory.
std::vector<std::string> errors_of(const std::string& name) {
  const auto r = registry();
  try {
    c::parse_policy_file(fixture(name), r);
  } catch (const c::PolicyError& e) {
    std::vector<std::string> out;
    for (const auto& d : e.diagnostics()) {
      EXPECT_EQ(d.file, fixture(name));
      out.push_back(std::to_string(d.line) + ": " + d.message);
    }
    return out;
  }
  ADD_FAILURE() << name << " parsed without errors";
  return {};
}

bool contains(const std::vector<std::string>& errors, const std::string& expected) {
  for (const auto& e : errors) {
    if (e.find(expected) != std::string::npos) return true;
  }
  return false;
}

}  // namespace

TEST(PolicyParser, ReadsTasksTreesAndTheStatechart) {
  const auto r = registry();
  const auto parsed = c::parse_policy(R"xml(<?xml version="1.0"?>
<policy name="demo" version="1">
  <description>two states</description>
  <task name="Watch" events="Ring, Knock" timeout="2h">
    <interpret name="hear" pass_unmatched="true">
      <rule when="event == 'Ping' and n > 3" emit="Ring"><set name="loud" value="n"/></rule>
      <rule when="event == 'Tap'" emit="Knock" copy="false"/>
      <filter pass="exists(n)" complete="any">
        <behavior type="Emit" event="Ping"><param name="delay" value="1min"/></behavior>
        <aggregate emit="Taps" count="3" window="10s" when="event == 'Tap'">
          <behavior type="Wait" duration="1h"/>
        </aggregate>
      </filter>
    </interpret>
  </task>
  <task name="Answer">
    <sequential repeat="forever" on_failure="continue"><behavior type="Wait" name="pause" duration="5min"/></sequential>
  </task>
  <statechart initial="Idle">
    <state name="Idle" task="Watch">
      <transition event="Ring" target="Busy" guard="time > 08:00"/>
    </state>
    <state name="Busy" task="Answer"/>
    <transition event="Knock" target="Idle"/>
  </statechart>
</policy>)xml",
                                      "demo.xml", r);
  const auto& p = parsed.policy;
  EXPECT_EQ(p.name, "demo");
  EXPECT_EQ(p.description, "two states");
  ASSERT_EQ(p.tasks.size(), 2u);
  const auto& watch = p.tasks[0];
  EXPECT_EQ(watch.events, (std::vector<std::string>{"Ring", "Knock"}));
  EXPECT_EQ(watch.timeout, std::chrono::hours(2));
  EXPECT_EQ(watch.root.kind, c::NodeSpec::Kind::interpret);
  EXPECT_TRUE(watch.root.pass_unmatched);
  ASSERT_EQ(watch.root.rules.size(), 2u);
  EXPECT_EQ(watch.root.rules[0].emit, "Ring");
  EXPECT_EQ(watch.root.rules[0].set.size(), 1u);
  EXPECT_FALSE(watch.root.rules[1].copy);
  const auto& filter = watch.root.children.at(0);
  EXPECT_EQ(filter.kind, c::NodeSpec::Kind::filter);
  EXPECT_EQ(filter.completion, b::Completion::any);
  EXPECT_EQ(filter.children.at(0).params.at("delay"), "1min");
  const auto& aggregate = filter.children.at(1);
  EXPECT_EQ(aggregate.aggregate.count, 3);
  EXPECT_EQ(aggregate.aggregate.window, std::chrono::seconds(10));
  const auto& answer = p.tasks[1].root;
  EXPECT_EQ(answer.sequence.repeat, 0);
  EXPECT_TRUE(answer.sequence.continue_on_failure);
  EXPECT_EQ(answer.children.at(0).name, "pause");
  EXPECT_EQ(p.root.initial, "Idle");
  ASSERT_EQ(p.root.children.size(), 2u);
  EXPECT_EQ(p.root.children[0].transitions.at(0).guard.text(), "time > 08:00");
  EXPECT_EQ(p.root.transitions.at(0).event, "Knock");
  EXPECT_EQ(p.root.children[0].line, 20);
  // Every node builds into a tree.
  auto tree = c::build_tree(watch.root, r);
  EXPECT_EQ(tree->children().size(), 1u);
  EXPECT_EQ(tree->children()[0]->children().size(), 2u);
  // A policy whose tasks may fail with no failure transition is valid, with warnings.
  EXPECT_FALSE(parsed.warnings.empty());
}

TEST(PolicyParser, MalformedXmlNamesTheLine) {
  const auto errors = errors_of("malformed_xml.xml");
  ASSERT_EQ(errors.size(), 1u);
  EXPECT_TRUE(contains(errors, "4: malformed XML: Start-end tags mismatch")) << errors[0];
}

TEST(PolicyParser, UnknownBehaviorTypeListsTheKnownOnes) {
  EXPECT_TRUE(contains(errors_of("unknown_behavior.xml"), "4: unknown behavior type 'Wiat' (known: Emit, Wait)"));
}

TEST(PolicyParser, TransitionToAStateThatDoesNotExist) {
  EXPECT_TRUE(contains(errors_of("bad_transition_target.xml"),
                       "7: transition on 'Go' goes to state 'Nowhere', which does not exist"));
}

TEST(PolicyParser, MissingAttribute) {
  EXPECT_TRUE(contains(errors_of("missing_attribute.xml"), "3: <behavior> needs a 'type' attribute"));
}

TEST(PolicyParser, BadParametersAreAllReported) {
  const auto errors = errors_of("bad_parameter.xml");
  EXPECT_TRUE(contains(errors, "4: Wait: parameter 'duration': 'ten minutes' is not a duration"));
  EXPECT_TRUE(contains(errors, "5: Wait has no parameter 'speed' (it has: duration)"));
}

TEST(PolicyParser, BadConditionNamesTheColumn) {
  EXPECT_TRUE(contains(errors_of("bad_condition.xml"), "4: in when=\"furniture == 'sofa' and\": column 24"));
}

TEST(PolicyParser, ATransitionOnAnEventNoTaskRaisesCanNeverFire) {
  EXPECT_TRUE(contains(errors_of("event_never_raised.xml"),
                       "7: transition on 'TimeToRst' in state 'S' can never fire: no task active there raises it"));
}

TEST(PolicyParser, DuplicateStatesAndUnknownTasks) {
  const auto errors = errors_of("unknown_task.xml");
  EXPECT_TRUE(contains(errors, "5: state 'S' is defined twice"));
  EXPECT_TRUE(contains(errors, "5: state 'S' runs task 'Missing', which the policy does not define"));
}

TEST(PolicyParser, TaskStructureErrors) {
  const auto errors = errors_of("wrong_structure.xml");
  EXPECT_TRUE(contains(errors, "2: task 'Empty' needs exactly one root behavior or composite, found 0"));
  EXPECT_TRUE(contains(errors, "3: task 'Two' needs exactly one root behavior or composite, found 2"));
  EXPECT_TRUE(contains(errors, "7: unknown node <parallel>"));
  EXPECT_TRUE(contains(errors, "8: initial state 'Gone' is not a child of"));
}

TEST(PolicyParser, WarningsDoNotStopAValidPolicy) {
  const auto r = registry();
  const auto parsed = c::parse_policy_file(fixture("valid_with_warnings.xml"), r);
  ASSERT_EQ(parsed.warnings.size(), 2u);
  EXPECT_EQ(parsed.warnings[0].to_string(),
            fixture("valid_with_warnings.xml") + ":2: warning: task 'T' raises 'Unused', but no transition handles it");
  EXPECT_NE(parsed.warnings[1].message.find("has no 'failed' transition"), std::string::npos);
}

TEST(PolicyParser, AMissingFileAndGarbageAreErrorsNotCrashes) {
  const auto r = registry();
  EXPECT_THROW(c::parse_policy_file("/nonexistent/policy.xml", r), c::PolicyError);
  for (const char* text : {"", "\x01\x02", "<policy/>", "<house name='x'/>", "<policy name='x'><statechart/></policy>",
                           "<policy name='x'><task name='t'><sequential repeat='-3'/></task></policy>"}) {
    EXPECT_THROW(c::parse_policy(text, "garbage.xml", r), c::PolicyError) << text;
  }
}
