// The upper layers at scale: the Control Architecture with a 1,000-state collaboration policy
// and the behavior model with a 1,000-node behavior tree (a plain program printing medians).
//
//   upper_bench [--runs 5] [--states 1000] [--nodes 1000] [--branching 4] [--events 20000]
//               [--fanout-events 1000] [--json FILE]
//
// Control (the registry `icars` runs: make_house_registry; a SimClock for time):
//   policy load        parse_policy_file on a generated policy: a chain of --states states,
//                      state i running its own task `Step<i>` (one `Wait 1s`, the simplest
//                      real task) and moving to state i+1 on `done`, plus a statechart-level
//                      `failed` transition back to the first state (as paper_home.xml does);
//                      the file is read, parsed and checked against the registry;
//   construct / start  PolicyFactory::create (the Coordinator and its state nodes), then
//                      Coordinator::start until it returns, i.e. the initial state is entered
//                      and its task's tree is running;
//   statechart run     the clock is driven to its next event as soon as one is pending (a
//                      discrete-event run, no waiting for simulated time) until the last state
//                      is entered: states-1 transitions, each `Wait` timer → task done →
//                      transition → old task halted and destroyed → next task built and
//                      started. Reported as transitions per wall-clock second.
// Behavior (propagation as the paper and behavior.h define it: an event a node propagates is
// posted to its parent and to every sibling; siblings handle it in handle_event, plain
// composites pass it on the same way, so it climbs to the top, where the owner — a Task in a
// running application, a counting Owner here — receives it):
//   the tree           a complete --branching-ary tree of --nodes nodes in breadth-first order:
//                      inner nodes are ConcurrentBehaviors (complete=all; in a sequential only
//                      one child runs at a time), leaves are ECA behaviors whose rule is
//                      `event == 'Stimulus' and leaf == <its number>` → propagate Alarm;
//   tree start         attach + start of the whole tree on the runtime (every entry runs);
//   propagation        --events stimuli, each delivered (posted) to one leaf, round robin;
//                      the leaf's rule fires and its Alarm climbs to the top. 64 events are in
//                      flight at a time (each arrival at the top injects the next). events/s =
//                      events reaching the top per second; a node visit is one delivery that
//                      runs: the stimulus, every sibling's handle_event, every parent's
//                      child_event and the owner's;
//   sensor fan-out     --fanout-events stimuli each delivered to every leaf (what listen()
//                      does for a sensor every leaf listens to: one posted delivery per
//                      behavior); every leaf evaluates its rule, the addressed one fires and
//                      its Alarm climbs as above. 4 events in flight.
// Everything behavioral runs on the one behavior Runtime thread, as in the application.
#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>
#include <unistd.h>

#include "bench_util.h"
#include "icars/behavior/composite.h"
#include "icars/behavior/condition.h"
#include "icars/clock/sim_clock.h"
#include "icars/control/collaboration.h"
#include "icars/control/coordinator.h"
#include "icars/control/policy.h"
#include "icars/home/behaviors.h"

