// The COROS knowledge base (COROS 4.2, Knowledge Base Manipulation Layer): what an agent knows
// about itself, its neighbours and the tasks of the fleet.
//
//   AgentState          one agent as last heard of (from its HELLO)
//   TaskState           one task as last heard of (auctioned, assigned, picked up, ...)
//   AgentConfiguration  the agent's own settings, read from and written as JSON (docs/coros.md)
//   NeighborMonitor     the neighbour table: agents heard from within the expiry time
//   TaskMonitor         the task table: the newest state of every task heard of
//
// The monitors are plain objects used from the agent's io_context; they do not lock.
#pragma once

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "icars/coros/messages.h"
#include "icars/coros/transport.h"

namespace icars::coros {

using Clock = std::chrono::steady_clock;

struct AgentState {
  std::string id, ip, role, status;
  std::uint16_t port = 0;
  double timestamp = 0;  // the agent's own clock in its last HELLO
  double x = 0, y = 0;
  int load = 0;
  Clock::time_point last_heard{};
  static AgentState from_hello(const HelloMessage& hello, Clock::time_point heard);
};

// The stages of a task, in order; a task only moves forward within a round.
enum class TaskStage { announced, assigned, to_pickup, picked_up, to_dropoff, delivered, failed };
std::string_view to_string(TaskStage stage);
std::optional<TaskStage> parse_task_stage(std::string_view text);

struct TaskState {
  std::string id, auctioneer, robot;  // robot: "" until assigned
  int round = 1;
  TaskStage stage = TaskStage::announced;
  Place pickup, dropoff;
  double cost = 0;      // the winning bid
  double distance = 0;  // metres driven so far
  Clock::time_point updated{};
  // A robot's TASK_STATUS as a task state; throws CorosError for an unknown stage.
  static TaskState from_status(const TaskStatusMessage& status, const std::string& sender);
};

struct AgentConfiguration {
  std::string id;
  std::string role = "robot";  // robot, user or monitor
  TransportOptions transport;
  std::chrono::milliseconds hello_period{200};
  std::chrono::milliseconds neighbor_expiry{1000};  // no HELLO for this long: gone
  std::chrono::milliseconds bid_window{400};
  std::chrono::milliseconds retry_period{100};  // resend awards and results until acknowledged
  int max_retries = 20;
  std::filesystem::path map;  // the house/office map (sim house XML)
  // A directory where the agents of one host share the map's distance fields (FieldCache), so
  // each is computed once per host rather than once per agent; "" for none.
  std::filesystem::path field_cache;
  // Robots: where they start (a waypoint or place name on the map, or "x,y"), their speed,
  // and how much faster than real time their simulated motion runs.
  std::string start;
  double speed = 0.5;
  double radius = 0.25;
  double speedup = 10.0;
  std::string robot_kind = "sim";  // sim or ros
  std::string ros_namespace;       // ros robots: topics under /<ns>/ (default: the id)
  // Users: deliveries to auction, "pickup>dropoff", started once `expect_robots` robots are
  // neighbours (or after `start_after`), one every `delivery_interval`.
  std::vector<std::pair<std::string, std::string>> deliveries;
  int expect_robots = 0;
  std::chrono::milliseconds start_after{3000};
  std::chrono::milliseconds delivery_interval{0};
  bool exit_when_done = true;
  std::filesystem::path track_file;  // robots: write the driven path here as JSON on exit

  // Reads a JSON configuration (docs/coros.md); a relative map, field cache or key file path is
  // relative to the file. The fleet key ('key_file' or 'key') is required unless 'insecure' is
  // true.
  // Throws CorosError "file: what was wrong" for unreadable, malformed or inconsistent files.
  static AgentConfiguration load(const std::filesystem::path& file);
  static AgentConfiguration parse(const std::string& json, const std::filesystem::path& base_dir,
                                  const std::string& source_name);
  // The inverse of parse(): every setting it reads, so parse(to_json().dump(), ...) gives this
  // configuration back. The map and track file are written as they are (a relative map is read
  // back relative to parse's base_dir), the fleet key as 'key' (hex), never as 'key_file', and
  // 'faults' only when they differ from none. The 'robot' section is written for robots and the
  // 'user' section for users; for another role a section only when it holds a value other than
  // the default (a monitor's robot.radius, say). Checks nothing: parse() does.
  nlohmann::json to_json() const;
};

class NeighborMonitor {
 public:
  using Listener = std::function<void(const AgentState&, bool joined)>;  // joined or left

  explicit NeighborMonitor(std::chrono::milliseconds expiry) : expiry_(expiry) {}

  // Records a HELLO; true when the agent is new (or came back after expiring). A HELLO older
  // than the one already recorded (reordered) updates nothing but last_heard.
  bool update(const AgentState& state);
  // Removes agents not heard from since now - expiry; returns them.
  std::vector<AgentState> expire(Clock::time_point now);
  void on_change(Listener listener) { listeners_.push_back(std::move(listener)); }

  const AgentState* find(const std::string& id) const;
  std::vector<AgentState> neighbors() const;  // by id
  std::vector<AgentState> neighbors_with_role(const std::string& role) const;
  std::size_t size() const { return table_.size(); }
  std::chrono::milliseconds expiry() const { return expiry_; }

 private:
  std::chrono::milliseconds expiry_;
  std::map<std::string, AgentState> table_;
  std::vector<Listener> listeners_;
};

class TaskMonitor {
 public:
  using Listener = std::function<void(const TaskState&)>;

  // Keeps the newest state: a higher round wins, and within a round a later stage. Returns
  // true when the table changed.
  bool update(const TaskState& state);
  void on_change(Listener listener) { listeners_.push_back(std::move(listener)); }
  const TaskState* find(const std::string& id) const;
  std::vector<TaskState> tasks() const;  // by id

 private:
  std::map<std::string, TaskState> table_;
  std::vector<Listener> listeners_;
};

}  // namespace icars::coros
