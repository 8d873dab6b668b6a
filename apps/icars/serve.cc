// `icars serve`: a MediatingServer that shares its devices, mirrors its peers' devices, hosts
// the subtrees their policies place on it and places its own policy's subtrees on them
// (docs/distribution.md). Its clock follows the simulated house's (the Simulation service, from
// a device manager of its own or a peer's), or the wall clock.
#include "serve.h"
#include "robot_market_host.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <csignal>
#include <cstdio>
#include <fstream>
#include <functional>
#include <memory>
#include <optional>
#include <set>

#include "icars/clock/wall_clock.h"
#include "icars/control/policy_check.h"
#include "icars/home/clock_follower.h"
#include "icars/home/sim/house_vocabulary.h"
#include "icars/planet/endpoint.h"
#include "icars/report/recorders.h"
#include "icars/report/run_summary.h"
#include "icars/server/mediating_server.h"
#include "icars/server/plugin.h"
#include "icars/sim/house.h"
#include "announcement.h"
#include "registries.h"
#include "run_outputs.h"
#include "security_options.h"

namespace icars::app {

namespace b = icars::behavior;
namespace c = icars::control;
namespace p = icars::planet;
using namespace std::chrono_literals;

namespace {

bool valid_name(const std::string& name) {
  return !name.empty() && name.size() <= 64 &&
         name.find_first_of(" \t\r\n/=\"'<>&") == std::string::npos;
}

std::vector<PeerAddress> read_peers(const ServeOptions& options) {
  std::vector<std::string> texts = options.peers;
  if (!options.peers_file.empty()) {
    std::ifstream in(options.peers_file);
    if (!in) throw std::invalid_argument(fmt::format("--peers {}: cannot be read", options.peers_file));
    std::string line;
    int number = 0;
    while (std::getline(in, line)) {
      ++number;
      if (const auto hash = line.find('#'); hash != std::string::npos) line.erase(hash);
      const auto first = line.find_first_not_of(" \t\r");
      if (first == std::string::npos) continue;
      line = line.substr(first, line.find_last_not_of(" \t\r") - first + 1);
      try {
        (void)parse_peer(line);
      } catch (const std::invalid_argument& e) {
        throw std::invalid_argument(fmt::format("{}:{}: {}", options.peers_file, number, e.what()));
      }
      texts.push_back(line);
    }
  }
  std::vector<PeerAddress> peers;
  std::set<std::string> names{options.name};
  for (const auto& text : texts) {
    auto peer = parse_peer(text);
    if (!names.insert(peer.name).second) {
      throw std::invalid_argument(peer.name == options.name
                                      ? fmt::format("peer {} has this server's own name", text)
                                      : fmt::format("two peers are named {}", peer.name));
    }
    peers.push_back(std::move(peer));
  }
  return peers;
}

// The hosts a policy places subtrees on, with the line of the first node naming each.
std::map<std::string, int> placed_hosts(const c::Policy& policy) {
  std::map<std::string, int> hosts;
  std::function<void(const c::NodeSpec&)> walk = [&](const c::NodeSpec& node) {
    if (!node.host.empty()) hosts.emplace(node.host, node.line);
    for (const auto& child : node.children) walk(child);
  };
  for (const auto& task : policy.tasks) walk(task.root);
  return hosts;
}

}  // namespace

PeerAddress parse_peer(const std::string& text) {
  const auto eq = text.find('=');
  if (eq == std::string::npos) throw std::invalid_argument(fmt::format("peer '{}' is not NAME=HOST:PORT", text));
  PeerAddress peer;
  peer.name = text.substr(0, eq);
  if (!valid_name(peer.name)) {
    throw std::invalid_argument(fmt::format("peer '{}': '{}' is not a server name (1 to 64 characters, no spaces, "
                                            "'/', '=', quotes or markup)",
                                            text, peer.name));
  }
  const auto endpoint = p::parse_endpoint(text.substr(eq + 1), /*allow_any_port=*/false);
  peer.host = endpoint.host;
  peer.port = endpoint.port;
  return peer;
}

int serve(const ServeOptions& options) {
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  spdlog::set_level(spdlog::level::warn);
  std::setvbuf(stdout, nullptr, _IOLBF, 0);
  auto fail = [&options](int code, const std::string& what) {
    std::fprintf(stderr, "icars serve %s: %s\n", options.name.c_str(), what.c_str());
    return code;
  };

  // --- Inputs ----------------------------------------------------------------------------------
  if (!valid_name(options.name)) return fail(2, fmt::format("--name '{}' is not a server name", options.name));
  std::vector<PeerAddress> peers;
  std::optional<coros::AgentConfiguration> fleet;
  try {
    peers = read_peers(options);
    if (options.fleet.enabled()) fleet = fleet_agent(options.fleet, options.name);
  } catch (const std::exception& e) {
    return fail(2, e.what());
  }
  if (!options.until.empty() && (options.policy.empty() || options.world.empty())) {
    return fail(2, "--until needs --policy and --world (the house's start time)");
  }
  std::optional<Registries> registries;
  try {
    registries.emplace(options.plugins);
  } catch (const server::PluginError& e) {
    return fail(2, e.what());
  }
  std::optional<sim::House> house;
  if (!options.world.empty()) {
    try {
      house = sim::load_house(options.world);
    } catch (const std::exception& e) {
      return fail(2, e.what());
    }
  }
  server::ServerOptions server_options;
  server_options.listen = options.listen;
  server_options.policy_dir = options.policy_dir;
  server_options.behaviors = registries->behaviors;
  server_options.adaptors = registries->adaptors;
  server_options.composers = registries->composers;
  server_options.planet.logger = spdlog::default_logger();
  server_options.planet.tls = options.tls;
  server_options.host_behaviors = true;
  server_options.share_devices = true;
  for (const auto& peer : peers) {
    server_options.behavior_hosts.push_back({peer.name, peer.host, peer.port});
    server_options.device_peers.push_back({peer.name, peer.host, peer.port});
  }
  const c::PolicyRepository repository(options.policy_dir);
  std::string policy_name;
  if (!options.policy.empty()) {
    const auto path = repository.path_of(options.policy);
    try {
      const auto parsed = c::parse_policy_file(path, server_options.behaviors);
      for (const auto& w : parsed.warnings) std::fprintf(stderr, "%s\n", w.to_string().c_str());
      policy_name = parsed.policy.name;
      auto problems = c::check_policy(parsed.policy, server_options.behaviors,
                                      house ? home::house_vocabulary(*house) : b::Vocabulary{});
      // Every host a node names must be a peer: a typo would otherwise fail the task at run time.
      std::set<std::string> known;
      for (const auto& peer : peers) known.insert(peer.name);
      for (const auto& [host, line] : placed_hosts(parsed.policy)) {
        if (known.contains(host)) continue;
        problems.push_back({path, line, false,
                            fmt::format("host=\"{}\" names no peer of this server (its peers: {})", host,
                                        known.empty() ? std::string("none") : fmt::format("{}", fmt::join(known, ", "))),
                            0});
      }
      for (const auto& d : problems) std::fprintf(stderr, "%s\n", d.to_string().c_str());
      if (!problems.empty()) return 2;
    } catch (const c::PolicyError& e) {
      for (const auto& d : e.diagnostics()) std::fprintf(stderr, "%s\n", d.to_string().c_str());
      return 2;
    }
  }
  std::optional<Time> stop_at;
  if (!options.until.empty()) {
    const auto until = parse_time_of_day(options.until);
    if (!until) return fail(2, fmt::format("--until {} is not a time of day (HH:MM)", options.until));
    stop_at = stop_time(house->start_time, *until, options.days);
  }
  try {
    if (!options.token_file.empty()) server_options.planet.token = read_token_file(options.token_file);
    if (!options.access_file.empty()) {
      server_options.planet.access = std::make_shared<p::AccessPolicy>(p::AccessPolicy::load(options.access_file));
    }
  } catch (const std::exception& e) {
    return fail(2, e.what());
  }

  // --- The server --------------------------------------------------------------------------------
  report::RunSummary summary(false);
  report::TraceClock stamp;
  std::optional<server::MediatingServer> server;
  try {
    server.emplace(std::move(server_options));
  } catch (const std::invalid_argument& e) {
    return fail(2, fmt::format("--listen {}", e.what()));
  } catch (const std::exception& e) {
    return fail(2, e.what());
  }
  auto& trace = server->trace();
  if (!policy_name.empty()) trace.add_sink(summary.sink());
  // Every record names its server and the machine's time, so that the traces of all servers
  // merge into one timeline in the order things happened (icars merge-traces): each server's
  // house time lags the house by up to a poll of its clock.
  try {
    add_trace_outputs(trace, options.quiet, options.trace_file, [name = options.name](b::TraceRecord& r) {
      const auto wall = std::chrono::duration_cast<std::chrono::microseconds>(
          std::chrono::system_clock::now().time_since_epoch());
      r.with("server", name).with("wall_us", static_cast<std::int64_t>(wall.count()));
    });
  } catch (const std::exception& e) {
    return fail(2, e.what());
  }
  server->services().registry().set_call_observer(
      std::make_shared<report::CommandRecorder>(trace, stamp, report::CommandRecorder::house_commands()));
  report::DeviceEventRecorder device_events(server->container(), trace, stamp);
  std::uint16_t bound = 0;
  try {
    bound = server->listen();
  } catch (const std::exception& e) {
    return fail(2, fmt::format("cannot listen on {}: {}", options.listen, e.what()));
  }
  const auto host = server->endpoint().host;
  std::printf("%s\n", server_announcement(host, bound, policy_name.empty() ? "(none)" : repository.path_of(options.policy),
                                          house ? house->name : std::string("(none)"))
                          .c_str());
  std::printf("[icars] server %s; peers: %s\n", options.name.c_str(),
              peers.empty() ? "none" : fmt::format("{}", fmt::join([&] {
                                         std::vector<std::string> v;
                                         for (const auto& peer : peers) v.push_back(fmt::format("{}={}:{}", peer.name, peer.host, peer.port));
                                         return v;
                                       }(), ", ")).c_str());

  // --- The clock: the house's, read from its Simulation service (here or a peer's), or the wall's.
  const auto wait_for = [&](const std::function<bool()>& ready) {
    while (!ready()) {
      const timespec wait{0, 50'000'000};
      if (sigtimedwait(&signals, nullptr, &wait) > 0) return false;
    }
    return true;
  };
  std::unique_ptr<Clock> clock;
  std::unique_ptr<home::ClockFollower> follower;
  if (options.wall_clock) {
    clock = std::make_unique<WallClock>();
  } else {
    auto followed = std::make_unique<SimClock>(house ? house->start_time : Time{0});
    follower = std::make_unique<home::ClockFollower>(*followed, server->container());
    clock = std::move(followed);
    std::printf("[icars] %s waiting for the house's clock (a device manager here or at a peer)\n", options.name.c_str());
    if (!wait_for([&] { return follower->following(); })) return 0;
  }
  stamp.set(clock.get());
  struct ClockRelease {
    server::MediatingServer& server;
    report::TraceClock& stamp;
    ~ClockRelease() {
      server.stop();
      stamp.set(nullptr);
    }
  } release_clock{*server, stamp};
  report::ServiceRecorder heard(server->container(), trace, true);
  std::unique_ptr<RobotMarketHost> robot_market;
  if (fleet) {
    home::RobotMarketOptions market_options;
    try {
      market_options.agent = *fleet;
      robot_market = std::make_unique<RobotMarketHost>(*server, std::move(market_options));
    } catch (const std::exception& e) {
      return fail(2, fmt::format("the robot market: {}", e.what()));
    }
  }
  server->use_clock(*clock);  // hosts the peers' subtrees from now on
  std::printf("[icars] %s serving: %zu devices here, %zu services\n", options.name.c_str(),
              server->services().registry().registered_devices(), server->container().all().size());

  // --- The coordinator's policy ------------------------------------------------------------------
  auto started_at = clock->now();
  auto wall_start = std::chrono::steady_clock::now();
  if (!policy_name.empty()) {
    // Its first nodes find their hosts and the peers' services (a peer not up yet is waited for
    // a while; a node placed on it meanwhile fails with "disconnected", as when it dies later).
    if (!server->wait_behavior_hosts(30s)) {
      b::TraceRecord r;
      r.time = clock->now();
      r.kind = "note";
      r.source = options.name;
      r.text = "not every peer is connected yet; the policy starts without them";
      trace.record(std::move(r));
    }
    server->wait_device_peers(30s);
    const auto has_devices = [&] {
      for (const auto& id : options.wait_for) {
        if (server->container().find(service::ServiceQuery{}.on_device(id).available()).empty()) return false;
      }
      return true;
    };
    const auto give_up = std::chrono::steady_clock::now() + 60s;
    if (!wait_for([&] { return has_devices() || std::chrono::steady_clock::now() > give_up; })) return 0;
    if (!has_devices()) {
      b::TraceRecord r;
      r.time = clock->now();
      r.kind = "note";
      r.source = options.name;
      r.text = fmt::format("not every device of --wait-for is here after 60 s ({}); the policy starts without them",
                           fmt::join(options.wait_for, ", "));
      trace.record(std::move(r));
    }
    started_at = clock->now();
    wall_start = std::chrono::steady_clock::now();
    try {
      server->run_policy(options.policy);
    } catch (const c::PolicyError& e) {
      std::fprintf(stderr, "%s\n", e.what());
      return 2;
    }
  }
  bool interrupted = false;
  while (!stop_at || clock->now() < *stop_at) {
    const timespec wait{0, 20'000'000};
    if (sigtimedwait(&signals, nullptr, &wait) > 0) {
      interrupted = true;
      break;
    }
  }
  const auto ended_at = clock->now();
  server->stop_policy(5s);
  device_events.stop();
  spdlog::set_level(spdlog::level::err);
  if (!policy_name.empty()) {
    const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
    summary.print(stdout, policy_name, started_at, ended_at, wall,
                  options.wall_clock ? std::string("on the wall clock") : std::string("following the house's clock"));
  }
  if (interrupted) std::printf("(interrupted)\n");
  if (!options.trace_file.empty()) std::printf("trace: %s\n", options.trace_file.c_str());
  return 0;
}

}  // namespace icars::app
