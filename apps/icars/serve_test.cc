// `icars serve`: one logical mediating server of three processes, as docs/distribution.md
// deploys it. Server A takes the house's devices from one device manager, the coordinator C the
// bedroom light from another; C's policy places the living room's subtree on server B, which
// switches the living room's light through A. SIGKILL of B mid-task is a failure transition on
// C with the reason, the run goes on (C takes the living room over, through A), and the three
// traces merge into one timeline. And `icars serve`'s bad input: a clear error, exit code 2.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <filesystem>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "house_processes.h"
#include "program_run.h"
#include "tls_files.h"

namespace {

using namespace std::chrono_literals;
using icars_test::json;
using icars_test::str;

const std::string kIcars = ICARS_BINARY;
const std::string kDeviceManager = ICARS_DEVICE_MANAGER_BINARY;
const std::string kSource = ICARS_SOURCE_DIR;
const std::string kHouse = kSource + "/houses/paper_house.xml";
const std::string kPolicy = kSource + "/examples/distributed/split_evening.xml";
constexpr double kSpeed = 600;

std::vector<json> trace_of(const std::string& path) {
  try {
    return icars_test::read_json_lines(path);
  } catch (const std::exception&) {
    return {};  // not written yet, or a line being written
  }
}

bool has(const std::vector<json>& records, const std::function<bool(const json&)>& match) {
  return std::any_of(records.begin(), records.end(), match);
}

// Starts `argv` and waits for the port it announces (the server's first line).
std::string start_server(icars_test::Program& program) {
  std::vector<std::string> output;
  return icars_test::start_mediator(program, output);
}

TEST(IcarsServe, ThreeServersOneHouseASubtreeOnAnotherServerAndItsDeathAsAFailureTransition) {
  const auto dir = icars_test::run_directory("", "icars_serve");
  const auto env = icars_test::child_environment();
  const auto trace = [&](const std::string& name) { return (dir / (name + ".jsonl")).string(); };
  const auto epoch = std::to_string(icars_test::SharedClock::wall_ms());
  const auto speed = std::to_string(kSpeed);

  icars_test::Program a(dir / "a.stderr", env, {kIcars, "serve", "--name", "A", "--trace", trace("a"), "--quiet"});
  const auto port_a = start_server(a);
  ASSERT_FALSE(port_a.empty()) << a.stderr_text();
  // The house's devices but the bedroom light, and its clock, register on A.
  icars_test::Program devices_a(dir / "devices_a.stderr", env,
                                {kDeviceManager, "--house", kHouse, "--server", "127.0.0.1:" + port_a, "--speedup",
                                 speed, "--epoch", epoch, "--no-engines", "--devices",
                                 "tv,living_light,sofa_sensor,bed_sensor,robot1_wheels,robot1_mic,robot1_speaker,"
                                 "robot1_camera"});
  icars_test::Program b(dir / "b.stderr", env,
                        {kIcars, "serve", "--name", "B", "--peer", "A=127.0.0.1:" + port_a, "--trace", trace("b"),
                         "--quiet"});
  const auto port_b = start_server(b);
  ASSERT_FALSE(port_b.empty()) << b.stderr_text();
  icars_test::Program c(dir / "c.stderr", env,
                        {kIcars, "serve", "--name", "C", "--peer", "A=127.0.0.1:" + port_a, "--peer",
                         "B=127.0.0.1:" + port_b, "--policy", kPolicy, "--world", kHouse, "--wait-for",
                         "living_light,bedroom_light", "--until", "23:00", "--trace", trace("c"), "--quiet"});
  const auto port_c = start_server(c);
  ASSERT_FALSE(port_c.empty()) << c.stderr_text();
  // The bedroom light registers on the coordinator.
  icars_test::Program devices_c(dir / "devices_c.stderr", env,
                                {kDeviceManager, "--house", kHouse, "--server", "127.0.0.1:" + port_c, "--speedup",
                                 speed, "--epoch", epoch, "--no-engines", "--no-simulator", "--devices",
                                 "bedroom_light"});

  // B runs the living room's subtree and switches the light of A's device manager through A.
  const auto b_switched = [](const json& j) {
    return str(j, "kind") == "behavior" && str(j, "source") == "Evening/Rooms/LivingRoom/SetLights" &&
           str(j, "event") == "success";
  };
  const auto a_acknowledged = [](const json& j) {
    return str(j, "kind") == "command" && str(j, "device") == "living_light" && str(j, "event") == "acknowledged";
  };
  const auto deadline = std::chrono::steady_clock::now() + 180s;
  while (!(has(trace_of(trace("b")), b_switched) && has(trace_of(trace("a")), a_acknowledged))) {
    ASSERT_LT(std::chrono::steady_clock::now(), deadline)
        << "B's subtree did not switch A's light\nC: " << icars_test::tail(c.stderr_text())
        << "\nB: " << icars_test::tail(b.stderr_text());
    ASSERT_FALSE(c.exited()) << icars_test::tail(c.stderr_text());
    std::this_thread::sleep_for(100ms);
  }
  const auto b_running = [](const json& j) {
    return str(j, "kind") == "behavior" && str(j, "source") == "Evening/Rooms/LivingRoom/Wait" &&
           str(j, "event") == "start";
  };
  ASSERT_TRUE(has(trace_of(trace("b")), b_running));
  ASSERT_FALSE(has(trace_of(trace("c")), [](const json& j) { return str(j, "kind") == "transition"; }))
      << "the evening ended before B was killed";
  b.signal(SIGKILL);

  // C ends by itself at 23:00.
  const auto end = std::chrono::steady_clock::now() + 300s;
  while (!c.exited()) {
    ASSERT_LT(std::chrono::steady_clock::now(), end) << "C did not stop at 23:00";
    std::this_thread::sleep_for(100ms);
  }
  const int c_status = c.wait();
  EXPECT_TRUE(icars_test::exit_problems("C", c_status, c.stderr_text()).empty()) << icars_test::tail(c.stderr_text());
  a.signal(SIGTERM);
  devices_a.signal(SIGTERM);
  devices_c.signal(SIGTERM);
  EXPECT_TRUE(icars_test::exit_problems("A", a.wait(), a.stderr_text()).empty()) << icars_test::tail(a.stderr_text());
  for (auto* dm : {&devices_a, &devices_c}) {
    EXPECT_TRUE(icars_test::exit_problems("device manager", dm->wait(), dm->stderr_text()).empty())
        << icars_test::tail(dm->stderr_text());
  }

  // On the coordinator: the failure transition with B's death as the reason, and the run went on.
  const auto tc = trace_of(trace("c"));
  const auto failed = std::find_if(tc.begin(), tc.end(), [](const json& j) {
    return str(j, "kind") == "transition" && str(j, "from") == "Evening" && str(j, "to") == "Alone" &&
           str(j, "event") == "failed";
  });
  ASSERT_NE(failed, tc.end()) << "no failure transition on C";
  EXPECT_NE(str(*failed, "reason").find("LivingRoom failed: disconnected: host B"), std::string::npos)
      << str(*failed, "reason");
  const auto took_over = std::find_if(failed, tc.end(), [](const json& j) {
    return str(j, "kind") == "behavior" && str(j, "source") == "Alone/Everything/SetLights" &&
           str(j, "event") == "success";
  });
  EXPECT_NE(took_over, tc.end()) << "C did not take the living room over after B died";
  EXPECT_FALSE(has(tc, [](const json& j) { return str(j, "kind") == "call" && j.contains("error"); }))
      << "a call of C failed";
  // The living light obeyed B and then C: two commands acknowledged on A, one of each.
  const auto ta = trace_of(trace("a"));
  EXPECT_GE(std::count_if(ta.begin(), ta.end(), [](const json& j) {
              return str(j, "kind") == "command" && str(j, "device") == "living_light" &&
                     str(j, "method") == "set_power" && str(j, "event") == "acknowledged";
            }),
            2);

  // One timeline: every server's records, in the order they happened.
  const auto merged = (dir / "all.jsonl").string();
  const auto merge = icars_test::run_program(kIcars, "merge-traces " + trace("a") + " " + trace("b") + " " +
                                                         trace("c") + " --output " + merged, 60);
  ASSERT_EQ(merge.exit_code, 0) << merge.output;
  const auto all = icars_test::read_json_lines(merged);
  EXPECT_EQ(all.size(), ta.size() + trace_of(trace("b")).size() + tc.size());
  std::int64_t last = 0;
  std::size_t b_call = all.size(), a_command = all.size(), c_failed = all.size();
  for (std::size_t i = 0; i < all.size(); ++i) {
    const auto wall = all[i].value("wall_us", std::int64_t{0});
    EXPECT_GE(wall, last) << "record " << i << " out of order";
    last = wall;
    const auto server = str(all[i], "server");
    if (b_call == all.size() && server == "B" && str(all[i], "kind") == "call") b_call = i;
    if (a_command == all.size() && server == "A" && a_acknowledged(all[i])) a_command = i;
    if (c_failed == all.size() && server == "C" && str(all[i], "kind") == "transition") c_failed = i;
  }
  EXPECT_LT(b_call, a_command) << "B's call comes before A's command";
  EXPECT_LT(a_command, c_failed) << "A's command comes before C's failure transition";
  EXPECT_LT(c_failed, all.size());
  if (!::testing::Test::HasFailure()) std::filesystem::remove_all(dir);  // kept to look at when it failed
}

// A device manager given two servers: when its server is killed it moves to the other one,
// whose coordinator then switches the light it hosts directly; the policy goes on.
TEST(IcarsServe, ADeviceManagerMovesToTheNextServerWhenItsServerIsKilled) {
  const auto dir = icars_test::run_directory("", "icars_serve_failover");
  const auto env = icars_test::child_environment();
  const auto trace = [&](const std::string& name) { return (dir / (name + ".jsonl")).string(); };
  const auto policy = (dir / "blink.xml").string();
  {
    std::FILE* f = std::fopen(policy.c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fputs(R"xml(<?xml version="1.0" encoding="UTF-8"?>
<policy name="blink">
  <task name="Blink">
    <repeat name="AllEvening" times="100">
      <sequential name="Once">
        <retry name="On" times="30" delay="1min"><behavior type="SetLights" rooms="living_room" on="true"/></retry>
        <behavior type="Wait" duration="10min"/>
        <retry name="Off" times="30" delay="1min"><behavior type="SetLights" rooms="living_room" on="false"/></retry>
        <behavior type="Wait" duration="10min"/>
      </sequential>
    </repeat>
  </task>
  <statechart initial="Blinking"><state name="Blinking" task="Blink"/></statechart>
</policy>
)xml", f);
    std::fclose(f);
  }
  icars_test::Program a(dir / "a.stderr", env, {kIcars, "serve", "--name", "A", "--trace", trace("a"), "--quiet"});
  const auto port_a = start_server(a);
  ASSERT_FALSE(port_a.empty()) << a.stderr_text();
  icars_test::Program b(dir / "b.stderr", env,
                        {kIcars, "serve", "--name", "B", "--peer", "A=127.0.0.1:" + port_a, "--policy", policy,
                         "--world", kHouse, "--wait-for", "living_light", "--until", "21:00", "--trace", trace("b"),
                         "--quiet"});
  const auto port_b = start_server(b);
  ASSERT_FALSE(port_b.empty()) << b.stderr_text();
  icars_test::Program devices(dir / "devices.stderr", env,
                              {kDeviceManager, "--house", kHouse, "--server", "127.0.0.1:" + port_a, "--server",
                               "127.0.0.1:" + port_b, "--failover-after", "0.5", "--speedup",
                               std::to_string(kSpeed), "--no-engines", "--devices", "living_light,sofa_sensor"});
  // B switched the light through A (the SetLights behavior succeeded, so the light confirmed).
  const auto switched = [](const json& j) {
    return str(j, "kind") == "behavior" && str(j, "type") == "SetLights" && str(j, "event") == "success";
  };
  auto deadline = std::chrono::steady_clock::now() + 120s;
  while (!has(trace_of(trace("b")), switched)) {
    ASSERT_LT(std::chrono::steady_clock::now(), deadline) << "B never switched A's light\n" << b.stderr_text();
    ASSERT_FALSE(b.exited()) << b.stderr_text();
    std::this_thread::sleep_for(100ms);
  }
  a.signal(SIGKILL);
  const auto killed_at = trace_of(trace("b")).size();
  bool moved = false;
  deadline = std::chrono::steady_clock::now() + 120s;
  while (!moved) {
    ASSERT_LT(std::chrono::steady_clock::now(), deadline) << "the device manager did not move\n"
                                                          << devices.stderr_text();
    for (const auto& line : devices.lines()) moved |= line == "SERVER 127.0.0.1:" + port_b;
  }
  deadline = std::chrono::steady_clock::now() + 300s;
  while (!b.exited()) {
    ASSERT_LT(std::chrono::steady_clock::now(), deadline) << "B did not stop at 21:00";
    std::this_thread::sleep_for(100ms);
  }
  const int b_status = b.wait();
  EXPECT_TRUE(icars_test::exit_problems("B", b_status, b.stderr_text()).empty()) << icars_test::tail(b.stderr_text());
  devices.signal(SIGTERM);
  EXPECT_TRUE(icars_test::exit_problems("device manager", devices.wait(), devices.stderr_text()).empty())
      << icars_test::tail(devices.stderr_text());
  // After A died, B switched the light again, now registered on B itself; no failure transition.
  const auto tb = trace_of(trace("b"));
  ASSERT_GT(tb.size(), killed_at);
  // (Two: one call sent just before the kill may still have been answered.)
  EXPECT_GE(std::count_if(tb.begin() + static_cast<std::ptrdiff_t>(killed_at), tb.end(),
                          [](const json& j) {
                            return str(j, "kind") == "behavior" && str(j, "type") == "SetLights" &&
                                   str(j, "event") == "success";
                          }),
            2)
      << "the light was not switched after A died";
  EXPECT_FALSE(has(tb, [](const json& j) { return str(j, "kind") == "transition"; }));
  if (!::testing::Test::HasFailure()) std::filesystem::remove_all(dir);
}

// Peers as docs/distribution.md secures them: TLS on every link, a token per server and an
// access file on the sharing server. The peer with a principal that may call the directory,
// the relays and the behavior host mirrors the house (it follows the house's clock through A);
// a peer whose principal may not is told why.
TEST(IcarsServe, PeersOverTlsWithTokensAndAnAccessFile) {
  const auto dir = icars_test::run_directory("", "icars_serve_secure");
  const auto env = icars_test::child_environment();
  planet_test::make_certificates(dir);
  const auto ca = (dir / "ca.pem").string(), cert = (dir / "server.pem").string(), key = (dir / "server.key").string();
  const auto token = [&](const std::string& name, const std::vector<std::string>& extra) {
    std::string args = "token " + name;
    for (const auto& e : extra) args += " " + e;
    const auto r = icars_test::run_program(kIcars, args, 60);
    EXPECT_EQ(r.exit_code, 0) << r.output;
    const auto newline = r.output.find('\n');
    return std::make_pair(r.output.substr(0, newline), r.output.substr(newline + 1, r.output.find('\n', newline + 1) - newline - 1));
  };
  const auto house = token("house", {"--devices", "'*'"});
  const auto peer_b = token("B", {"--may-call", "/sf/directory", "'/sf/relay/*'", "/control/behavior_host"});
  const auto peer_c = token("C", {"--may-call", "/control/behavior_host"});
  const auto write = [&](const std::string& name, const std::string& text) {
    const auto path = (dir / name).string();
    std::FILE* f = std::fopen(path.c_str(), "w");
    EXPECT_NE(f, nullptr);
    std::fputs(text.c_str(), f);
    std::fclose(f);
    return path;
  };
  const auto access = write("access.json", "{\"principals\": [" + house.second + ", " + peer_b.second + ", " +
                                               peer_c.second + "]}");
  const std::vector<std::string> tls = {"--tls", "on", "--tls-ca", ca, "--tls-cert", cert, "--tls-key", key};
  std::vector<std::string> a_argv = {kIcars, "serve", "--name", "A", "--access", access, "--quiet"};
  a_argv.insert(a_argv.end(), tls.begin(), tls.end());
  icars_test::Program a(dir / "a.stderr", env, a_argv);
  const auto port_a = start_server(a);
  ASSERT_FALSE(port_a.empty()) << a.stderr_text();
  icars_test::Program devices(dir / "devices.stderr", env,
                              {kDeviceManager, "--house", kHouse, "--server", "127.0.0.1:" + port_a, "--speedup",
                               std::to_string(kSpeed), "--no-engines", "--devices", "living_light", "--tls", "on",
                               "--tls-ca", ca, "--token-file", write("house.token", house.first + "\n")});
  const auto serve_peer = [&](const std::string& name, const std::string& token_line) {
    std::vector<std::string> argv = {kIcars, "serve", "--name", name, "--peer", "A=127.0.0.1:" + port_a,
                                     "--token-file", write(name + ".token", token_line + "\n"), "--quiet"};
    argv.insert(argv.end(), tls.begin(), tls.end());
    return std::make_unique<icars_test::Program>(dir / (name + ".stderr"), env, argv);
  };
  const auto wait_line = [](icars_test::Program& program, const std::string& text) {
    const auto deadline = std::chrono::steady_clock::now() + 120s;
    while (std::chrono::steady_clock::now() < deadline && !program.exited()) {
      for (const auto& line : program.lines()) {
        if (line.find(text) != std::string::npos) return line;
      }
    }
    return std::string();
  };
  auto b = serve_peer("B", peer_b.first);
  const auto serving = wait_line(*b, "B serving:");
  EXPECT_FALSE(serving.empty()) << "B did not follow the house's clock through A\n" << b->stderr_text();
  EXPECT_NE(serving.find("services"), std::string::npos) << serving;
  auto c = serve_peer("C", peer_c.first);
  const auto refused = wait_line(*c, "cannot read the service directory of A");
  EXPECT_NE(refused.find("principal 'C' may not call '/sf/directory'"), std::string::npos)
      << refused << "\n" << c->stderr_text();
  for (auto* program : {b.get(), c.get(), &devices, &a}) program->signal(SIGTERM);
  for (auto* program : {b.get(), c.get(), &devices, &a}) {
    EXPECT_TRUE(icars_test::exit_problems("program", program->wait(), program->stderr_text()).empty())
        << icars_test::tail(program->stderr_text());
  }
  if (!::testing::Test::HasFailure()) std::filesystem::remove_all(dir);
}

TEST(IcarsServe, BadPeersHostsAndOptionsAreClearErrors) {
  const auto serve = [](const std::string& args) { return icars_test::run_program(kIcars, "serve " + args, 60); };
  auto r = serve("--peer B");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("peer 'B' is not NAME=HOST:PORT"), std::string::npos) << r.output;
  r = serve("--peer B=127.0.0.1:99999");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("99999"), std::string::npos) << r.output;
  r = serve("--peer B=127.0.0.1:7000 --peer B=127.0.0.1:7001");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("two peers are named B"), std::string::npos) << r.output;
  r = serve("--name A --peer A=127.0.0.1:7000");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("has this server's own name"), std::string::npos) << r.output;
  r = serve("--peer 'B/x=127.0.0.1:7000'");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("is not a server name"), std::string::npos) << r.output;
  // The policy places a subtree on a host that is no peer: its line, before anything starts.
  r = serve("--policy " + kPolicy + " --world " + kHouse);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("split_evening.xml:9: error: host=\"B\" names no peer of this server"), std::string::npos)
      << r.output;
  r = serve("--until 23:00");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("--until needs --policy and --world"), std::string::npos) << r.output;
  const auto peers = icars_test::temp_path("icars_serve", "peers.txt");
  {
    std::FILE* f = std::fopen(peers.c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fputs("# the other servers\nA=127.0.0.1:7000\nnot a peer\n", f);
    std::fclose(f);
  }
  r = serve("--peers " + peers);
  std::remove(peers.c_str());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("peers.txt:3: peer 'not a peer' is not NAME=HOST:PORT"), std::string::npos) << r.output;
}

TEST(IcarsServe, MergeTracesRefusesWhatIsNotATrace) {
  const auto bad = icars_test::temp_path("icars_serve", "bad.jsonl");
  {
    std::FILE* f = std::fopen(bad.c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fputs("{\"t\":1,\"kind\":\"note\"}\n{not json\n", f);
    std::fclose(f);
  }
  const auto r = icars_test::run_program(kIcars, "merge-traces " + bad, 60);
  std::remove(bad.c_str());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("bad.jsonl:2: not a trace record"), std::string::npos) << r.output;
}

}  // namespace