namespace {

namespace b = icars::behavior;
namespace c = icars::control;
using icars::SimClock;
using icars::Time;
using Clock = std::chrono::steady_clock;
using Ms = std::chrono::duration<double, std::milli>;
using namespace std::chrono_literals;
namespace home = icars::home;

using icars::bench::Stats;
using icars::bench::stats;

// --- Control: a chain of states ---------------------------------------------------------------

std::string state_name(int i) { return fmt::format("S{:04}", i); }

std::string chain_policy(int states) {
  std::string xml = "<policy name=\"chain\" version=\"1\">\n";
  xml += fmt::format("  <description>A chain of {} states, each waiting 1 s then moving on</description>\n", states);
  for (int i = 0; i < states; ++i) {
    xml += fmt::format("  <task name=\"Step{:04}\"><behavior type=\"Wait\" duration=\"1s\"/></task>\n", i);
  }
  xml += fmt::format("  <statechart initial=\"{}\">\n", state_name(0));
  xml += fmt::format("    <transition event=\"failed\" target=\"{}\"/>\n", state_name(0));
  for (int i = 0; i < states; ++i) {
    if (i + 1 < states) {
      xml += fmt::format("    <state name=\"{}\" task=\"Step{:04}\"><transition event=\"done\" target=\"{}\"/></state>\n",
                         state_name(i), i, state_name(i + 1));
    } else {
      xml += fmt::format("    <state name=\"{}\" task=\"Step{:04}\"/>\n", state_name(i), i);
    }
  }
  xml += "  </statechart>\n</policy>\n";
  return xml;
}

struct ControlResult {
  double load_ms = 0, construct_ms = 0, start_ms = 0, run_ms = 0;
  std::uint64_t transitions = 0;
};

ControlResult run_control(const std::string& path, int states, const b::BehaviorRegistry& registry) {
  ControlResult result;
  SimClock clock{Time{0}};
  b::Runtime runtime(clock);
  icars::service::ServiceContainer services;
  b::Trace trace;
  b::Environment env{runtime, services, trace};
  const std::string last = state_name(states - 1);
  std::atomic<bool> reached_last{false};
  // Runs on the runtime thread, under the trace's lock.
  trace.add_sink([&](const b::TraceRecord& r) {
    if (r.kind == "state" && r.field("event") == "enter" && r.field("state") == last) reached_last = true;
  });

  auto t0 = Clock::now();
  auto parsed = c::parse_policy_file(path, registry);
  result.load_ms = Ms(Clock::now() - t0).count();
  if (!parsed.warnings.empty()) throw std::runtime_error("policy: " + parsed.warnings.front().to_string());

  t0 = Clock::now();
  auto coordinator = c::PolicyFactory(registry).create(std::move(parsed.policy), env);
  result.construct_ms = Ms(Clock::now() - t0).count();

  t0 = Clock::now();
  coordinator->start();
  result.start_ms = Ms(Clock::now() - t0).count();
  if (coordinator->current() != state_name(0)) {
    throw std::runtime_error("the coordinator did not start in " + state_name(0) + " but in '" +
                             coordinator->current() + "'");
  }

  // Drive the clock to each next timer as soon as the runtime has set it.
  t0 = Clock::now();
  const auto bound = t0 + 120s;
  while (!reached_last.load()) {
    if (const auto next = clock.next_event_time()) {
      clock.advance_to(*next);
    } else if (Clock::now() > bound) {
      throw std::runtime_error(fmt::format("the statechart run stopped in {} after {} transitions",
                                           coordinator->current(), coordinator->transitions()));
    } else {
      std::this_thread::yield();
    }
  }
  result.run_ms = Ms(Clock::now() - t0).count();
  result.transitions = coordinator->transitions();
  if (result.transitions != static_cast<std::uint64_t>(states - 1)) {
    throw std::runtime_error(fmt::format("{} transitions, expected {}", result.transitions, states - 1));
  }
  coordinator->stop();
  if (!runtime.drain(10s)) throw std::runtime_error("the runtime did not drain");
  return result;
}

// --- Behavior: a tree of ECA leaves under concurrent composites -------------------------------

// An ECA behavior: on an event for which `when` holds, propagate `emit` with the event's
// properties.
class EcaLeaf final : public b::Behavior {
 public:
  EcaLeaf(b::Condition when, std::string emit) : when_(std::move(when)), emit_(std::move(emit)) {}

 protected:
  void handle_event(const b::Event& e) override {
    if (!when_.evaluate(e)) return;
    b::Event out(emit_);
    for (const auto& [name, value] : e.items()) out.put(name, value);
    propagate(std::move(out));
  }

