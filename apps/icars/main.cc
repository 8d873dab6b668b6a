// icars: the mediating server of a smart home (ICARS paper 3, Figs. 14 and 16b).
//
//   icars run POLICY --world HOUSE [--speed N|max] [--until HH:MM] [--days N] [--trace FILE] [--plot FILE.svg]
//       runs a collaboration policy on a house: the Service Framework, the behaviors and the
//       Coordinator, with the house's device managers embedded in the same process (simulated
//       devices over loopback PLANET, the clock in lock-step with the mediator unless
//       --free-running) or, with --external, connecting from elsewhere (icars-device-manager).
//       Prints a timeline and a summary.
//   icars validate POLICY... [--world HOUSE]
//       checks policies without running them (with a house: against its rooms, waypoints,
//       furniture, devices, users and robots, as `icars run` does); exit code 1 if any has
//       errors, 2 for a house or plugin that cannot be used.
//   icars behaviors
//       lists the behavior types a policy can use, with their parameters.
//   --plugin PATH.so (run, validate, behaviors; repeatable)
//       loads a plugin that adds behavior, adaptor and composer types (icars/server/plugin.h);
//       a plugin that cannot be used stops the command with exit code 2 and the reason.
//   icars replay TRACE --world HOUSE [--policy POLICY] [--http HOST:PORT]
//       shows a recorded trace in the live dashboard, with a time slider (docs/dashboard.md).
//   --http HOST:PORT (run): the live dashboard of the run (docs/dashboard.md).
//   icars serve [--name NAME] [--listen HOST:PORT] [--peer NAME=HOST:PORT]... [--peers FILE]
//               [--policy POLICY [--world HOUSE] [--until HH:MM]] [--trace FILE]
//       one server of a logical mediating server of several processes (docs/distribution.md):
//       shares its devices with its peers, uses theirs, hosts the behavior subtrees their
//       policies place on it (host="NAME"); the one given --policy coordinates.
//   icars merge-traces TRACE... [--output FILE]
//       the traces of several servers (icars serve --trace) as one timeline.
//   icars token NAME [--may-call PATTERN...] [--devices PATTERN...] [--max-devices N]
//       makes a token for a device manager or agent: prints the token (for its --token-file) and
//       the entry to add to the server's --access file (docs/security.md).
#include <CLI/CLI.hpp>
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cstdio>
#include <optional>

#include "icars/control/collaboration.h"
#include "icars/control/policy_check.h"
#include "icars/home/sim/house_vocabulary.h"
#include "icars/home/sim/sim_devices.h"
#include "icars/server/plugin.h"
#include "mediator.h"
#include "merge_traces.h"
#include "registries.h"
#include "security_options.h"
#include "serve.h"

namespace b = icars::behavior;
namespace c = icars::control;
namespace home = icars::home;

