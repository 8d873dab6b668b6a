#include "icars/coros/knowledge.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

namespace icars::coros {

AgentState AgentState::from_hello(const HelloMessage& hello, Clock::time_point heard) {
  AgentState s;
  s.id = hello.id;
  s.ip = hello.ip;
  s.role = hello.role;
  s.status = hello.status;
  s.port = static_cast<std::uint16_t>(std::clamp(hello.port, 0, 65535));
  s.timestamp = hello.timestamp;
  s.x = hello.x;
  s.y = hello.y;
  s.load = hello.load;
  s.last_heard = heard;
  return s;
}

namespace {
constexpr std::array<std::string_view, 7> kStageNames = {
    "announced", "assigned", "to_pickup", "picked_up", "to_dropoff", "delivered", "failed"};
}

std::string_view to_string(TaskStage stage) {
  return kStageNames.at(static_cast<std::size_t>(stage));
}

std::optional<TaskStage> parse_task_stage(std::string_view text) {
  for (std::size_t i = 0; i < kStageNames.size(); ++i) {
    if (kStageNames[i] == text) return static_cast<TaskStage>(i);
  }
  return std::nullopt;
}

TaskState TaskState::from_status(const TaskStatusMessage& m, const std::string& sender) {
  const auto stage = parse_task_stage(m.state);
  if (!stage) throw CorosError("TASK_STATUS with unknown state '" + m.state + "' from " + sender);
  TaskState s;
  s.id = m.task_id;
  s.auctioneer = m.auctioneer;
  s.robot = m.robot;
  s.round = m.round;
  s.stage = *stage;
  s.distance = m.distance;
  s.updated = Clock::now();
  return s;
}

// --- AgentConfiguration --------------------------------------------------------------------

namespace {

using nlohmann::json;

class ConfigReader {
 public:
  explicit ConfigReader(std::string source) : source_(std::move(source)) {}

  [[noreturn]] void fail(const std::string& what) const {
    throw CorosError(fmt::format("{}: {}", source_, what));
  }

  // Rejects keys nobody reads, so a misspelt setting is an error, not silently ignored.
  void only(const json& object, const std::string& where, std::set<std::string> keys) const {
    if (!object.is_object()) fail(fmt::format("{} must be an object", where));
    for (const auto& [key, value] : object.items()) {
      if (!keys.contains(key)) {
        std::string known;
        for (const auto& k : keys) known += (known.empty() ? "" : ", ") + k;
        fail(fmt::format("unknown setting '{}' in {} (known: {})", key, where, known));
      }
    }
  }

  std::string string(const json& o, const char* key, const std::string& fallback) const {
    if (!o.contains(key)) return fallback;
    if (!o[key].is_string()) fail(fmt::format("'{}' must be a string", key));
    return o[key].get<std::string>();
  }
  double number(const json& o, const char* key, double fallback, double min, double max) const {
    if (!o.contains(key)) return fallback;
    if (!o[key].is_number()) fail(fmt::format("'{}' must be a number", key));
    const double v = o[key].get<double>();
    if (!(v >= min && v <= max)) fail(fmt::format("'{}' = {} is outside {}..{}", key, v, min, max));
    return v;
  }
  std::chrono::milliseconds millis(const json& o, const char* key,
                                   std::chrono::milliseconds fallback, double min = 1) const {
    return std::chrono::milliseconds(static_cast<std::int64_t>(
        number(o, key, static_cast<double>(fallback.count()), min, 3.6e6)));
  }
  bool boolean(const json& o, const char* key, bool fallback) const {
    if (!o.contains(key)) return fallback;
    if (!o[key].is_boolean()) fail(fmt::format("'{}' must be true or false", key));
    return o[key].get<bool>();
  }