 private:
  b::Condition when_;
  std::string emit_;
};

// The tree's owner: counts the events reaching the top and injects the next ones.
class TopOwner final : public b::Owner {
 public:
  std::function<void()> on_event;
  void child_event(b::Behavior&, const b::Event&) override { on_event(); }
  void child_done(b::Behavior&) override {}
};

struct Tree {
  std::unique_ptr<b::Behavior> root;
  std::vector<b::Behavior*> nodes;  // breadth-first
  std::vector<b::Behavior*> leaves;
  std::vector<int> leaf_depth;
};

Tree build_tree(int node_count, int branching) {
  Tree t;
  const auto n = static_cast<std::size_t>(node_count);
  const auto k = static_cast<std::size_t>(branching);
  std::vector<std::unique_ptr<b::Behavior>> owned(n);
  std::vector<int> depth(n, 0);
  int leaf_number = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (i > 0) depth[i] = depth[(i - 1) / k] + 1;
    if (k * i + 1 < n) {
      owned[i] = std::make_unique<b::ConcurrentBehavior>();
      owned[i]->set_identity("concurrent", fmt::format("c{}", i));
    } else {
      owned[i] = std::make_unique<EcaLeaf>(
          b::Condition::parse(fmt::format("event == 'Stimulus' and leaf == {}", leaf_number)), "Alarm");
      owned[i]->set_identity("Eca", fmt::format("leaf{}", leaf_number));
      t.leaves.push_back(owned[i].get());
      t.leaf_depth.push_back(depth[i]);
      ++leaf_number;
    }
    t.nodes.push_back(owned[i].get());
  }
  // Parents adopt their children from the last parent back, so each child still has its
  // own subtree and is still here to be moved; children keep their order.
  for (std::size_t p = n; p-- > 0;) {
    for (std::size_t ch = k * p + 1; ch <= k * p + k && ch < n; ++ch) owned[p]->add_child(std::move(owned[ch]));
  }
  t.root = std::move(owned[0]);
  return t;
}

struct BehaviorResult {
  double start_ms = 0;
  double propagation_s = 0, fanout_s = 0;
  std::uint64_t propagation_visits = 0, fanout_visits = 0;
};

// Delivers `events` stimuli with `window` in flight; `deliver(k)` posts the deliveries of
// stimulus k. Returns the seconds until the last Alarm reached the top, and the node visits:
// the deliveries that ran a handle_event (counted by the nodes, after draining the runtime so
// the last events' sibling deliveries are in) plus one child_event per level climbed.
std::pair<double, std::uint64_t> stream_events(b::Runtime& runtime, Tree& tree, TopOwner& top, int events,
                                               int window, const std::function<void(int)>& deliver) {
  std::mutex mutex;
  std::condition_variable cv;
  bool done = false;
  int arrived = 0, injected = 0;
  std::uint64_t parent_visits = 0;
  std::uint64_t handled_before = 0;
  runtime.run([&] {
    for (auto* node : tree.nodes) handled_before += node->events_handled();
  });
  top.on_event = [&] {  // on the runtime thread
    ++arrived;
    if (injected < events) deliver(injected++);
    if (arrived == events) {
      std::lock_guard lock(mutex);
      done = true;
      cv.notify_all();
    }
  };
  const auto t0 = Clock::now();
  runtime.post([&] {
    while (injected < std::min(window, events)) deliver(injected++);
  });
  {
    std::unique_lock lock(mutex);
    if (!cv.wait_for(lock, 300s, [&] { return done; })) throw std::runtime_error("events did not reach the top in 300 s");
  }
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  if (!runtime.drain(30s)) throw std::runtime_error("the runtime did not drain");
  std::uint64_t handled = 0;
  runtime.run([&] {
    for (auto* node : tree.nodes) handled += node->events_handled();
  });
  // Parents' child_event (and the owner's): one per level the Alarm climbs.
  for (int k = 0; k < events; ++k) {
    parent_visits += static_cast<std::uint64_t>(tree.leaf_depth[static_cast<std::size_t>(k) % tree.leaves.size()]) + 1;
  }
  top.on_event = [] {};
  return {seconds, handled - handled_before + parent_visits};
}

