#include "icars/home/mqtt/home_assistant.h"

#include <fmt/format.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <condition_variable>
#include <deque>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <set>
#include <stdexcept>
#include <thread>

#include "icars/clock/time.h"
#include "icars/home/mqtt/entity_devices.h"

namespace icars::home::mqtt {

namespace bm = icars::bridge::mqtt;
using nlohmann::json;

namespace {

constexpr std::size_t kMaxState = 255;  // Home Assistant keeps at most this much of a state

// "TimeToSleep" → "Time to sleep", "come_to_me" → "Come to me".
std::string label_of(std::string_view event) {
  std::string out;
  for (std::size_t i = 0; i < event.size(); ++i) {
    const char c = event[i];
    if (c == '_' || c == '-') {
      out += ' ';
      continue;
    }
    if (i > 0 && std::isupper(static_cast<unsigned char>(c)) && !out.empty() && out.back() != ' ') out += ' ';
    out += out.empty() ? static_cast<char>(std::toupper(static_cast<unsigned char>(c)))
                       : static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  }
  return out;
}

std::string clip(std::string s) {
  if (s.size() > kMaxState) s.resize(kMaxState);
  return s;
}

struct Robot {
  bool known = false;
  double x = 0, y = 0;
  bool moving = false;
  std::string target;  // where its last go_to leads
  std::string room;
};

// What an operator asked for over MQTT, run on the publisher's thread.
struct Command {
  enum class Kind { run_policy, raise } kind;
  std::string value;
  std::string topic;
};

}  // namespace

struct HomeAssistantPublisher::State {
  State(server::MediatingServer& s, HomeAssistantOptions o) : server(s), options(std::move(o)) {}

  server::MediatingServer& server;
  HomeAssistantOptions options;
  std::string base;
  std::shared_ptr<spdlog::logger> log;
  std::unique_ptr<bm::Client> client;
  std::map<std::string, std::string> carrier_of;  // device → robot
  std::atomic<std::uint64_t> published{0};

  std::mutex mutex;
  std::condition_variable changed;
  // What the trace told, under mutex.
  std::vector<std::string> configuration;  // active states, in the order entered
  std::vector<std::string> tasks;
  std::string last_transition;
  std::string time;  // of the last change, as the trace writes it
  std::string error = "none";
  std::map<std::string, Robot> robots;
  std::map<std::string, std::map<std::string, std::string>> device_state;  // device → what → value
  // What has to be published, under mutex.
  bool all_dirty = false;  // a new connection: everything
  bool policy_dirty = false;
  bool state_dirty = false;
  bool robots_dirty = false;
  std::set<std::string> devices_dirty;
  std::deque<Command> commands;
  bool running = false;
  bool stopping = false;
  std::set<std::string> problems_seen;
  std::vector<std::string> problems;
  // Only on the worker thread (and in stop(), after it ended).
  std::set<std::string> configs;       // config topics published (retained)
  std::set<std::string> states;        // state topics published (retained)
  std::vector<std::string> buttons;    // the events with a button now
  std::thread worker;

  void problem(const std::string& what) {
    {
      std::lock_guard lock(mutex);
      if (problems_seen.size() >= 1024 || !problems_seen.insert(what).second) return;
      problems.push_back(what);
    }
    log->warn("{}", what);
  }

  // --- The trace, under the trace's lock: only the snapshot changes here. ---------------------

  void on_record(const behavior::TraceRecord& r) {
    std::lock_guard lock(mutex);
    if (r.kind == "policy") {
      configuration.clear();
      tasks.clear();
      policy_dirty = state_dirty = true;
    } else if (r.kind == "state") {
      const auto state = r.field("state");
      std::erase(configuration, state);
      if (r.field("event") == "enter") configuration.push_back(state);
      state_dirty = true;
    } else if (r.kind == "task") {
      const auto task = r.field("task");
      std::erase(tasks, task);
      if (r.field("event") == "start") tasks.push_back(task);
      state_dirty = true;
    } else if (r.kind == "transition") {
      last_transition = r.text;
      state_dirty = true;
    } else if (r.kind == "robot") {
      auto& robot = robots[r.field("robot")];
      robot.known = true;
      robot.x = r.number("x").value_or(robot.x);
      robot.y = r.number("y").value_or(robot.y);
      robot.moving = r.flag("moving").value_or(false);
      if (options.room_at) robot.room = options.room_at(robot.x, robot.y);
      robots_dirty = true;
    } else if (r.kind == "effect") {
      const auto device = r.field("device");
      const auto what = r.field("what");
      const auto value = r.field("value");
      auto& fields = device_state[device];
      if (what == "stopped") {
        fields["playing"] = "";
      } else {
        fields[what] = value;
      }
      fields["last"] = value.empty() ? what : what + " " + value;
      if (const auto robot = carrier_of.find(device); robot != carrier_of.end()) {
        auto& rb = robots[robot->second];
        if (what == "going_to" || what == "heading") rb.target = value;
        if (what == "halted") rb.target.clear();
        robots_dirty = true;
      }
      devices_dirty.insert(device);
    } else {
      return;
    }
    time = format_time(r.time);
    changed.notify_one();
  }

