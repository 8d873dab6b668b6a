// The mediating server as a library: assembled from ServerOptions, it takes device
// registrations over real PLANET connections on loopback, runs a policy on the clock it is given,
// refuses bad endpoints, missing clocks and broken policies with clear errors, and puts a new
// access policy in force.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <mutex>

#include "child_process.h"
#include "icars/behavior/registry.h"
#include "icars/clock/sim_clock.h"
#include "icars/device/device_manager.h"
#include "icars/server/mediating_server.h"
#include "test_interfaces.h"

namespace icars::server {
namespace {

using namespace std::chrono_literals;
namespace p = icars::planet;

// A device manager with one device, as a separate endpoint with its own token. Its capability
// is the test Echo interface, which the server knows no adaptor for: a GenericAdaptor.
struct Manager {
  p::Communicator communicator;
  device::DeviceManager manager{communicator};

  Manager(std::uint16_t port, const std::string& token, const std::string& id = "tv")
      : communicator(options(token)) {
    auto tv = std::make_shared<device::Device>(id, "TV", "living_room");
    tv->add("echo", planet_test::make_echo_servant(communicator));
    manager.add(tv);
    manager.connect("127.0.0.1", port);
  }
  static p::CommunicatorOptions options(const std::string& token) {
    p::CommunicatorOptions o;
    o.token = token;
    return o;
  }
};

// A policy directory of its own, removed at the end.
class PolicyDir {
 public:
  PolicyDir() : path_(std::filesystem::temp_directory_path() / fmt::format("icars-server-test-{}", ::getpid())) {
    std::filesystem::create_directories(path_);
  }
  ~PolicyDir() { std::filesystem::remove_all(path_); }
  void write(const std::string& name, const std::string& xml) const { std::ofstream(path_ / name) << xml; }
  std::string path() const { return path_.string(); }

 private:
  std::filesystem::path path_;
};

constexpr const char* kEvening = R"(<policy name="evening">
  <task name="Wait" events="Dark">
    <sequential name="dusk">
      <behavior type="Wait" duration="30min"/>
      <behavior type="Emit" event="Dark"/>
    </sequential>
  </task>
  <task name="Rest"><behavior type="Wait" duration="8h"/></task>
  <statechart>
    <state name="Day" task="Wait"><transition event="Dark" target="Night"/></state>
    <state name="Night" task="Rest"/>
  </statechart>
</policy>)";

ServerOptions options_with(const PolicyDir& dir) {
  ServerOptions o;
  o.policy_dir = dir.path();
  behavior::register_generic_behaviors(o.behaviors);  // Wait, Emit
  return o;
}

TEST(MediatingServer, TakesDevicesAndRunsAPolicyOnTheClockItIsGiven) {
  PolicyDir dir;
  dir.write("evening.xml", kEvening);
  MediatingServer server(options_with(dir));
  behavior::TraceLog log;
  server.trace().add_sink(log.sink());
  const auto port = server.listen();
  EXPECT_NE(port, 0);
  EXPECT_EQ(server.endpoint().to_string(), fmt::format("127.0.0.1:{}", port));

  Manager living_room(port, "");
  ASSERT_TRUE(living_room.manager.wait_registered(1, 20s)) << living_room.manager.last_error();
  ASSERT_EQ(server.container().all().size(), 1u);
  EXPECT_EQ(server.container().all().front()->type(), "test::Echo");

  SimClock clock(at_time(0, 18, 0));
  server.use_clock(clock);
  EXPECT_EQ(server.run_policy("evening").policy.name, "evening");
  ASSERT_NE(server.coordinator(), nullptr);
  ASSERT_TRUE(server.runtime()->drain(20s));
  EXPECT_EQ(server.coordinator()->current(), "Day");
  clock.advance_by(29min);
  ASSERT_TRUE(server.runtime()->drain(20s));
  EXPECT_EQ(server.coordinator()->current(), "Day");
  clock.advance_by(1min);
  ASSERT_TRUE(log.wait_for([](const behavior::TraceRecord& r) { return r.kind == "transition"; }, 20s));
  ASSERT_TRUE(server.runtime()->drain(20s));
  EXPECT_EQ(server.coordinator()->current(), "Night");
  EXPECT_EQ(log.of_kind("transition").front().text, "Day -> Night on Dark");

  server.stop();
  EXPECT_EQ(server.coordinator(), nullptr);
  EXPECT_EQ(server.runtime(), nullptr);
  // The server still serves its devices after its behaviors stopped.
  EXPECT_TRUE(server.container().all().front()->available());
}

// Two servers: B hosts behaviors, A's policy places the dusk on B (host="B"). The Wait runs on
// B's runtime and clock, B's Emit reaches A's task as its own, and A's statechart moves on.
TEST(MediatingServer, APolicyPlacesASubtreeOnABehaviorHost) {
  SimClock clock(at_time(0, 18, 0));  // one clock for both, as servers following one house; outlives them
  PolicyDir dir;
  std::string evening = kEvening;
  evening.replace(evening.find(R"(<sequential name="dusk">)"), 24, R"(<sequential name="dusk" host="B">)");
  dir.write("evening.xml", evening);
  auto b_options = options_with(dir);
  b_options.host_behaviors = true;
  MediatingServer b(std::move(b_options));
  behavior::TraceLog b_log;
  b.trace().add_sink(b_log.sink());
  const auto b_port = b.listen();
  auto a_options = options_with(dir);
  a_options.behavior_hosts = {{"B", "127.0.0.1", b_port}};
  MediatingServer a(std::move(a_options));
  behavior::TraceLog a_log;
  a.trace().add_sink(a_log.sink());
  a.listen();

  b.use_clock(clock);
  a.use_clock(clock);
  ASSERT_TRUE(a.wait_behavior_hosts(20s));
  a.run_policy("evening");
  ASSERT_TRUE(b_log.wait_for([](const behavior::TraceRecord& r) { return r.text == "Wait/dusk/Wait started"; }, 20s))
      << "B never ran the dusk";
  ASSERT_TRUE(b.runtime()->drain(20s));  // its Wait has set its timer
  clock.advance_by(30min);
  ASSERT_TRUE(a_log.wait_for([](const behavior::TraceRecord& r) { return r.kind == "transition"; }, 20s));
  EXPECT_EQ(a_log.of_kind("transition").front().text, "Day -> Night on Dark");
  EXPECT_TRUE(b_log.wait_for([](const behavior::TraceRecord& r) { return r.text == "Wait/dusk/Emit succeeded"; }, 20s));
  a.stop();
  b.stop();
}

TEST(MediatingServer, BadEndpointsAreRefusedBeforeAnythingStarts) {
  PolicyDir dir;
  for (const auto* bad : {"localhost", "127.0.0.1:http", "127.0.0.1:70000", ":4711"}) {
    auto o = options_with(dir);
    o.listen = bad;
    try {
      MediatingServer server(std::move(o));
      ADD_FAILURE() << bad << " was accepted";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(bad), std::string::npos) << e.what();
    }
  }
  // A port already taken: listen() says so, and the server can be destroyed cleanly.
  MediatingServer first(options_with(dir));
  const auto port = first.listen();
  auto o = options_with(dir);
  o.listen = fmt::format("127.0.0.1:{}", port);
  MediatingServer second(std::move(o));
  EXPECT_THROW(second.listen(), std::exception);
}