BehaviorResult run_behavior(int node_count, int branching, int events, int fanout_events) {
  BehaviorResult result;
  SimClock clock{Time{0}};
  b::Runtime runtime(clock);
  icars::service::ServiceContainer services;
  b::Trace trace;
  b::Environment env{runtime, services, trace};
  TopOwner top;
  top.on_event = [] {};
  Tree tree = build_tree(node_count, branching);
  const auto leaf_count = tree.leaves.size();
  std::vector<std::shared_ptr<const b::Event>> stimuli;
  for (std::size_t i = 0; i < leaf_count; ++i) {
    b::Event e("Stimulus");
    e.set("leaf", static_cast<std::int32_t>(i));
    stimuli.push_back(std::make_shared<const b::Event>(std::move(e)));
  }

  auto t0 = Clock::now();
  runtime.run([&] {
    tree.root->attach(env, top, "Bench");
    tree.root->start();
  });
  result.start_ms = Ms(Clock::now() - t0).count();
  if (!runtime.run([&] {
        return std::all_of(tree.nodes.begin(), tree.nodes.end(), [](auto* n) { return n->running(); });
      })) {
    throw std::runtime_error("not every node of the tree is running");
  }

  // Propagation: one stimulus to one leaf, round robin.
  std::tie(result.propagation_s, result.propagation_visits) =
      stream_events(runtime, tree, top, events, 64, [&](int k) {
        const auto i = static_cast<std::size_t>(k) % leaf_count;
        runtime.post([leaf = tree.leaves[i], life = tree.leaves[i]->life(), e = stimuli[i]] {
          if (life.lock()) leaf->receive(*e);
        });
      });
  // Fan-out: every stimulus to every leaf, as a sensor they all listen to.
  std::tie(result.fanout_s, result.fanout_visits) =
      stream_events(runtime, tree, top, fanout_events, 4, [&](int k) {
        const auto& e = stimuli[static_cast<std::size_t>(k) % leaf_count];
        for (auto* leaf : tree.leaves) {
          runtime.post([leaf, life = leaf->life(), e] {
            if (life.lock()) leaf->receive(*e);
          });
        }
      });
  runtime.run([&] {
    tree.root->halt();
    tree.root.reset();
  });
  return result;
}

// --- Output -------------------------------------------------------------------------------------

struct Row {
  std::string layer, workload, unit;
  std::vector<double> values;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Control Architecture and behavior model at 1,000 states / nodes"};
  int runs = 5;
  int states = 1000;
  int nodes = 1000;
  int branching = 4;
  int events = 20000;
  int fanout_events = 1000;
  std::string json_file;
  app.add_option("--runs", runs, "repetitions")->check(CLI::Range(1, 1000));
  app.add_option("--states", states, "states in the policy's chain")->check(CLI::Range(2, 100000));
  app.add_option("--nodes", nodes, "nodes in the behavior tree")->check(CLI::Range(2, 1000000));
  app.add_option("--branching", branching, "children per inner node")->check(CLI::Range(2, 1000));
  app.add_option("--events", events, "stimuli per propagation run")->check(CLI::Range(64, 100000000));
  app.add_option("--fanout-events", fanout_events, "stimuli per fan-out run")->check(CLI::Range(4, 10000000));
  app.add_option("--json", json_file, "also write the rows to FILE as JSON");
  CLI11_PARSE(app, argc, argv);