  // --- Commands, on the MQTT client's thread: queued for the worker. ----------------------------

  void on_message(const bm::Message& m) {
    if (m.retained) return;  // a command is meant now, not replayed from an earlier run
    Command c;
    if (m.topic == topic("policy/set")) {
      c = Command{Command::Kind::run_policy, m.payload, m.topic};
    } else if (m.topic.starts_with(topic("event/"))) {
      c = Command{Command::Kind::raise, m.topic.substr(topic("event/").size()), m.topic};
    } else {
      return;
    }
    std::lock_guard lock(mutex);
    if (commands.size() >= 64) {
      problems.push_back(m.topic + ": more than 64 commands waiting; this one is refused");
      return;
    }
    commands.push_back(std::move(c));
    changed.notify_one();
  }

  std::string topic(const std::string& path) const { return base + "/" + path; }
  std::string availability() const { return topic("availability"); }

  // --- The worker: runs commands and publishes. -------------------------------------------------

  void run() {
    auto last_positions = std::chrono::steady_clock::time_point{};
    for (;;) {
      std::deque<Command> todo;
      bool all = false, policy = false, state = false, positions = false;
      std::set<std::string> devices;
      {
        std::unique_lock lock(mutex);
        changed.wait_for(lock, options.position_interval, [&] {
          return stopping || all_dirty || policy_dirty || state_dirty || !devices_dirty.empty() || !commands.empty();
        });
        if (stopping) return;
        todo.swap(commands);
        all = std::exchange(all_dirty, false);
        policy = std::exchange(policy_dirty, false) || all;
        state = std::exchange(state_dirty, false) || all;
        devices.swap(devices_dirty);
        const auto now = std::chrono::steady_clock::now();
        if (all || (robots_dirty && now - last_positions >= options.position_interval)) {
          positions = true;
          robots_dirty = false;
          last_positions = now;
        }
      }
      for (const auto& c : todo) execute(c);
      try {
        if (all) publish_fixed();
        if (policy) publish_policy();
        if (state) publish_state();
        if (positions) publish_robots();
        if (all) {
          for (const auto& d : options.devices) publish_device(d.id);
        } else {
          for (const auto& d : devices) publish_device(d);
        }
      } catch (const bm::Error& e) {
        // The broker went away: everything is published again on the next connection.
        log->warn("Home Assistant view not published: {}", e.what());
      }
    }
  }

  void execute(const Command& c) {
    if (c.kind == Command::Kind::run_policy) {
      std::string outcome = "none";
      try {
        server.run_policy(c.value);
        log->info("{}: policy {} runs", c.topic, c.value);
      } catch (const std::exception& e) {
        outcome = clip(fmt::format("{} not run, {} keeps running: {}", c.value, server.policy_name(), e.what()));
        log->warn("{}: {}", c.topic, outcome);
      }
      std::lock_guard lock(mutex);
      error = outcome;
      policy_dirty = state_dirty = true;
      return;
    }
    const auto events = server.policy_events();
    if (std::find(events.begin(), events.end(), c.value) == events.end()) {
      problem(fmt::format("{}: the running policy waits for no event '{}'; nothing raised", c.topic, c.value));
      return;
    }
    if (!server.raise(behavior::Event(c.value))) {
      problem(fmt::format("{}: no policy runs; '{}' not raised", c.topic, c.value));
      return;
    }
    log->info("{}: {} raised", c.topic, c.value);
  }

  void send(const std::string& t, const std::string& payload, bool retain = true) {
    client->publish(t, payload, retain);
    ++published;
  }

  void publish_config(const std::string& component, const std::string& key, const std::string& name, json config) {
    config["unique_id"] = options.node_id + "_" + key;
    config["object_id"] = options.node_id + "_" + key;
    config["name"] = name;
    config["availability_topic"] = availability();
    config["device"] = {{"identifiers", json::array({options.node_id})},
                        {"name", options.name},
                        {"manufacturer", "ICARS"},
                        {"model", "robotic mediator"}};
    const auto t = fmt::format("{}/{}/{}/{}/config", options.discovery_prefix, component, options.node_id, key);
    send(t, config.dump());
    configs.insert(t);
  }

