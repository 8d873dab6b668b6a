// Behavior subtrees on another server (idl/behavior.idl, remote_tree.h): two servers in one
// process, each with its own communicator, runtime, services and trace, over loopback TCP. A
// subtree placed on server B stays part of server A's tree: its events reach its parent and
// siblings on A, its siblings' events reach it on B, it completes its node, halting the node
// halts it, and a host that goes away fails the node with the reason.
#include <gtest/gtest.h>

#include <atomic>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "child_process.h"
#include "icars/behavior/composite.h"
#include "icars/behavior/registry.h"
#include "icars/clock/wall_clock.h"
#include "icars/control/collaboration.h"
#include "icars/control/remote_tree.h"
#include "icars/control/tree_builder.h"

namespace icars::control {
namespace {

using namespace std::chrono_literals;
namespace b = icars::behavior;
namespace p = icars::planet;

// One server's side: what its behaviors run on.
struct Side {
  Side() : runtime(clock), env{runtime, services, trace} {
    b::register_generic_behaviors(registry);
    trace.add_sink([this](const b::TraceRecord& r) {
      std::lock_guard lock(mutex);
      records.push_back(r.source + ": " + r.text);
    });
  }
  bool recorded(const std::string& text) {
    std::lock_guard lock(mutex);
    for (const auto& r : records) {
      if (r.find(text) != std::string::npos) return true;
    }
    return false;
  }
  // Gone in the reverse order: the communicator's io thread first, then the runtime's thread,
  // then what their handlers use.
  std::mutex mutex;
  std::vector<std::string> records;
  WallClock clock;
  service::ServiceContainer services;
  b::Trace trace;
  b::Runtime runtime;
  b::Environment env;
  b::BehaviorRegistry registry;
  p::Communicator communicator{named_icars()};  // both alike, as two icars servers are by default

  static p::CommunicatorOptions named_icars() {
    p::CommunicatorOptions o;
    o.name = "icars";
    return o;
  }
};

// The owner of a tree's root on server A: what reaches the top, and how the tree ended.
class Top final : public b::Owner {
 public:
  void child_event(b::Behavior&, const b::Event& e) override {
    std::lock_guard lock(mutex_);
    events_.push_back(e.type());
  }
  void child_done(b::Behavior& root) override {
    std::lock_guard lock(mutex_);
    done_ = std::string(b::to_string(root.status())) + (root.failure_reason().empty() ? "" : ": " + root.failure_reason());
  }
  std::vector<std::string> events() {
    std::lock_guard lock(mutex_);
    return events_;
  }
  std::string done() {
    std::lock_guard lock(mutex_);
    return done_;
  }

 private:
  std::mutex mutex_;
  std::vector<std::string> events_;
  std::string done_;
};

class RemoteTree : public ::testing::Test {
 protected:
  void SetUp() override {
    host_ = std::make_shared<SubtreeHost>(b_->env, b_->registry, b_->communicator);
    b_->communicator.adapter().add(std::string(kBehaviorHostPath), host_);
    b_port_ = b_->communicator.listen("127.0.0.1", 0);
    hosts_ = std::make_unique<RemoteHosts>(a_.communicator);
    hosts_->add("B", "127.0.0.1", b_port_);
    ASSERT_TRUE(hosts_->wait_connected("B", 20s));
  }
  void TearDown() override {
    if (root_) a_.runtime.run([this] { root_.reset(); });
    hosts_.reset();
  }
  // Starts `root` on A's runtime, owned by top_.
  void start(std::unique_ptr<b::Behavior> root) {
    root_ = std::move(root);
    a_.runtime.run([this] {
      root_->attach(a_.env, top_, "");
      root_->start();
    });
  }
  std::unique_ptr<b::Behavior> local(const std::string& xml) { return build_tree(parse_subtree(xml, a_.registry), a_.registry); }