 private:
  std::string source_;
};

}  // namespace

AgentConfiguration AgentConfiguration::parse(const std::string& text,
                                             const std::filesystem::path& base_dir,
                                             const std::string& source_name) {
  json root;
  try {
    root = json::parse(text);
  } catch (const json::parse_error& e) {
    throw CorosError(fmt::format("{}: not valid JSON: {}", source_name, e.what()));
  }
  ConfigReader in(source_name);
  in.only(root, "the configuration",
          {"id", "role", "ip", "port", "broadcast", "hello_period_ms", "neighbor_expiry_ms",
           "bid_window_ms", "retry_period_ms", "max_retries", "map", "field_cache", "robot",
           "track_file", "user", "faults", "key", "key_file", "insecure"});
  AgentConfiguration c;
  c.id = in.string(root, "id", "");
  if (c.id.empty() || c.id.size() > 255)
    in.fail("'id' must be a non-empty string of up to 255 bytes");
  c.role = in.string(root, "role", "robot");
  if (c.role != "robot" && c.role != "user" && c.role != "monitor") {
    in.fail(fmt::format("'role' is '{}', expected robot, user or monitor", c.role));
  }
  c.transport.ip = in.string(root, "ip", c.transport.ip);
  c.transport.port = static_cast<std::uint16_t>(in.number(root, "port", 0, 0, 65535));
  if (root.contains("broadcast")) {
    const json& b = root["broadcast"];
    in.only(b, "'broadcast'", {"address", "port"});
    c.transport.broadcast_address = in.string(b, "address", c.transport.broadcast_address);
    c.transport.broadcast_port =
        static_cast<std::uint16_t>(in.number(b, "port", c.transport.broadcast_port, 1, 65535));
  }
  c.hello_period = in.millis(root, "hello_period_ms", c.hello_period);
  c.neighbor_expiry = in.millis(root, "neighbor_expiry_ms", c.neighbor_expiry);
  if (c.neighbor_expiry <= c.hello_period) {
    in.fail("'neighbor_expiry_ms' must be longer than 'hello_period_ms'");
  }
  c.bid_window = in.millis(root, "bid_window_ms", c.bid_window);
  c.retry_period = in.millis(root, "retry_period_ms", c.retry_period);
  c.max_retries = static_cast<int>(in.number(root, "max_retries", c.max_retries, 1, 100000));
  const std::string map = in.string(root, "map", "");
  if (!map.empty()) {
    c.map = std::filesystem::path(map).is_absolute() ? std::filesystem::path(map) : base_dir / map;
  }
  if (const std::string cache = in.string(root, "field_cache", ""); !cache.empty()) {
    const std::filesystem::path p(cache);
    c.field_cache = p.is_absolute() ? p : base_dir / p;
  }
  if (root.contains("robot")) {
    const json& r = root["robot"];
    in.only(r, "'robot'", {"start", "speed", "radius", "speedup", "kind", "ros_namespace"});
    c.start = in.string(r, "start", "");
    c.speed = in.number(r, "speed", c.speed, 0.01, 20);
    c.radius = in.number(r, "radius", c.radius, 0.01, 5);
    c.speedup = in.number(r, "speedup", c.speedup, 0.1, 10000);
    c.robot_kind = in.string(r, "kind", c.robot_kind);
    if (c.robot_kind != "sim" && c.robot_kind != "ros") {
      in.fail(fmt::format("robot 'kind' is '{}', expected sim or ros", c.robot_kind));
    }
    c.ros_namespace = in.string(r, "ros_namespace", "");
  }
  c.track_file = in.string(root, "track_file", "");
  if (root.contains("user")) {
    const json& u = root["user"];
    in.only(u, "'user'",
            {"deliveries", "expect_robots", "start_after_ms", "delivery_interval_ms",
             "exit_when_done"});
    if (u.contains("deliveries")) {
      const json& d = u["deliveries"];
      if (!d.is_array()) in.fail("'deliveries' must be a list of [pickup, dropoff] pairs");
      for (const json& pair : d) {
        if (!pair.is_array() || pair.size() != 2 || !pair[0].is_string() || !pair[1].is_string()) {
          in.fail(fmt::format("delivery {} must be [pickup, dropoff]", pair.dump()));
        }
        c.deliveries.emplace_back(pair[0].get<std::string>(), pair[1].get<std::string>());
      }
    }
    c.expect_robots = static_cast<int>(in.number(u, "expect_robots", 0, 0, 100000));
    c.start_after = in.millis(u, "start_after_ms", c.start_after, 0);
    c.delivery_interval = in.millis(u, "delivery_interval_ms", c.delivery_interval, 0);
    c.exit_when_done = in.boolean(u, "exit_when_done", c.exit_when_done);
  }
  if (root.contains("faults")) {
    try {
      c.transport.faults = FaultInjection::parse(in.string(root, "faults", ""));
    } catch (const CorosError& e) {
      in.fail(e.what());
    }
  }
  if (c.role == "robot" && c.map.empty()) in.fail("a robot needs a 'map'");
  if (c.role == "user" && c.map.empty()) in.fail("a user needs a 'map' to place deliveries");
  // The fleet key, or an explicit 'insecure'. The key is read now, so an unusable key file is a
  // configuration error naming the file.
  const std::string key_hex = in.string(root, "key", "");
  const std::string key_file = in.string(root, "key_file", "");
  c.transport.insecure = in.boolean(root, "insecure", false);
  if (!key_hex.empty() && !key_file.empty()) in.fail("set 'key' or 'key_file', not both");
  if (c.transport.insecure && (!key_hex.empty() || !key_file.empty())) {
    in.fail("'insecure' is true but a fleet key is set too: remove one of them");
  }
  try {
    if (!key_hex.empty()) c.transport.key = FleetKey::from_hex(key_hex);
  } catch (const CorosError& e) {
    in.fail(fmt::format("'key': {}", e.what()));
  }
  if (!key_file.empty()) {
    const std::filesystem::path p(key_file);
    try {
      c.transport.key = FleetKey::load(p.is_absolute() ? p : base_dir / p);
    } catch (const CorosError& e) {
      in.fail(fmt::format("'key_file': {}", e.what()));
    }
  }
  if (!c.transport.key && !c.transport.insecure) {
    in.fail(
        "no fleet key: set 'key_file' to a file holding the fleet's shared key as hex (make it "
        "once with `openssl rand -hex 32 > fleet.key; chmod 600 fleet.key` and give every agent "
        "of the fleet the same file), or 'key' to the hex itself, or 'insecure': true to run "
        "without message authentication");
  }
  return c;
}

nlohmann::json AgentConfiguration::to_json() const {
  const AgentConfiguration defaults;
  json out;
  out["id"] = id;
  out["role"] = role;
  out["ip"] = transport.ip;
  out["port"] = transport.port;
  out["broadcast"] = {{"address", transport.broadcast_address}, {"port", transport.broadcast_port}};
  out["hello_period_ms"] = hello_period.count();
  out["neighbor_expiry_ms"] = neighbor_expiry.count();
  out["bid_window_ms"] = bid_window.count();
  out["retry_period_ms"] = retry_period.count();
  out["max_retries"] = max_retries;
  if (!map.empty()) out["map"] = map.string();
  if (!field_cache.empty()) out["field_cache"] = field_cache.string();
  const bool robot_set = start != defaults.start || speed != defaults.speed ||
                         radius != defaults.radius || speedup != defaults.speedup ||
                         robot_kind != defaults.robot_kind ||
                         ros_namespace != defaults.ros_namespace;
  if (role == "robot" || robot_set) {
    json robot = {{"start", start},
                  {"speed", speed},
                  {"radius", radius},
                  {"speedup", speedup},
                  {"kind", robot_kind}};
    if (!ros_namespace.empty()) robot["ros_namespace"] = ros_namespace;
    out["robot"] = std::move(robot);
  }
  if (!track_file.empty()) out["track_file"] = track_file.string();
  const bool user_set = !deliveries.empty() || expect_robots != defaults.expect_robots ||
                        start_after != defaults.start_after ||
                        delivery_interval != defaults.delivery_interval ||
                        exit_when_done != defaults.exit_when_done;
  if (role == "user" || user_set) {
    json list = json::array();
    for (const auto& [pickup, dropoff] : deliveries) list.push_back(json::array({pickup, dropoff}));
    out["user"] = {{"deliveries", std::move(list)},
                   {"expect_robots", expect_robots},
                   {"start_after_ms", start_after.count()},
                   {"delivery_interval_ms", delivery_interval.count()},
                   {"exit_when_done", exit_when_done}};
  }
  if (transport.faults != FaultInjection{}) out["faults"] = transport.faults.spec();
  if (transport.key) out["key"] = transport.key->to_hex();
  if (transport.insecure) out["insecure"] = true;
  return out;
}

AgentConfiguration AgentConfiguration::load(const std::filesystem::path& file) {
  std::ifstream in(file);
  if (!in) throw CorosError(fmt::format("{}: cannot read the file", file.string()));
  std::stringstream text;
  text << in.rdbuf();
  return parse(text.str(), file.parent_path(), file.string());
}

// --- NeighborMonitor -----------------------------------------------------------------------

bool NeighborMonitor::update(const AgentState& state) {
  auto it = table_.find(state.id);
  if (it == table_.end()) {
    const AgentState& added = table_.emplace(state.id, state).first->second;
    for (const auto& l : listeners_) l(added, true);
    return true;
  }
  if (state.timestamp >= it->second.timestamp) {
    it->second = state;
  } else {
    it->second.last_heard = std::max(it->second.last_heard, state.last_heard);  // reordered HELLO
  }
  return false;
}

std::vector<AgentState> NeighborMonitor::expire(Clock::time_point now) {
  std::vector<AgentState> gone;
  for (auto it = table_.begin(); it != table_.end();) {
    if (now - it->second.last_heard > expiry_) {
      gone.push_back(it->second);
      it = table_.erase(it);
    } else {
      ++it;
    }
  }
  for (const auto& g : gone) {
    for (const auto& l : listeners_) l(g, false);
  }
  return gone;
}

const AgentState* NeighborMonitor::find(const std::string& id) const {
  const auto it = table_.find(id);
  return it == table_.end() ? nullptr : &it->second;
}

std::vector<AgentState> NeighborMonitor::neighbors() const {
  std::vector<AgentState> out;
  for (const auto& [id, s] : table_) out.push_back(s);
  return out;
}

std::vector<AgentState> NeighborMonitor::neighbors_with_role(const std::string& role) const {
  std::vector<AgentState> out;
  for (const auto& [id, s] : table_) {
    if (s.role == role) out.push_back(s);
  }
  return out;
}

// --- TaskMonitor ---------------------------------------------------------------------------

bool TaskMonitor::update(const TaskState& state) {
  auto it = table_.find(state.id);
  if (it != table_.end()) {
    const TaskState& old = it->second;
    const bool newer =
        state.round > old.round || (state.round == old.round && state.stage > old.stage) ||
        (state.round == old.round && state.stage == old.stage && state.distance > old.distance);
    if (!newer) return false;
    it->second = state;
  } else {
    it = table_.emplace(state.id, state).first;
  }
  for (const auto& l : listeners_) l(it->second);
  return true;
}

const TaskState* TaskMonitor::find(const std::string& id) const {
  const auto it = table_.find(id);
  return it == table_.end() ? nullptr : &it->second;
}

std::vector<TaskState> TaskMonitor::tasks() const {
  std::vector<TaskState> out;
  for (const auto& [id, s] : table_) out.push_back(s);
  return out;
}

}  // namespace icars::coros