  void publish_retained_state(const std::string& t, const std::string& payload) {
    send(t, payload);
    states.insert(t);
  }

  // What does not change with the policy: the availability, the state sensors, the robots and
  // the devices.
  void publish_fixed() {
    send(availability(), "online");
    publish_config("sensor", "state", "State",
                   {{"state_topic", topic("policy/state")},
                    {"json_attributes_topic", topic("policy/attributes")},
                    {"icon", "mdi:state-machine"}});
    publish_config("sensor", "task", "Task", {{"state_topic", topic("policy/task")}, {"icon", "mdi:robot"}});
    publish_config("sensor", "policy_error", "Policy error",
                   {{"state_topic", topic("policy/error")}, {"icon", "mdi:alert-circle-outline"}});
    for (const auto& r : options.robots) {
      const auto& robot = r.id;
      const auto key = name_of(robot);
      const auto state = topic("robot/" + key);
      publish_config("sensor", key + "_room", robot + " room",
                     {{"state_topic", state}, {"value_template", "{{ value_json.room }}"},
                      {"json_attributes_topic", state}, {"icon", "mdi:map-marker"}});
      publish_config("sensor", key + "_activity", robot + " activity",
                     {{"state_topic", state}, {"value_template", "{{ value_json.activity }}"},
                      {"icon", "mdi:robot-vacuum"}});
    }
    for (const auto& d : options.devices) {
      const auto key = "device_" + name_of(d.id);
      const auto state = topic("device/" + name_of(d.id));
      publish_config("sensor", key, d.id,
                     {{"state_topic", state}, {"value_template", "{{ value_json.state }}"},
                      {"json_attributes_topic", state}});
    }
  }

  // The select (its options: the repository's policies) and one button per event.
  void publish_policy() {
    const auto name = server.policy_name();
    auto names = server.policies().names();
    if (!name.empty() && std::find(names.begin(), names.end(), name) == names.end()) names.push_back(name);
    if (names.empty()) names.push_back("none");
    publish_config("select", "policy", "Policy",
                   {{"command_topic", topic("policy/set")},
                    {"state_topic", topic("policy/name")},
                    {"options", names},
                    {"icon", "mdi:file-tree"}});
    publish_retained_state(topic("policy/name"), name.empty() ? names.front() : name);
    const auto events = server.policy_events();
    for (const auto& gone : buttons) {
      if (std::find(events.begin(), events.end(), gone) != events.end()) continue;
      const auto t = fmt::format("{}/button/{}/event_{}/config", options.discovery_prefix, options.node_id, name_of(gone));
      send(t, "");
      configs.erase(t);
    }
    for (const auto& event : events) {
      publish_config("button", "event_" + name_of(event), label_of(event),
                     {{"command_topic", topic("event/" + event)}, {"icon", "mdi:gesture-tap-button"}});
    }
    buttons = events;
  }

  void publish_state() {
    std::string state, tasks_text, error_text;
    json attributes;
    {
      std::lock_guard lock(mutex);
      state = configuration.empty() ? "none" : configuration.back();
      std::string joined;
      for (const auto& t : tasks) joined += (joined.empty() ? "" : ", ") + t;
      tasks_text = joined.empty() ? "none" : joined;
      attributes = {{"configuration", configuration}, {"tasks", tasks}, {"last_transition", last_transition},
                    {"time", time}};
      error_text = error;
    }
    publish_retained_state(topic("policy/state"), clip(state));
    publish_retained_state(topic("policy/attributes"), attributes.dump());
    publish_retained_state(topic("policy/task"), clip(tasks_text));
    publish_retained_state(topic("policy/error"), clip(error_text));
  }

  void publish_robots() {
    std::vector<std::pair<std::string, json>> out;
    {
      std::lock_guard lock(mutex);
      for (const auto& robot : options.robots) {
        const auto& name = robot.id;
        const auto it = robots.find(name);
        const Robot r = it == robots.end() ? Robot{} : it->second;
        std::string activity = "unknown";
        if (r.known) {
          if (r.moving) {
            activity = r.target.empty() ? "moving" : "going to " + r.target;
          } else {
            activity = r.room.empty() ? "standing" : "standing in the " + r.room;
          }
        }
        json j = {{"room", r.room.empty() ? "unknown" : r.room}, {"activity", activity}, {"moving", r.moving}};
        if (r.known) {
          j["x"] = std::round(r.x * 100) / 100;
          j["y"] = std::round(r.y * 100) / 100;
        }
        out.emplace_back(name, std::move(j));
      }
    }
    for (const auto& [name, j] : out) publish_retained_state(topic("robot/" + name_of(name)), j.dump());
  }