TEST(MediatingServer, APolicyNeedsAClockAndBrokenPoliciesLeaveTheRunningOneAlone) {
  PolicyDir dir;
  dir.write("evening.xml", kEvening);
  dir.write("broken.xml", "<policy name=\"broken\"><task name=\"T\">");
  SimClock clock;  // outlives the server, whose behaviors' timers are on it
  MediatingServer server(options_with(dir));
  try {
    server.run_policy("evening");
    ADD_FAILURE() << "a policy ran without a clock";
  } catch (const std::logic_error& e) {
    EXPECT_STREQ(e.what(), "the mediating server has no clock: call use_clock() first");
  }
  server.use_clock(clock);
  server.run_policy("evening");
  EXPECT_THROW(server.run_policy("broken"), control::PolicyError);
  EXPECT_THROW(server.run_policy("missing"), control::PolicyError);
  ASSERT_NE(server.coordinator(), nullptr);
  EXPECT_EQ(server.coordinator()->current(), "Day");
  SimClock other;
  EXPECT_THROW(server.use_clock(other), std::logic_error);
}

TEST(MediatingServer, AReloadedAccessPolicyRevokesRemovedPrincipalsAndTheirDevices) {
  PolicyDir dir;
  const std::vector<std::string> dm_paths{std::string(device::kRegistryPath), "/sf/listeners/*"};
  auto access = std::make_shared<p::AccessPolicy>();
  access->add({"living-room", p::sha256_hex("living-room-token"), "", dm_paths, {"tv"}, 4});
  access->add({"kitchen", p::sha256_hex("kitchen-token"), "", dm_paths, {"kitchen_tv"}, 4});
  auto o = options_with(dir);
  o.planet.access = access;
  MediatingServer server(std::move(o));
  const auto port = server.listen();
  Manager living_room(port, "living-room-token");
  Manager kitchen(port, "kitchen-token", "kitchen_tv");
  ASSERT_TRUE(living_room.manager.wait_registered(1, 20s)) << living_room.manager.last_error();
  ASSERT_TRUE(kitchen.manager.wait_registered(1, 20s)) << kitchen.manager.last_error();
  ASSERT_EQ(server.container().all().size(), 2u);

  auto next = std::make_shared<p::AccessPolicy>();
  next->add({"living-room", p::sha256_hex("living-room-token"), "", dm_paths, {"tv"}, 4});
  const auto reload = server.reload_access(next);
  EXPECT_EQ(reload.principals, 1u);
  EXPECT_EQ(reload.changed, std::vector<std::string>{"kitchen"});
  EXPECT_EQ(reload.forgotten_devices, 1u);
  EXPECT_EQ(server.access(), next);
  ASSERT_EQ(server.container().all().size(), 1u);
  EXPECT_EQ(server.container().all().front()->attributes().device, "tv");

  MediatingServer open_server(options_with(dir));
  EXPECT_THROW(open_server.reload_access(next), std::logic_error);
  EXPECT_THROW(server.reload_access(nullptr), std::invalid_argument);
}

}  // namespace
}  // namespace icars::server
