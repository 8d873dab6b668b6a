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

// The errors parsing `xml` gives, as "line: message".
std::vector<std::string> errors_in(const std::string& xml) {
  const auto r = registry();
  try {
    c::parse_policy(xml, "inline.xml", r);
  } catch (const c::PolicyError& e) {
    std::vector<std::string> out;
    for (const auto& d : e.diagnostics()) out.push_back(std::to_string(d.line) + ": " + d.message);
    return out;
  }
  ADD_FAILURE() << "parsed without errors:\n" << xml;
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
  // At the closing tag, with its column, naming the element left open (xmllint's line).
  EXPECT_TRUE(contains(errors, "4: malformed XML: </task> closes <behavior> opened at line 3, expected </behavior>"))
      << errors[0];
  try {
    c::parse_policy_file(fixture("malformed_xml.xml"), registry());
  } catch (const c::PolicyError& e) {
    EXPECT_EQ(e.diagnostics().at(0).column, 3);
    EXPECT_NE(e.diagnostics().at(0).to_string().find("malformed_xml.xml:4:3: error: "), std::string::npos);
  }
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

TEST(PolicyParser, ReadsParallelStatesRegionsFinalStatesHistoryAndDelays) {
  const auto r = registry();
  const auto parsed = c::parse_policy(R"xml(<policy name="p">
  <task name="T"><behavior type="Wait" duration="1s"/></task>
  <statechart>
    <transition event="failed" target="Done"/>
    <parallel name="P" task="T">
      <transition event="done" target="Done"/>
      <region name="R1" initial="B" history="deep">
        <state name="A"/>
        <state name="B"><transition after="90s" target="A" guard="time > 08:00"/></state>
        <final name="R1End"/>
      </region>
      <region name="R2"><send event="Ping" after="2min"/><transition event="Ping" target="R2End"/><final name="R2End"/></region>
    </parallel>
    <final name="Done"/>
  </statechart>
</policy>)xml",
                                      "p.xml", r);
  using Kind = c::StateSpec::Kind;
  const auto& p = parsed.policy.root.children.at(0);
  EXPECT_EQ(p.kind, Kind::parallel);
  EXPECT_EQ(p.task, "T");
  ASSERT_EQ(p.children.size(), 2u);
  const auto& r1 = p.children[0];
  EXPECT_EQ(r1.kind, Kind::region);
  EXPECT_EQ(r1.history, c::StateSpec::History::deep);
  EXPECT_EQ(r1.initial, "B");
  EXPECT_EQ(r1.children.at(2).kind, Kind::final);
  const auto& after = r1.children.at(1).transitions.at(0);
  EXPECT_EQ(after.after, std::chrono::seconds(90));
  EXPECT_TRUE(after.event.empty());
  EXPECT_EQ(after.line, 9);
  const auto& r2 = p.children[1];
  ASSERT_EQ(r2.sends.size(), 1u);
  EXPECT_EQ(r2.sends[0].event, "Ping");
  EXPECT_EQ(r2.sends[0].after, std::chrono::minutes(2));
  EXPECT_EQ(parsed.policy.root.children.at(1).kind, Kind::final);
  EXPECT_TRUE(parsed.warnings.empty()) << parsed.warnings.at(0).to_string();
}

TEST(PolicyParser, StatechartMistakesAreLocatedErrors) {
  const auto errors = errors_of("statechart_mistakes.xml");
  for (const auto* expected : {
           "5: <parallel> has no attribute 'history' (it takes: name, task)",
           "5: parallel state 'P' needs at least two <region>s, found 1",
           "6: initial state 'Gone' is not a child of 'Only'",
           "7: unexpected <state> in <parallel> (expected <region>, <transition> or <send>)",
           "8: unexpected <final> in <parallel>",
           "10: <final> has no attribute 'task' (it takes: name)",
           "11: final state 'F2' cannot hold <transition>: a final state has no task, child states or transitions",
           "13: parameter 'after': 'ten minutes' is not a duration",
           "14: after=\"0s\": a delayed transition needs a duration longer than 0",
           "15: <transition> takes an 'event' or an 'after' delay, not both",
           "16: <transition> needs an 'event' attribute (or 'after' for a delayed transition)",
           "17: transition after a delay goes to state 'Nowhere', which does not exist",
           "18: <send> cannot raise 'failed'",
           "19: parameter 'after': 'soon' is not a duration",
           "20: <region> belongs in <parallel>, not in <state>",
           "22: history=\"shallow\" on 'Leaf', which has no child states",
           "23: history=\"wide\": expected shallow or deep",
           "24: state 'A' is defined twice",
       }) {
    EXPECT_TRUE(contains(errors, expected)) << expected;
  }
  EXPECT_EQ(errors.size(), 18u) << ::testing::PrintToString(errors);
}

