// `icars run`: assembles the mediating server — PLANET server, Service Framework, behavior
// runtime, Collaboration Manager — around a house, runs a policy and reports what happened.
#include "mediator.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <mutex>
#include <csignal>
#include <cmath>
#include <cstdio>
#include <map>
#include <set>
#include <thread>

#include "icars/behavior/house_behaviors.h"
#include "icars/control/collaboration.h"
#include "icars/device/simulated_house.h"
#include "icars/service/service_framework.h"
#include "icars/sim/svg_plot.h"

namespace icars::app {

namespace b = icars::behavior;
namespace c = icars::control;
namespace p = icars::planet;
namespace s = icars::service;
using namespace std::chrono_literals;

namespace {

std::pair<std::string, std::uint16_t> split_endpoint(const std::string& endpoint) {
  const auto colon = endpoint.rfind(':');
  if (colon == std::string::npos) throw std::invalid_argument("--listen " + endpoint + ": expected host:port");
  const auto port = std::stoi(endpoint.substr(colon + 1));
  if (port < 0 || port > 65535) throw std::invalid_argument("--listen " + endpoint + ": bad port");
  return {endpoint.substr(0, colon), static_cast<std::uint16_t>(port)};
}

b::TraceRecord record(sim::SimTime t, std::string kind, std::string source, std::string text) {
  b::TraceRecord r;
  r.time = t;
  r.kind = std::move(kind);
  r.source = std::move(source);
  r.text = std::move(text);
  return r;
}

// Follows the simulated time of a house whose device managers run elsewhere: polls the
// Simulation service's clock and advances the mediator's own clock to it.
class ClockFollower {
 public:
  ClockFollower(sim::SimClock& clock, s::ServiceContainer& services) : clock_(clock), services_(services) {
    thread_ = std::thread([this] { run(); });
  }
  ~ClockFollower() {
    stop_ = true;
    thread_.join();
  }
  bool following() const { return following_; }

 private:
  void run() {
    while (!stop_) {
      if (auto simulation = services_.find_first<s::SimulationService>(s::ServiceQuery::of_type("Simulation").available())) {
        try {
          const sim::SimTime remote(simulation->proxy().now_ms());
          if (remote > clock_.now()) clock_.advance_to(remote);
          following_ = true;
        } catch (const std::exception&) {
          // The device manager is restarting: keep the time we have and ask again.
        }
      }
      // A call is tens of microseconds; at 1500x, 5 ms of wall time are 7.5 s simulated.
      std::this_thread::sleep_for(5ms);
    }
  }
  sim::SimClock& clock_;
  s::ServiceContainer& services_;
  std::atomic<bool> stop_{false};
  std::atomic<bool> following_{false};
  std::thread thread_;
};

// What the mediator hears and where its robots are, for the timeline: every SpeechSensor's
// recognized speech and (for robots the mediator cannot see directly) Navigation positions.
class ServiceObserver {
 public:
  ServiceObserver(s::ServiceContainer& services, b::Trace& trace, bool positions)
      : services_(services), trace_(trace), positions_(positions) {
    watch_ = services_.watch([this](const std::shared_ptr<s::Service>& service, const s::ServiceChange& change) {
      if (change == s::ServiceChange::added) observe(service);
    });
    for (const auto& service : services_.all()) observe(service);
  }
  ~ServiceObserver() {
    services_.remove_watcher(watch_);
    std::lock_guard lock(mutex_);
    for (auto& release : releases_) release();
  }
  int heard() const { return heard_.load(); }