  Side a_;
  std::unique_ptr<Side> b_ = std::make_unique<Side>();
  std::shared_ptr<SubtreeHost> host_;
  std::unique_ptr<RemoteHosts> hosts_;
  std::uint16_t b_port_ = 0;
  Top top_;
  std::unique_ptr<b::Behavior> root_;
};

TEST_F(RemoteTree, ASubtreeOnAnotherServerIsPartOfTheTree) {
  // A's Near says Pong at once; B's Far, beside it, answers Pong with Pang; A's Echo, beside both,
  // answers Pang with Echoed. (A <when> hears its siblings; docs/policy.md, "What reaches a node".)
  auto all = std::make_unique<b::ConcurrentBehavior>(b::Completion::all);
  all->set_identity("concurrent", "Both");
  all->add_child(local(R"(<sequential name="Near"><behavior type="Emit" event="Pong"/></sequential>)"));
  all->add_child(hosts_->make("B", "Far",
                              R"(<when name="Far" event="Pong" times="1"><behavior type="Emit" event="Pang"/></when>)"));
  all->add_child(local(R"(<when name="Echo" event="Pang" times="1"><behavior type="Emit" event="Echoed"/></when>)"));
  start(std::move(all));

  ASSERT_TRUE(planet_test::wait_until([&] { return !top_.done().empty(); }, 30s))
      << ::testing::PrintToString(top_.events()) << "\nA: " << ::testing::PrintToString(a_.records)
      << "\nB: " << ::testing::PrintToString(b_->records);
  EXPECT_EQ(top_.done(), "succeeded");
  // What reached the top, in order: A's Pong, B's Pang (through the placeholder), A's Echoed.
  EXPECT_EQ(top_.events(), (std::vector<std::string>{"Pong", "Pang", "Echoed"}));
  // B traced its part of the tree under A's paths.
  EXPECT_TRUE(b_->recorded("Both/Far/Emit: Both/Far/Emit succeeded"));
  EXPECT_TRUE(planet_test::wait_until([&] { return host_->running() == 0; }, 10s));
}

TEST_F(RemoteTree, HaltingTheNodeHaltsTheSubtreeOnItsHost) {
  start(hosts_->make("B", "Long", R"(<sequential name="Long"><behavior type="Wait" duration="1h"/></sequential>)"));
  ASSERT_TRUE(planet_test::wait_until([&] { return b_->recorded("Long/Wait started"); }, 30s));
  EXPECT_EQ(host_->running(), 1u);
  a_.runtime.run([this] { root_->halt(); });
  EXPECT_TRUE(planet_test::wait_until([&] { return host_->running() == 0; }, 30s));
  EXPECT_TRUE(planet_test::wait_until([&] { return b_->recorded("Long/Wait halted"); }, 30s));
  EXPECT_EQ(top_.done(), "") << "a halted node does not complete";
}

TEST_F(RemoteTree, AHostThatGoesAwayFailsTheNodeWithTheReason) {
  start(hosts_->make("B", "Long", R"(<sequential name="Long"><behavior type="Wait" duration="1h"/></sequential>)"));
  ASSERT_TRUE(planet_test::wait_until([&] { return host_->running() == 1; }, 30s));
  host_.reset();
  b_.reset();  // server B stops: its sockets close
  ASSERT_TRUE(planet_test::wait_until([&] { return !top_.done().empty(); }, 30s));
  EXPECT_TRUE(top_.done().starts_with("failed: disconnected: host B")) << top_.done();
}

TEST_F(RemoteTree, ASubtreeTheHostCannotBuildFailsTheNodeWithTheHostsReason) {
  start(hosts_->make("B", "Odd", R"(<sequential name="Odd"><behavior type="Juggle"/></sequential>)"));
  ASSERT_TRUE(planet_test::wait_until([&] { return !top_.done().empty(); }, 30s));
  EXPECT_NE(top_.done().find("host B did not start Odd"), std::string::npos) << top_.done();
  EXPECT_NE(top_.done().find("Juggle"), std::string::npos) << top_.done();
  EXPECT_EQ(host_->running(), 0u);
}

// A policy places a node on host B with host="B": the Coordinator's task runs it there and
// moves on when it is done; B going away mid-task is a failure transition with the reason.
constexpr const char* kSplitPolicy = R"xml(<?xml version="1.0" encoding="UTF-8"?>
<policy name="split">
  <task name="Work">
    <sequential name="Round">
      <behavior type="Wait" name="Far" duration="{far}" host="B"/>
      <behavior type="Emit" event="Near"/>
    </sequential>
  </task>
  <task name="Idle"><behavior type="Wait" duration="1h"/></task>
  <statechart initial="Working">
    <transition event="failed" target="Trouble"/>
    <state name="Working" task="Work"><transition event="done" target="Finished"/></state>
    <state name="Finished" task="Idle"/>
    <state name="Trouble" task="Idle"/>
  </statechart>
</policy>
)xml";

std::string split_policy(const std::string& far) {
  std::string xml = kSplitPolicy;
  xml.replace(xml.find("{far}"), 5, far);
  return xml;
}

TEST_F(RemoteTree, APolicysNodeWithAHostRunsThereAndItsTaskGoesOn) {
  const auto parsed = parse_policy(split_policy("50ms"), "split.xml", a_.registry);
  auto coordinator = PolicyFactory(a_.registry, hosts_.get()).create(parsed.policy, a_.env);
  coordinator->start();
  ASSERT_TRUE(planet_test::wait_until([&] { return coordinator->current() == "Finished"; }, 30s))
      << coordinator->current() << "\nA: " << ::testing::PrintToString(a_.records);
  EXPECT_TRUE(b_->recorded("Work/Round/Far succeeded")) << ::testing::PrintToString(b_->records);
  coordinator->stop();
}

TEST_F(RemoteTree, AHostGoneMidTaskIsAFailureTransitionWithTheReason) {
  const auto parsed = parse_policy(split_policy("1h"), "split.xml", a_.registry);
  auto coordinator = PolicyFactory(a_.registry, hosts_.get()).create(parsed.policy, a_.env);
  coordinator->start();
  ASSERT_TRUE(planet_test::wait_until([&] { return b_->recorded("Work/Round/Far started"); }, 30s)) << ::testing::PrintToString(b_->records);
  host_.reset();
  b_.reset();  // server B stops: its sockets close
  ASSERT_TRUE(planet_test::wait_until([&] { return coordinator->current() == "Trouble"; }, 30s)) << coordinator->current();
  EXPECT_TRUE(a_.recorded("Working -> Trouble on failed")) << ::testing::PrintToString(a_.records);
  EXPECT_TRUE(a_.recorded("disconnected: host B")) << ::testing::PrintToString(a_.records);
  coordinator->stop();
}

TEST(RemoteTreePolicy, AHostAttributeIsCheckedAndAServerWithoutThatHostFailsTheTask) {
  b::BehaviorRegistry registry;
  b::register_generic_behaviors(registry);
  const auto bad = [&](const std::string& attribute) {
    std::string xml = kSplitPolicy;
    xml.replace(xml.find("host=\"B\""), 8, attribute);
    xml.replace(xml.find("{far}"), 5, "1s");
    try {
      parse_policy(xml, "split.xml", registry);
    } catch (const PolicyError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(bad("host=\"\"").find("expected the name of a behavior host"), std::string::npos);
  EXPECT_NE(bad("host=\"a b\"").find("expected the name of a behavior host"), std::string::npos);
  // The node's XML, as the host will build it, without the attribute.
  const auto parsed = parse_policy(split_policy("1s"), "split.xml", registry);
  const auto& far = parsed.policy.task("Work")->root.children.at(0);
  EXPECT_EQ(far.host, "B");
  EXPECT_EQ(far.xml, R"(<behavior type="Wait" name="Far" duration="1s"/>)");
  EXPECT_THROW(build_tree(parsed.policy.task("Work")->root, registry), std::invalid_argument);
}

// Bad input from a peer: a host answers malformed descriptions with SubtreeRefused and the
// parser's reason, ignores events with malformed bytes and calls for subtrees it does not have.
TEST_F(RemoteTree, AHostRefusesMalformedSubtreesAndIgnoresBadEventsAndUnknownIds) {
  p::Communicator caller;
  auto peer = caller.connect("127.0.0.1", b_port_);
  ASSERT_TRUE(peer->wait_connected(20s));
  remote::BehaviorHostPrx b(caller, peer, std::string(kBehaviorHostPath));
  for (const std::string xml : {"<sequential name=\"Open\"", "", "<task name=\"T\"/>", "not xml at all",
                                R"(<behavior type="Wait" duration="soon"/>)", "<sequential/><sequential/>",
                                // out of the host's wrapper into a task of its own
                                R"(<behavior type="Wait" duration="1s"/></task><task name="Other">)"
                                R"(<behavior type="Wait" duration="1h"/>)"}) {
    try {
      b.start("X", xml);
      ADD_FAILURE() << "started: " << xml;
    } catch (const remote::SubtreeRefused& e) {
      EXPECT_FALSE(e.reason().empty()) << xml;
    }
  }
  remote::TreeEvent garbage;
  garbage.encoded.bytes = {std::byte{0xff}, std::byte{0x01}, std::byte{0x02}};
  b.deliver(12345, garbage);                  // unknown subtree, malformed bytes: nothing happens
  b.deliver(12345, encode_tree_event(b::Event("Hello")));
  b.halt(12345);
  EXPECT_EQ(b.status(12345), "unknown");
  EXPECT_EQ(host_->running(), 0u);
  // The host still works.
  EXPECT_EQ(b.status(b.start("X", R"(<behavior type="Wait" duration="1h"/>)")), "running");
  EXPECT_EQ(host_->running(), 1u);
}

TEST(RemoteTreeEvents, AnEventCrossesServersWithItsPropertiesAndMalformedBytesAreRefused) {
  b::Event e("WaypointReached");
  e.set("waypoint", std::string("door")).set("index", std::int32_t{3}).set("x", 1.5);
  const auto back = decode_tree_event(encode_tree_event(e));
  EXPECT_EQ(back.type(), "WaypointReached");
  EXPECT_EQ(back.get<std::string>("waypoint"), "door");
  EXPECT_EQ(back.get<std::int32_t>("index"), 3);
  EXPECT_DOUBLE_EQ(back.get<double>("x"), 1.5);
  auto broken = encode_tree_event(e);
  broken.encoded.bytes.resize(broken.encoded.bytes.size() / 2);
  EXPECT_THROW(decode_tree_event(broken), p::Error);
  broken = encode_tree_event(e);
  broken.encoded.bytes.push_back(std::byte{1});
  EXPECT_THROW(decode_tree_event(broken), p::Error);
}

}  // namespace
}  // namespace icars::control