  try {
    const auto registry = home::behavior_registry();
    const auto path = (std::filesystem::temp_directory_path() / fmt::format("upper_bench_chain_{}.xml", ::getpid())).string();
    {
      std::ofstream out(path);
      out << chain_policy(states);
      if (!out) throw std::runtime_error("cannot write " + path);
    }
    const auto policy_bytes = std::filesystem::file_size(path);

    const std::string st = fmt::format("{} states", states);
    const std::string nd = fmt::format("{} nodes", nodes);
    std::vector<Row> rows = {
        {"control", fmt::format("policy load ({})", st), "ms", {}},
        {"control", fmt::format("coordinator construct ({})", st), "ms", {}},
        {"control", fmt::format("coordinator start ({})", st), "ms", {}},
        {"control", fmt::format("statechart run ({} transitions)", states - 1), "transitions/s", {}},
        {"behavior", fmt::format("tree start ({})", nd), "ms", {}},
        {"behavior", fmt::format("event propagation leaf to top ({})", nd), "events/s", {}},
        {"behavior", fmt::format("event propagation leaf to top ({}), per node visit", nd), "ns", {}},
        {"behavior", fmt::format("sensor fan-out to every leaf ({})", nd), "events/s", {}},
        {"behavior", fmt::format("sensor fan-out to every leaf ({}), per node visit", nd), "ns", {}},
    };
    double propagation_visits = 0, fanout_visits = 0;
    std::size_t leaves = 0;
    {
      const Tree probe = build_tree(nodes, branching);
      leaves = probe.leaves.size();
    }
    for (int r = 0; r < runs; ++r) {
      const auto cr = run_control(path, states, registry);
      rows[0].values.push_back(cr.load_ms);
      rows[1].values.push_back(cr.construct_ms);
      rows[2].values.push_back(cr.start_ms);
      rows[3].values.push_back(static_cast<double>(cr.transitions) / (cr.run_ms / 1000));
      const auto br = run_behavior(nodes, branching, events, fanout_events);
      rows[4].values.push_back(br.start_ms);
      rows[5].values.push_back(events / br.propagation_s);
      rows[6].values.push_back(br.propagation_s * 1e9 / static_cast<double>(br.propagation_visits));
      rows[7].values.push_back(fanout_events / br.fanout_s);
      rows[8].values.push_back(br.fanout_s * 1e9 / static_cast<double>(br.fanout_visits));
      propagation_visits = static_cast<double>(br.propagation_visits) / events;
      fanout_visits = static_cast<double>(br.fanout_visits) / fanout_events;
    }
    std::filesystem::remove(path);

    fmt::print("policy: chain of {} states, {} tasks (Wait 1s each), {} KiB; tree: {} nodes, {}-ary, {} ECA leaves\n",
               states, states, policy_bytes / 1024, nodes, branching, leaves);
    fmt::print("node visits per event: propagation {:.1f}, fan-out {:.1f}; {} runs, median [min, max]\n",
               propagation_visits, fanout_visits, runs);
    fmt::print("{:<9} {:<60} {:>12} {:>25}  {}\n", "layer", "workload", "median", "[min, max]", "unit");
    nlohmann::ordered_json out_rows = nlohmann::ordered_json::array();
    for (const auto& row : rows) {
      const auto s = stats(row.values);
      fmt::print("{:<9} {:<60} {:>12.4g} [{:>11.4g}, {:>11.4g}]  {}\n", row.layer, row.workload, s.median, s.min,
                 s.max, row.unit);
      out_rows.push_back({{"layer", row.layer},
                          {"workload", row.workload},
                          {"value", s.median},
                          {"unit", row.unit},
                          {"min", s.min},
                          {"max", s.max},
                          {"runs", runs}});
    }
    if (!json_file.empty()) {
      std::ofstream out(json_file);
      out << nlohmann::ordered_json{{"rows", out_rows}}.dump(2) << '\n';
      if (!out) throw std::runtime_error("cannot write " + json_file);
    }
  } catch (const c::PolicyError& e) {
    fmt::print(stderr, "upper_bench: {}\n", e.what());
    return 1;
  } catch (const std::exception& e) {
    fmt::print(stderr, "upper_bench: {}\n", e.what());
    return 1;
  }
  return 0;
}