 private:
  void observe(const std::shared_ptr<s::Service>& service) {
    std::lock_guard lock(mutex_);
    if (!seen_.insert(service->id()).second) return;
    if (auto speech = std::dynamic_pointer_cast<s::SpeechSensor>(service)) {
      const auto id = speech->subscribe([this](const s::SpeechEvent& e) {
        ++heard_;
        auto r = record(sim::SimTime(e.time_ms), "speech", e.device,
                        fmt::format("{} heard \"{}\" ({:.0f}% sure)", e.device, e.text, e.confidence * 100));
        r.with("words", e.text).with("device", e.device);
        trace_.record(std::move(r));
      });
      releases_.push_back([speech, id] { speech->unsubscribe(id); });
    }
    if (auto nav = std::dynamic_pointer_cast<s::NavigationService>(service); nav && positions_) {
      const auto id = nav->subscribe([this](const home::PositionEvent& e) {
        auto r = record(sim::SimTime(e.time_ms), "robot", e.robot,
                        fmt::format("{} at ({:.2f}, {:.2f}){}", e.robot, e.x, e.y, e.moving ? " moving" : ""));
        r.with("robot", e.robot).with("x", e.x).with("y", e.y).with("moving", e.moving);
        trace_.record(std::move(r));
      });
      releases_.push_back([nav, id] { nav->unsubscribe(id); });
    }
  }

  s::ServiceContainer& services_;
  b::Trace& trace_;
  bool positions_;
  std::uint64_t watch_ = 0;
  std::mutex mutex_;
  std::set<std::string> seen_;
  std::vector<std::function<void()>> releases_;
  std::atomic<int> heard_{0};
};

// The mediator's record of the commands it sends to devices: every call of an operation that
// changes a device, traced as "command" records when sent and when acknowledged (a reply came)
// or failed (the error), with the PLANET request id that the device side logs with what it
// executed (the effects of --effects / the embedded house), so the two can be matched.
class CommandRecorder final : public p::CallObserver {
 public:
  explicit CommandRecorder(b::Trace& trace) : trace_(trace) {}
  // Records are stamped with `clock`'s time (0 while null); once this returns, the previous
  // clock is no longer read.
  void set_clock(const sim::SimClock* clock) {
    std::lock_guard lock(mutex_);
    clock_ = clock;
  }

  void sent(std::uint32_t request_id, const std::string& path, std::string_view method) override {
    if (!is_command(method)) return;
    add(request_id, path, method, "sent", {});
  }
  void ended(std::uint32_t request_id, const std::string& path, std::string_view method,
             const std::exception_ptr& error) override {
    if (!is_command(method)) return;
    add(request_id, path, method, error ? "failed" : "acknowledged", error ? describe(error) : "");
  }

 private:
  static std::string describe(const std::exception_ptr& error) {
    try {
      std::rethrow_exception(error);
    } catch (const std::exception& e) {
      return e.what();
    } catch (...) {
      return "unknown error";
    }
  }
  // The operations of idl/home.idl that change a device (each one the devices report as an
  // effect); the others only read a state or subscribe.
  static bool is_command(std::string_view method) {
    static constexpr std::string_view kCommands[] = {"set_power", "set_channel", "set_volume", "set_intensity",
                                                     "play", "stop", "speak", "go_to", "go_to_waypoint", "turn_to"};
    return std::find(std::begin(kCommands), std::end(kCommands), method) != std::end(kCommands);
  }
  void add(std::uint32_t request_id, const std::string& path, std::string_view method, const char* event,
           const std::string& error) {
    // The path of a device capability is /devices/<device>/<capability>.
    std::string device = path, capability;
    if (path.starts_with("/devices/")) {
      device = path.substr(9);
      if (const auto slash = device.find('/'); slash != std::string::npos) {
        capability = device.substr(slash + 1);
        device.resize(slash);
      }
    }
    std::lock_guard lock(mutex_);
    auto r = record(clock_ ? clock_->now() : sim::SimTime(0), "command", device,
                    fmt::format("command {} {}: {}.{}.{}{}", request_id, event, device, capability, method,
                                error.empty() ? std::string() : fmt::format(" ({})", error)));
    r.with("event", std::string(event)).with("request", static_cast<double>(request_id)).with("device", device)
        .with("capability", capability).with("method", std::string(method));
    if (!error.empty()) r.with("error", error);
    trace_.record(std::move(r));
  }