// The tasks of every region of a parallel state count where that parallel state is active, and
// only there; a state's <send> counts like its task.
TEST(PolicyParser, EventsOfRegionsCountWhileTheirParallelStateIsActive) {
  const auto errors = errors_of("statechart_events.xml");
  ASSERT_EQ(errors.size(), 1u) << ::testing::PrintToString(errors);
  EXPECT_TRUE(contains(errors, "13: transition on 'Opened' in state 'Outside' can never fire: no task active there raises it"))
      << errors[0];
}

TEST(PolicyParser, WarnsOfAParallelStateThatCannotCompleteAndOfAnUnhandledSend) {
  const auto r = registry();
  const auto parsed = c::parse_policy(R"xml(<policy name="p">
  <statechart>
    <parallel name="P">
      <transition event="done" target="Q"/>
      <region name="R1"><final name="End"/></region>
      <region name="R2"><state name="Q"><send event="Nobody"/></state></region>
    </parallel>
  </statechart>
</policy>)xml",
                                      "p.xml", r);
  ASSERT_EQ(parsed.warnings.size(), 2u);
  EXPECT_EQ(parsed.warnings[0].to_string(),
            "p.xml:6: warning: region 'R2' has no <final>: parallel state 'P' never completes, so its 'done' "
            "transition fires only on a task's done");
  EXPECT_EQ(parsed.warnings[1].to_string(),
            "p.xml:6: warning: state 'Q' sends 'Nobody', but no transition handles it");
}

TEST(PolicyParser, ReadsFallbackReactiveNodesAndDecorators) {
  const auto r = registry();
  const auto parsed = c::parse_policy(R"xml(<policy name="control">
  <task name="T" events="Ping">
    <concurrent>
      <behavior type="Emit" event="Ping" delay="1min"/>
      <when name="OnPing" event="Ping" if="time > 08:00" running="restart" times="3" on_failure="continue">
        <retry times="2" delay="10s">
          <timeout after="30s"><behavior type="Wait" duration="5s"/></timeout>
        </retry>
      </when>
      <reactive_fallback>
        <condition name="Pinged" event="Ping"/>
        <repeat times="forever"><invert><behavior type="Wait" duration="1s"/></invert></repeat>
      </reactive_fallback>
      <reactive_sequence><condition event="Ping" if="true"/><behavior type="Wait" duration="1s"/></reactive_sequence>
      <fallback><behavior type="Wait" duration="1s"/><behavior type="Wait" duration="2s"/></fallback>
    </concurrent>
  </task>
  <statechart><transition event="failed" target="S"/><state name="S" task="T"/></statechart>
</policy>)xml",
                                      "control.xml", r);
  const auto& root = parsed.policy.tasks.at(0).root;
  ASSERT_EQ(root.children.size(), 5u);
  const auto& when = root.children[1];
  EXPECT_EQ(when.kind, c::NodeSpec::Kind::when);
  EXPECT_EQ(when.name, "OnPing");
  EXPECT_EQ(when.when.trigger.event, "Ping");
  EXPECT_EQ(when.when.trigger.condition.text(), "time > 08:00");
  EXPECT_EQ(when.when.while_running, b::WhileRunning::restart);
  EXPECT_EQ(when.when.times, 3);
  EXPECT_TRUE(when.when.continue_on_failure);
  const auto& retry = when.children.at(0);
  EXPECT_EQ(retry.kind, c::NodeSpec::Kind::retry);
  EXPECT_EQ(retry.times, 2);
  EXPECT_EQ(retry.delay, std::chrono::seconds(10));
  const auto& timeout = retry.children.at(0);
  EXPECT_EQ(timeout.kind, c::NodeSpec::Kind::timeout);
  EXPECT_EQ(timeout.limit, std::chrono::seconds(30));
  const auto& reactive_fallback = root.children[2];
  EXPECT_EQ(reactive_fallback.kind, c::NodeSpec::Kind::reactive_fallback);
  EXPECT_EQ(reactive_fallback.children.at(0).kind, c::NodeSpec::Kind::condition);
  EXPECT_EQ(reactive_fallback.children.at(0).trigger.event, "Ping");
  EXPECT_TRUE(reactive_fallback.children.at(0).trigger.condition.empty());
  const auto& repeat = reactive_fallback.children.at(1);
  EXPECT_EQ(repeat.kind, c::NodeSpec::Kind::repeat);
  EXPECT_EQ(repeat.times, 0);  // forever
  EXPECT_EQ(repeat.children.at(0).kind, c::NodeSpec::Kind::invert);
  EXPECT_EQ(root.children[3].kind, c::NodeSpec::Kind::reactive_sequence);
  EXPECT_EQ(root.children[3].children.at(0).name, "condition");  // the element name by default
  EXPECT_EQ(root.children[4].kind, c::NodeSpec::Kind::fallback);
  // Each builds into the behavior layer's node, named as given.
  const auto tree = c::build_tree(root, r);
  const auto& on_ping = *tree->children()[1];
  EXPECT_NE(dynamic_cast<const b::WhenBehavior*>(&on_ping), nullptr);
  EXPECT_EQ(on_ping.name(), "OnPing");
  EXPECT_EQ(on_ping.type(), "when");
  EXPECT_NE(dynamic_cast<const b::RetryBehavior*>(on_ping.children()[0].get()), nullptr);
  EXPECT_NE(dynamic_cast<const b::TimeoutBehavior*>(on_ping.children()[0]->children()[0].get()), nullptr);
  const auto& fallback = *tree->children()[2];
  EXPECT_NE(dynamic_cast<const b::ReactiveFallbackBehavior*>(&fallback), nullptr);
  EXPECT_NE(dynamic_cast<const b::ConditionBehavior*>(fallback.children()[0].get()), nullptr);
  EXPECT_NE(dynamic_cast<const b::RepeatBehavior*>(fallback.children()[1].get()), nullptr);
  EXPECT_NE(dynamic_cast<const b::InvertBehavior*>(fallback.children()[1]->children()[0].get()), nullptr);
  EXPECT_NE(dynamic_cast<const b::ReactiveSequenceBehavior*>(tree->children()[3].get()), nullptr);
  EXPECT_NE(dynamic_cast<const b::FallbackBehavior*>(tree->children()[4].get()), nullptr);
}