  void publish_device(const std::string& id) {
    if (std::none_of(options.devices.begin(), options.devices.end(), [&](const auto& d) { return d.id == id; })) return;
    json j = json::object();
    {
      std::lock_guard lock(mutex);
      const auto it = device_state.find(id);
      if (it != device_state.end()) {
        for (const auto& [what, value] : it->second) j[what] = value;
      }
    }
    // The state shown: on/off for what has a power, the track for a speaker, else what it did last.
    if (j.contains("power")) {
      j["state"] = j["power"];
    } else if (j.contains("playing")) {
      j["state"] = j["playing"].get<std::string>().empty() ? "silent" : "playing " + j["playing"].get<std::string>();
    } else {
      j["state"] = j.contains("last") ? j["last"] : json("idle");
    }
    j["state"] = clip(j["state"].get<std::string>());
    publish_retained_state(topic("device/" + name_of(id)), j.dump());
  }
};

HomeAssistantPublisher::HomeAssistantPublisher(server::MediatingServer& server, bm::ClientOptions broker,
                                               HomeAssistantOptions options)
    : state_(std::make_shared<State>(server, std::move(options))) {
  auto& s = *state_;
  if (s.options.node_id.empty() || name_of(s.options.node_id) != s.options.node_id) {
    throw std::invalid_argument("Home Assistant node id '" + s.options.node_id +
                                "' is not a name of letters, digits, '_' and '-'");
  }
  s.base = s.options.base_topic + "/" + s.options.node_id;
  s.log = s.options.logger ? s.options.logger
                           : std::make_shared<spdlog::logger>(
                                 "home-assistant", std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
  for (const auto& d : s.options.devices) {
    if (!d.carrier.empty()) s.carrier_of[d.id] = d.carrier;
  }
  for (const auto& r : s.options.robots) {
    auto& robot = s.robots[r.id];
    robot.known = true;
    robot.x = r.x;
    robot.y = r.y;
    if (s.options.room_at) robot.room = s.options.room_at(r.x, r.y);
  }
  if (broker.client_id.empty()) broker.client_id = "icars-home-assistant-" + s.options.node_id;
  broker.will = bm::Will{s.availability(), "offline", true};
  s.client = std::make_unique<bm::Client>(broker);
  const std::weak_ptr<State> weak = state_;
  s.client->on_message([weak](const bm::Message& m) {
    if (auto self = weak.lock()) self->on_message(m);
  });
  s.client->on_connection([weak](bool connected, const std::string&) {
    auto self = weak.lock();
    if (!self || !connected) return;
    std::lock_guard lock(self->mutex);
    self->all_dirty = true;
    self->changed.notify_one();
  });
  s.client->subscribe(s.topic("policy/set"));
  s.client->subscribe(s.topic("event/+"));
  server.trace().add_sink([weak](const behavior::TraceRecord& r) {
    if (auto self = weak.lock()) self->on_record(r);
  });
}

HomeAssistantPublisher::~HomeAssistantPublisher() { stop(); }

void HomeAssistantPublisher::start(std::chrono::milliseconds timeout) {
  auto& s = *state_;
  {
    std::lock_guard lock(s.mutex);
    if (s.running) return;
    s.running = true;
  }
  s.client->start();
  if (!s.client->wait_connected(timeout)) {
    const auto why = s.client->last_error();
    s.client->stop();
    throw bm::Error(fmt::format("Home Assistant: no connection to the MQTT broker: {}", why.empty() ? "no answer" : why));
  }
  s.worker = std::thread([&s] { s.run(); });
}

void HomeAssistantPublisher::stop() {
  auto& s = *state_;
  {
    std::lock_guard lock(s.mutex);
    if (!s.running) return;
    s.running = false;
    s.stopping = true;
    s.changed.notify_one();
  }
  if (s.worker.joinable()) s.worker.join();
  // Home Assistant forgets the entities: every config and state removed, then offline.
  try {
    for (const auto& t : s.configs) s.send(t, "");
    for (const auto& t : s.states) s.send(t, "");
    s.send(s.availability(), "offline");
    s.client->drain(std::chrono::seconds(5));
  } catch (const bm::Error& e) {
    s.log->warn("Home Assistant's entities not removed: {}", e.what());
  }
  s.configs.clear();
  s.states.clear();
  s.client->stop();
}

std::string HomeAssistantPublisher::availability_topic() const { return state_->availability(); }
std::string HomeAssistantPublisher::topic(const std::string& path) const { return state_->topic(path); }
std::uint64_t HomeAssistantPublisher::published() const { return state_->published.load(); }
std::vector<std::string> HomeAssistantPublisher::problems() const {
  std::lock_guard lock(state_->mutex);
  return state_->problems;
}

}  // namespace icars::home::mqtt