  b::Trace& trace_;
  std::mutex mutex_;
  const sim::SimClock* clock_ = nullptr;
};

// --- The summary ----------------------------------------------------------------------------

// What the summary and the plot are made of, gathered record by record as the run goes (a trace
// sink) so that a run of any length keeps a bounded amount: counts, time per state, the first
// failures, the last effect per device. Only a run that draws a plot keeps its positions and
// transitions (the plot shows every one).
class Summary {
 public:
  explicit Summary(bool keep_plot) : keep_plot_(keep_plot) {}
  // The sink reads nothing but the record; it is called under the trace's lock.
  b::Trace::Sink sink() {
    return [this](const b::TraceRecord& r) { add(r); };
  }

  void print(const std::string& policy, sim::SimTime from, sim::SimTime to, double wall_seconds, double speed) const {
    std::lock_guard lock(mutex_);
    std::printf("\n=== summary: policy %s, %s to %s (%.0f min simulated in %.1f s, %.0fx) ===\n", policy.c_str(),
                sim::format_time(from).c_str(), sim::format_time(to).c_str(),
                static_cast<double>((to - from).count()) / 60000.0, wall_seconds, speed);
    // States: how often entered and for how long (a state still active counts up to `to`).
    auto states = states_;
    for (const auto& [name, since] : entered_) states[name].second += to - since;
    std::printf("states (%d transitions):\n", transitions_);
    for (const auto& name : order_) {
      std::printf("  %-14s entered %2d times, %6.1f min\n", name.c_str(), states[name].first,
                  static_cast<double>(states[name].second.count()) / 60000.0);
    }
    std::printf("behaviors: %d started, %d succeeded, %d failed, %d halted\n", started_, succeeded_, failed_, halted_);
    for (const auto& f : failures_) std::printf("  %s\n", f.c_str());
    std::printf("service calls: %d (%d failed); voice commands heard: %d\n", calls_, failed_calls_, heard_);
    std::printf("device commands: %d sent, %d acknowledged, %d failed\n", commands_sent_, commands_acknowledged_,
                commands_failed_);
    std::printf("device effects: %d; last effect per device:\n", effects_);
    for (const auto& [device, state] : device_state_) std::printf("  %-16s %s\n", device.c_str(), state.c_str());
    std::printf("robot distance driven: %.1f m\n", driven_);
  }

  // Needs keep_plot.
  sim::PlotData plot(const std::string& title, const sim::House& house) const {
    std::lock_guard lock(mutex_);
    sim::PlotData data;
    data.title = title;
    std::map<std::string, sim::PlotTrack> robots, users;
    std::pair<double, double> robot_at{0, 0};
    if (!house.robots.empty()) robot_at = {house.robots.front().start.x, house.robots.front().start.y};
    for (const auto& r : plotted_) {
      if (r.kind == "robot" || r.kind == "user") {
        const auto who = r.kind == "robot" ? r.field("robot") : r.field("user");
        auto& track = (r.kind == "robot" ? robots : users)[who];
        track.name = who;
        const double x = std::stod(r.field("x")), y = std::stod(r.field("y"));
        track.points.emplace_back(r.time, sim::Point{x, y});
        if (r.kind == "robot") robot_at = {x, y};
      } else if (r.kind == "transition") {
        sim::PlotMark mark;
        mark.time = r.time;
        mark.at = sim::Point{robot_at.first, robot_at.second};
        mark.label = fmt::format("{} {}", sim::format_time(r.time).substr(3, 5), r.field("to"));
        data.marks.push_back(std::move(mark));
      }
    }
    for (auto& [name, track] : robots) data.robots.push_back(std::move(track));
    for (auto& [name, track] : users) data.users.push_back(std::move(track));
    return data;
  }