TEST(PolicyParser, MistakesInReactiveNodesAndDecoratorsAreLocatedErrors) {
  const auto errors = errors_in(R"xml(<policy name="bad">
  <task name="T">
    <concurrent>
      <when if="true"><behavior type="Wait" duration="1s"/></when>
      <when event="E" running="sometimes" times="twice" on_failure="retry"><behavior type="Wait" duration="1s"/></when>
      <when event="E"><behavior type="Wait" duration="1s"/><behavior type="Wait" duration="1s"/></when>
      <retry><behavior type="Wait" duration="1s"/></retry>
      <retry times="-1" delay="soon"><behavior type="Wait" duration="1s"/></retry>
      <timeout><behavior type="Wait" duration="1s"/></timeout>
      <timeout after="0s"><behavior type="Wait" duration="1s"/></timeout>
      <invert/>
      <repeat times="3" until="done"><behavior type="Wait" duration="1s"/></repeat>
      <fallback/>
      <sequential><condition event="E"/></sequential>
      <reactive_sequence>
        <condition event="E" if="occupied =="/>
        <condition event="E"><behavior type="Wait" duration="1s"/></condition>
      </reactive_sequence>
      <selector/>
    </concurrent>
  </task>
  <task name="Root"><condition event="E"/></task>
  <statechart><state name="S" task="T"/></statechart>
</policy>)xml");
  for (const char* expected : {
           "4: <when> needs a 'event' attribute",
           "5: running=\"sometimes\": expected restart or ignore",
           "5: times=\"twice\": expected a count (1, 2, ...) or forever",
           "5: on_failure=\"retry\": expected fail or continue",
           "6: <when> wraps exactly one node, found 2",
           "7: <retry> needs a 'times' attribute",
           "8: times=\"-1\": expected a count (1, 2, ...) or forever",
           "8: parameter 'delay': 'soon' is not a duration",
           "9: <timeout> needs a 'after' attribute",
           "10: after=\"0s\": expected a duration longer than 0 (30s, 5min)",
           "11: <invert> wraps exactly one node, found 0",
           "12: <repeat> has no attribute 'until' (it takes: name, host, times)",
           "13: <fallback> needs at least one node",
           "14: <condition> belongs in <reactive_sequence> or <reactive_fallback>, not in <sequential>",
           "16: in if=\"occupied ==\": column 12: expected an expression",
           "17: unexpected <behavior> in <condition> (it takes no children)",
           "19: unknown node <selector> (expected behavior, sequential, fallback, concurrent, filter, interpret, "
           "aggregate, reactive_sequence, reactive_fallback, when, retry, repeat, timeout or invert)",
           "22: <condition> belongs in <reactive_sequence> or <reactive_fallback>, not in <task>",
       }) {
    EXPECT_TRUE(contains(errors, expected)) << expected << "\nin:\n" << ::testing::PrintToString(errors);
  }
}