namespace {

using icars::app::Registries;

int validate(const std::vector<std::string>& policies, const std::string& policy_dir, const std::string& world,
             const std::vector<std::string>& plugins) {
  std::optional<Registries> loaded;
  try {
    loaded.emplace(plugins);
  } catch (const icars::server::PluginError& e) {
    std::fprintf(stderr, "icars validate: %s\n", e.what());
    return 2;
  }
  const auto& registry = loaded->behaviors;
  // Without a house, the events are checked and no names are.
  icars::behavior::Vocabulary vocabulary;
  if (!world.empty()) {
    try {
      const auto house = icars::sim::load_house(world);
      loaded->sim_devices.check(house);
      vocabulary = home::house_vocabulary(house);
    } catch (const icars::sim::HouseError& e) {
      std::fprintf(stderr, "%s\n", e.what());
      return 2;
    }
  }
  const c::PolicyRepository repository(policy_dir);
  int failed = 0;
  for (const auto& name : policies) {
    const auto path = repository.path_of(name);
    try {
      const auto parsed = c::parse_policy_file(path, registry);
      if (auto problems = c::check_policy(parsed.policy, registry, vocabulary); !problems.empty()) {
        throw c::PolicyError(std::move(problems));
      }
      for (const auto& w : parsed.warnings) std::fprintf(stderr, "%s\n", w.to_string().c_str());
      std::size_t states = 0;
      std::function<void(const c::StateSpec&)> count = [&](const c::StateSpec& s) {
        for (const auto& child : s.children) {
          ++states;
          count(child);
        }
      };
      count(parsed.policy.root);
      std::printf("%s: ok: policy %s, %zu tasks, %zu states, %zu warning%s\n", path.c_str(),
                  parsed.policy.name.c_str(), parsed.policy.tasks.size(), states, parsed.warnings.size(),
                  parsed.warnings.size() == 1 ? "" : "s");
    } catch (const c::PolicyError& e) {
      for (const auto& d : e.diagnostics()) std::fprintf(stderr, "%s\n", d.to_string().c_str());
      std::fprintf(stderr, "%s: %zu error%s\n", path.c_str(), e.diagnostics().size(),
                   e.diagnostics().size() == 1 ? "" : "s");
      ++failed;
    }
  }
  return failed == 0 ? 0 : 1;
}

int list_behaviors(const std::vector<std::string>& plugins) {
  std::optional<Registries> loaded;
  try {
    loaded.emplace(plugins);
  } catch (const icars::server::PluginError& e) {
    std::fprintf(stderr, "icars behaviors: %s\n", e.what());
    return 2;
  }
  const auto& registry = loaded->behaviors;
  const auto from = [&](const std::string& type) -> std::string {
    const auto* plugin = loaded->plugin_of_behavior(type);
    return plugin != nullptr ? " (plugin " + plugin->path + ")" : "";
  };
  for (const auto& type : registry.types()) {
    const auto* entry = registry.find(type);
    std::printf("%s: %s%s\n", type.c_str(), entry->doc.c_str(), from(type).c_str());
    for (const auto& p : entry->params) {
      std::printf("    %-16s %-12s %s%s\n", p.name.c_str(), std::string(b::to_string(p.type)).c_str(),
                  p.doc.c_str(),
                  p.default_value ? (" [default: \"" + *p.default_value + "\"]").c_str() : " [required]");
    }
  }
  for (const auto& plugin : loaded->plugins) {
    std::printf("plugin %s: %zu behavior types, adaptors for %zu interfaces%s%s, %zu composers\n",
                plugin.path.c_str(), plugin.behaviors.size(), plugin.interfaces.size(),
                plugin.interfaces.empty() ? "" : ": ", fmt::format("{}", fmt::join(plugin.interfaces, ", ")).c_str(),
                plugin.composers);
    for (const auto& [kind, names] : plugin.extended) {
      std::printf("plugin %s: %s %s\n", plugin.path.c_str(), kind.c_str(), fmt::format("{}", fmt::join(names, ", ")).c_str());
    }
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"ICARS mediating server: runs collaboration policies on a smart home"};
  app.require_subcommand(1);

  icars::app::RunOptions run;
  auto* run_cmd = app.add_subcommand("run", "run a policy on a house");
  run_cmd->add_option("policy", run.policy, "policy file, or a name in --policies")->required();
  run_cmd->add_option("--world", run.world, "house file (docs/house.md)")->required();
  run_cmd
      ->add_option_function<std::string>(
          "--speed",
          [&run](const std::string& text) {
            if (text == "max") {
              run.speed = 0;
              return;
            }
            std::size_t used = 0;
            double value = 0;
            try {
              value = std::stod(text, &used);
            } catch (const std::exception&) {
              used = 0;
            }
            if (used != text.size() || !(value >= 1.0 && value <= 100000.0)) {
              throw CLI::ValidationError("--speed", text + " is neither a number in [1, 100000] nor 'max'");
            }
            run.speed = value;
          },
          "simulated seconds per wall-clock second, or 'max': as fast as the machine goes "
          "(lock-step only)")
      ->default_str("1500");
  run_cmd->add_flag("--free-running", run.free_running,
                    "run the embedded house's clock with the wall clock instead of in lock-step with the "
                    "mediator: reactions then lag by the time they take, times --speed");
  run_cmd->add_option("--until", run.until, "stop at this simulated time of day (HH:MM)")->capture_default_str();
  run_cmd->add_option("--days", run.days,
                      "run this many simulated days: stop at the N-th --until after the house's start "
                      "(the users' daily schedule repeats)")
      ->check(CLI::Range(1, 3650))
      ->capture_default_str();
  run_cmd->add_option("--trace", run.trace_file, "write a JSON-lines trace to this file");
  run_cmd->add_option("--plot", run.plot_file, "draw the house and the run to this SVG file");
  run_cmd->add_option("--listen", run.listen, "where device managers connect, host:port")->capture_default_str();
  run_cmd->add_flag("--external", run.external, "device managers run as separate processes");
  run_cmd->add_flag("--quiet", run.quiet, "print only the summary");
  run_cmd->add_option("--wait-for", run.wait_for,
                      "with --external: start the policy once these devices (ids) are registered (at most 60 s)")
      ->delimiter(',');
  run_cmd->add_flag("--market", run.market,
                    "run the robot market (robot=\"any\"; on by itself for a house with two robots or more)");
  add_fleet_options(*run_cmd, run.fleet, "the robot market");
  run_cmd->add_option("--policies", run.policy_dir, "the policy repository directory")->capture_default_str();
  run_cmd->add_option("--mqtt", run.mqtt,
                      "MQTT broker, mqtt://HOST[:PORT] or mqtts://HOST[:PORT]: the house's MQTT devices "
                      "(<device mqtt=...>) are simulated there and brought in through an MQTT bridge");
  run_cmd->add_option("--mqtt-ca-file", run.mqtt_ca_file, "CA the mqtts:// broker's certificate is checked against")
      ->check(CLI::ExistingFile);
  run_cmd->add_flag("--publish-to-home-assistant", run.home_assistant,
                    "publish the mediator to Home Assistant on the --mqtt broker: the policy's state and task, "
                    "a select of policies, a button per policy event, the robots and the devices");
  run_cmd->add_option("--ha-node-id", run.ha_node_id,
                      "the Home Assistant device the mediator is published as (default: icars_<house name>)");
  // The live dashboard (docs/dashboard.md): the same options for run and replay.
  const auto add_http_options = [](CLI::App& cmd, icars::app::DashboardSettings& settings) {
    cmd.add_option("--http", settings.listen,
                   "serve the live dashboard on HOST:PORT (loopback; another address needs --http-tls-cert)");
    cmd.add_option("--http-token-file", settings.token_file,
                   "the dashboard controls' token (its first line; default: a new one, in the printed URL)")
        ->check(CLI::ExistingFile);
    cmd.add_option("--http-tls-cert", settings.tls_cert, "the dashboard's TLS certificate (PEM)")->check(CLI::ExistingFile);
    cmd.add_option("--http-tls-key", settings.tls_key, "the dashboard's TLS key (PEM)")->check(CLI::ExistingFile);
  };
  add_http_options(*run_cmd, run.dashboard);
  icars::app::add_tls_options(*run_cmd, run.tls, icars::app::Side::server);
  run_cmd->add_option("--access", run.access_file,
                      "access file: who may connect and what each may call (docs/security.md)")
      ->check(CLI::ExistingFile);

  std::vector<std::string> to_validate;
  std::string policy_dir = "examples/smart_home";
  auto* validate_cmd = app.add_subcommand("validate", "check policies without running them");
  validate_cmd->add_option("policy", to_validate, "policy files or names")->required();
  validate_cmd->add_option("--policies", policy_dir, "the policy repository directory")->capture_default_str();
  std::string validate_world;
  validate_cmd->add_option("--world", validate_world,
                           "also check the policies against this house: the rooms, waypoints, furniture, "
                           "devices, users and robots they name");

  std::string replay_trace, replay_world, replay_policy;
  icars::app::DashboardSettings replay_http;
  auto* replay_cmd = app.add_subcommand("replay", "show a recorded trace (icars run --trace) in the dashboard");
  replay_cmd->add_option("trace", replay_trace, "the trace file (JSON lines)")->required()->check(CLI::ExistingFile);
  replay_cmd->add_option("--world", replay_world, "the house the trace was recorded on")->required()->check(CLI::ExistingFile);
  replay_cmd->add_option("--policy", replay_policy, "the policy it ran, to draw its statechart and trees")
      ->check(CLI::ExistingFile);
  add_http_options(*replay_cmd, replay_http);
  replay_http.listen = "127.0.0.1:8080";
  replay_cmd->get_option("--http")->capture_default_str();

  auto* behaviors_cmd = app.add_subcommand("behaviors", "list the behavior types policies can use");

  // Plugins: the same option on the three commands that need the behavior types.
  std::vector<std::string> plugins;
  for (auto* cmd : {run_cmd, validate_cmd, behaviors_cmd}) {
    // One file per --plugin, so that `--plugin a.so policy.xml` leaves the policy alone.
    cmd->add_option("--plugin", cmd == run_cmd ? run.plugins : plugins,
                    "a plugin (shared library) adding behavior, adaptor and composer types")
        ->allow_extra_args(false);
  }

  icars::app::ServeOptions serve;
  auto* serve_cmd = app.add_subcommand(
      "serve", "one server of a logical mediating server of several processes (docs/distribution.md)");
  serve_cmd->add_option("--name", serve.name, "this server's name, as policies (host=\"NAME\") and peers name it")
      ->capture_default_str();
  serve_cmd->add_option("--listen", serve.listen, "where device managers and peers connect, host:port")
      ->capture_default_str();
  serve_cmd->add_option("--peer", serve.peers,
                        "another server, NAME=HOST:PORT: its devices are services here, and subtrees placed "
                        "on host NAME run there (repeatable)");
  serve_cmd->add_option("--peers", serve.peers_file, "a file of peers, one NAME=HOST:PORT per line")
      ->check(CLI::ExistingFile);
  serve_cmd->add_option("--policy", serve.policy, "the policy this server coordinates (a file, or a name in --policies)");
  serve_cmd->add_option("--policies", serve.policy_dir, "the policy repository directory")->capture_default_str();
  serve_cmd->add_option("--world", serve.world, "the house the policy runs on: its names are checked, --until counts from its start")
      ->check(CLI::ExistingFile);
  serve_cmd->add_option("--wait-for", serve.wait_for,
                        "start the policy once these devices (ids) are here or at a peer (at most 60 s)")
      ->delimiter(',');
  serve_cmd->add_option("--until", serve.until, "stop at this simulated time of day (HH:MM; needs --policy and --world)");
  serve_cmd->add_option("--days", serve.days, "with --until: stop at its N-th time after the house's start")
      ->check(CLI::Range(1, 3650));
  serve_cmd->add_flag("--wall-clock", serve.wall_clock,
                      "behaviors count wall-clock time (a real home) instead of following the simulated house's clock");
  serve_cmd->add_option("--trace", serve.trace_file, "write a JSON-lines trace to this file (each record names this server)");
  serve_cmd->add_flag("--quiet", serve.quiet, "no timeline on stdout");
  serve_cmd->add_option("--token-file", serve.token_file, "the token this server presents to its peers (docs/security.md)")
      ->check(CLI::ExistingFile);
  serve_cmd->add_option("--access", serve.access_file,
                        "access file: who may connect and what each may call; peers need /sf/directory, "
                        "/sf/relay/* and /control/behavior_host (docs/distribution.md)")
      ->check(CLI::ExistingFile);
  icars::app::add_tls_options(*serve_cmd, serve.tls, icars::app::Side::server);
  add_fleet_options(*serve_cmd, serve.fleet, "the robot market of the behaviors running here");
  serve_cmd->add_option("--plugin", serve.plugins, "a plugin (shared library) adding behavior, adaptor and composer types")
      ->allow_extra_args(false);

  std::vector<std::string> merge_files;
  std::string merge_output;
  auto* merge_cmd = app.add_subcommand("merge-traces", "merge the traces of several servers into one timeline");
  merge_cmd->add_option("trace", merge_files, "trace files (JSON lines)")->required()->check(CLI::ExistingFile);
  merge_cmd->add_option("--output,-o", merge_output, "write here instead of stdout");

  std::string token_name;
  std::vector<std::string> token_paths;
  auto* token_cmd = app.add_subcommand(
      "token", "make a token for a device manager or agent: prints it and its access-file entry");
  token_cmd->add_option("name", token_name, "the principal's name")->required();
  token_cmd->add_option("--may-call", token_paths,
                        "servant path patterns it may call (default: what a device manager needs)");
  std::vector<std::string> token_devices;
  std::size_t token_max_devices = icars::planet::Principal{}.max_devices;
  token_cmd->add_option("--devices", token_devices,
                        "device id patterns it may register (\"tv\", \"robot1_*\", \"*\")");
  token_cmd->add_option("--max-devices", token_max_devices, "devices it may hold at once");

  CLI11_PARSE(app, argc, argv);
  if (*validate_cmd) return validate(to_validate, policy_dir, validate_world, plugins);
  if (*token_cmd) {
    if (token_paths.empty()) {
      token_paths = icars::app::device_manager_paths();
      if (token_devices.empty()) {
        std::fprintf(stderr,
                     "icars token: a device manager's token needs --devices: the device ids it may register "
                     "(\"tv\", \"living_*\", or \"*\" for any id no other principal holds)\n");
        return 2;
      }
    }
    icars::planet::Principal principal{token_name, "", "", token_paths, token_devices, token_max_devices};
    const std::string token = icars::planet::random_token();
    principal.token_sha256 = icars::planet::sha256_hex(token);
    try {
      icars::planet::AccessPolicy().add(principal);  // checks the name and the patterns
    } catch (const std::exception& e) {
      std::fprintf(stderr, "icars token: %s\n", e.what());
      return 2;
    }
    std::printf("%s\n%s\n", token.c_str(), icars::app::access_entry(principal).c_str());
    return 0;
  }
  if (*behaviors_cmd) return list_behaviors(plugins);
  if (*serve_cmd) return icars::app::serve(serve);
  if (*merge_cmd) return icars::app::merge_traces(merge_files, merge_output);
  if (*replay_cmd) return icars::app::replay(replay_trace, replay_world, replay_policy, replay_http);
  return icars::app::run(run);
}