 private:
  void add(const b::TraceRecord& r) {
    std::lock_guard lock(mutex_);
    if (keep_plot_ && (r.kind == "robot" || r.kind == "user" || r.kind == "transition")) plotted_.push_back(r);
    if (r.kind == "transition") {
      ++transitions_;
    } else if (r.kind == "state") {
      const auto name = r.field("state");
      if (!states_.contains(name)) order_.push_back(name);
      if (r.field("event") == "enter") {
        ++states_[name].first;
        entered_[name] = r.time;
      } else if (entered_.contains(name)) {
        states_[name].second += r.time - entered_[name];
        entered_.erase(name);
      }
    } else if (r.kind == "behavior") {
      const auto e = r.field("event");
      started_ += e == "start";
      succeeded_ += e == "success";
      halted_ += e == "halt";
      if (e == "failure") {
        ++failed_;
        if (failures_.size() < 5) failures_.push_back(fmt::format("[{}] {}", sim::format_time(r.time), r.text));
      }
    } else if (r.kind == "call") {
      if (r.field("ok") == "false") ++failed_calls_;
      else ++calls_;
    } else if (r.kind == "command") {
      const auto e = r.field("event");
      commands_sent_ += e == "sent";
      commands_acknowledged_ += e == "acknowledged";
      commands_failed_ += e == "failed";
    } else if (r.kind == "effect") {
      ++effects_;
      device_state_[r.field("device")] = r.field("what") + (r.field("value").empty() ? "" : " " + r.field("value"));
    } else if (r.kind == "speech") {
      ++heard_;
    } else if (r.kind == "robot") {
      const double x = std::stod(r.field("x")), y = std::stod(r.field("y"));
      const auto robot = r.field("robot");
      if (last_pose_.contains(robot)) driven_ += std::hypot(x - last_pose_[robot].first, y - last_pose_[robot].second);
      last_pose_[robot] = {x, y};
    }
  }

  const bool keep_plot_;
  mutable std::mutex mutex_;
  std::map<std::string, std::pair<int, sim::SimTime>> states_;  // times entered, time spent
  std::map<std::string, sim::SimTime> entered_;                 // active states: since when
  std::vector<std::string> order_;
  int transitions_ = 0, started_ = 0, succeeded_ = 0, failed_ = 0, halted_ = 0, calls_ = 0, failed_calls_ = 0;
  int commands_sent_ = 0, commands_acknowledged_ = 0, commands_failed_ = 0, effects_ = 0, heard_ = 0;
  std::vector<std::string> failures_;  // the first five
  std::map<std::string, std::string> device_state_;
  double driven_ = 0;
  std::map<std::string, std::pair<double, double>> last_pose_;
  std::vector<b::TraceRecord> plotted_;
};

// SIGHUP: reads the access file again and puts it in force; principals removed or changed lose
// their links, and those removed their devices. A broken file changes nothing.
void reload_access(const RunOptions& options, std::shared_ptr<const p::AccessPolicy>& in_force,
                   p::Communicator& server, s::DeviceRegistry& registry, b::Trace& trace,
                   const sim::SimClock& clock, const std::string& house_token) {
  const auto current = in_force;
  if (options.access_file.empty() || !current) {
    trace.record(record(clock.now(), "note", "icars", "SIGHUP: no access file to reload"));
    return;
  }
  std::shared_ptr<p::AccessPolicy> next;
  try {
    next = std::make_shared<p::AccessPolicy>(p::AccessPolicy::load(options.access_file));
    if (const auto* house = current->find("house-devices"); house && !house_token.empty()) next->add(*house);
  } catch (const std::exception& e) {
    trace.record(record(clock.now(), "note", "icars",
                        fmt::format("access file not reloaded, the old one stays in force: {}", e.what())));
    return;
  }
  const auto changed = p::reload_access_policy(server.connections(), *current, next);
  std::size_t forgotten = 0;
  for (const auto& name : changed) {
    if (!next->find(name)) forgotten += registry.forget_holder(name);
  }
  in_force = next;
  trace.record(record(clock.now(), "note", "icars",
                      fmt::format("access file reloaded: {} principals; revoked or changed: {}; {} devices forgotten",
                                  next->principals().size(), changed.empty() ? "none" : fmt::format("{}", fmt::join(changed, ", ")),
                                  forgotten)));
}

}  // namespace

int run(const RunOptions& options) {
  // Signals are taken by sigtimedwait below: block them before any thread starts.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGHUP);  // reload the access file
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  spdlog::set_level(spdlog::level::warn);
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // the timeline is read live, also through pipes

  // --- Inputs: every mistake here is reported before anything starts. ---------------------------
  sim::House house;
  try {
    house = sim::load_house(options.world);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "icars: %s\n", e.what());
    return 2;
  }
  const auto registry = b::house::make_house_registry();
  c::PolicyRepository repository(options.policy_dir);
  std::string policy_name;
  try {
    const auto parsed = c::parse_policy_file(repository.path_of(options.policy), registry);
    for (const auto& w : parsed.warnings) std::fprintf(stderr, "%s\n", w.to_string().c_str());
    policy_name = parsed.policy.name;
  } catch (const c::PolicyError& e) {
    for (const auto& d : e.diagnostics()) std::fprintf(stderr, "%s\n", d.to_string().c_str());
    return 2;
  }
  const auto until = sim::parse_time_of_day(options.until);
  if (!until) {
    std::fprintf(stderr, "icars: --until %s is not a time of day (HH:MM)\n", options.until.c_str());
    return 2;
  }
  const auto start = house.start_time;
  const auto day = sim::kDay * (start / sim::kDay);
  auto stop_at = day + *until;
  if (stop_at <= start) stop_at += sim::kDay;
  stop_at += sim::kDay * (options.days - 1);  // the house's daily schedule repeats
  std::string host;
  std::uint16_t port = 0;
  try {
    std::tie(host, port) = split_endpoint(options.listen);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "icars: %s\n", e.what());
    return 2;
  }

  // --- The trace: timeline, JSON lines, and what the summary and plot are made from. ---------
  b::Trace trace;
  Summary summary(!options.plot_file.empty());
  trace.add_sink(summary.sink());
  // The timeline leaves out positions and the command record (the "call" lines say it).
  if (!options.quiet) trace.add_sink(b::timeline_printer(stdout, {"robot", "user", "command"}));
  if (!options.trace_file.empty()) {
    try {
      trace.add_sink(b::json_lines_writer(options.trace_file));
    } catch (const std::exception& e) {
      std::fprintf(stderr, "icars: %s\n", e.what());
      return 2;
    }
  }

  // --- The mediating server. ----------------------------------------------------------------------
  p::CommunicatorOptions server_options;
  server_options.name = "icars";
  server_options.logger = spdlog::default_logger();
  server_options.tls = options.tls;
  // The embedded house authenticates with a token made for this run.
  const std::string house_token = options.access_file.empty() ? "" : p::random_token();
  if (!options.access_file.empty()) {
    try {
      auto access = std::make_shared<p::AccessPolicy>(p::AccessPolicy::load(options.access_file));
      if (!options.external) {
        access->add({"house-devices", p::sha256_hex(house_token), "",
                     {std::string(device::kRegistryPath), "/sf/listeners/*"}, {"*"}, house.devices.size() + 16});
      }
      server_options.access = std::move(access);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "icars: %s\n", e.what());
      return 2;
    }
  }
  std::unique_ptr<p::Communicator> server_endpoint;
  try {
    server_endpoint = std::make_unique<p::Communicator>(server_options);
  } catch (const std::exception& e) {  // unreadable TLS files, a key that does not match
    std::fprintf(stderr, "icars: %s\n", e.what());
    return 2;
  }
  p::Communicator& server = *server_endpoint;
  std::shared_ptr<const p::AccessPolicy> access_in_force = server_options.access;
  s::ServiceFramework sf(server);
  auto commands = std::make_shared<CommandRecorder>(trace);
  sf.registry().set_call_observer(commands);
  // Outages of device managers and what came back, in the timeline (stamped once a clock runs).
  std::atomic<const sim::SimClock*> device_clock{nullptr};
  const auto device_watch = sf.container().watch_devices([&trace, &device_clock](const p::Event& e) {
    const auto* at = device_clock.load();
    const auto device = e.get<std::string>("device");
    std::string text;
    if (e.type() == "DeviceLost") text = fmt::format("{} lost: {}", device, e.get<std::string>("reason"));
    else if (e.type() == "DeviceBack") text = fmt::format("{} registered again", device);
    else if (e.type() == "DeviceForgotten") text = fmt::format("{} forgotten (gone too long)", device);
    else if (e.type() == "DeviceRestored") {
      const auto error = e.get<std::string>("error");
      text = fmt::format("{} came back with another state: {}{}{}", device, e.get<std::string>("differences"),
                         e.get<bool>("reapplied") ? "; re-applied" : "", error.empty() ? "" : "; failed: " + error);
    } else {
      return;
    }
    auto r = record(at ? at->now() : sim::SimTime(0), "device", device, std::move(text));
    r.with("event", e.type()).with("device", device);
    if (e.type() == "DeviceRestored") {
      r.with("differences", e.get<std::string>("differences")).with("reapplied", e.get<bool>("reapplied"));
    }
    trace.record(std::move(r));
  });
  struct DeviceWatch {
    s::ServiceContainer& services;
    std::uint64_t id;
    ~DeviceWatch() { services.remove_device_watcher(id); }
  } release_device_watch{sf.container(), device_watch};
  std::uint16_t bound = 0;
  try {
    bound = server.listen(host, port);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "icars: cannot listen on %s: %s\n", options.listen.c_str(), e.what());
    return 2;
  }
  std::printf("[icars] mediating server on %s:%u; policy %s; house %s\n", host.c_str(), bound,
              repository.path_of(options.policy).c_str(), house.name.c_str());

  // --- The house: simulated device managers in this process, or elsewhere. -------------------
  std::unique_ptr<device::SimulatedHouse> home;
  std::unique_ptr<sim::SimClock> own_clock;
  std::vector<std::uint64_t> world_listeners;
  sim::SimClock* clock = nullptr;
  if (!options.external) {
    device::SimulatedHouseOptions house_options;
    house_options.speedup = options.speed;
    house_options.pun = "house-devices";
    house_options.tls = options.tls;
    house_options.token = house_token;
    house_options.logger = spdlog::default_logger();
    house_options.effects = [&trace](const device::DeviceEffect& e) {
      auto r = record(e.time, "effect", e.device, fmt::format("{}: {}{}", e.device, e.what, e.value.empty() ? "" : " " + e.value));
      r.with("device", e.device).with("what", e.what).with("value", e.value)
          .with("request", static_cast<double>(e.request_id));
      trace.record(std::move(r));
    };
    home = std::make_unique<device::SimulatedHouse>(house, house_options);
    auto& world = home->world();
    world_listeners.push_back(world.on_robot_pose([&trace, &world](const std::string& robot, const sim::Pose& pose, bool moving) {
      auto r = record(world.clock().now(), "robot", robot,
                      fmt::format("{} at ({:.2f}, {:.2f}){}", robot, pose.x, pose.y, moving ? " moving" : ""));
      r.with("robot", robot).with("x", pose.x).with("y", pose.y).with("moving", moving);
      trace.record(std::move(r));
    }));
    world_listeners.push_back(world.on_user([&trace, &world](const sim::UserState& u) {
      const auto posture = std::string(sim::to_string(u.posture));
      auto r = record(world.clock().now(), "user", u.user,
                      fmt::format("{} {}{} in the {}", u.user, posture, u.furniture.empty() ? "" : " on the " + u.furniture,
                                  u.room.empty() ? "house" : u.room));
      r.with("user", u.user).with("x", u.at.x).with("y", u.at.y).with("room", u.room).with("posture", posture)
          .with("furniture", u.furniture);
      trace.record(std::move(r));
    }));
    home->start("127.0.0.1", bound);
    if (!home->manager().wait_registered(1, 30s)) {
      std::fprintf(stderr, "icars: the house's devices did not register: %s\n", home->manager().last_error().c_str());
      return 1;
    }
    clock = &home->clock();
    std::printf("[icars] %zu devices registered, %zu services\n", home->manager().devices().size(),
                sf.container().all().size());
  } else {
    own_clock = std::make_unique<sim::SimClock>(start);
    clock = own_clock.get();
    std::printf("[icars] waiting for device managers (icars-device-manager --server %s:%u)\n", host.c_str(), bound);
  }
  commands->set_clock(clock);
  device_clock = clock;
  struct ClockRelease {  // the clock goes before the server, whose io thread may still end calls
    CommandRecorder& commands;
    ~ClockRelease() { commands.set_clock(nullptr); }
  } release_clock{*commands};
  std::unique_ptr<ClockFollower> follower;
  if (own_clock) follower = std::make_unique<ClockFollower>(*own_clock, sf.container());
  ServiceObserver observer(sf.container(), trace, options.external);

  // --- Behaviors, tasks and the Coordinator. -------------------------------------------------------
  b::Runtime runtime(*clock);
  b::Environment env{runtime, sf.container(), trace};
  c::CollaborationManager manager(repository, registry, env);
  if (follower) {
    // Start once the simulation's time is known, so timers count from the house's clock.
    while (!follower->following()) {
      const timespec wait{0, 50'000'000};
      const int signal = sigtimedwait(&signals, nullptr, &wait);
      if (signal == SIGHUP) {
        reload_access(options, access_in_force, server, sf.registry(), trace, *clock, house_token);
      } else if (signal > 0) {
        return 0;
      }
    }
  }
  const auto started_at = clock->now();
  const auto wall_start = std::chrono::steady_clock::now();
  try {
    manager.run(options.policy);
  } catch (const c::PolicyError& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 2;
  }

  bool interrupted = false;
  while (clock->now() < stop_at) {
    const timespec wait{0, 20'000'000};
    const int signal = sigtimedwait(&signals, nullptr, &wait);
    if (signal == SIGHUP) {
      reload_access(options, access_in_force, server, sf.registry(), trace, *clock, house_token);
    } else if (signal > 0) {
      interrupted = true;
      break;
    }
  }
  const auto ended_at = clock->now();
  manager.stop();
  runtime.drain(5s);
  // The run is over: the house's devices going away with it are no outage to report.
  sf.container().remove_device_watcher(device_watch);
  spdlog::set_level(spdlog::level::err);
  if (home) {
    for (const auto id : world_listeners) home->world().remove_listener(id);
  }
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();

  summary.print(policy_name, started_at, ended_at, wall, options.speed);
  if (interrupted) std::printf("(interrupted)\n");
  if (!options.plot_file.empty()) {
    try {
      sim::write_svg(options.plot_file, house, summary.plot(fmt::format("{} on {}", policy_name, house.name), house));
      std::printf("plot: %s\n", options.plot_file.c_str());
    } catch (const std::exception& e) {
      std::fprintf(stderr, "icars: %s\n", e.what());
      return 1;
    }
  }
  if (!options.trace_file.empty()) std::printf("trace: %s\n", options.trace_file.c_str());
  return 0;
}

}  // namespace icars::app
