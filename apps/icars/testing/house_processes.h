// Test support for the end-to-end tests that run the smart home as separate processes (the soak
// and chaos tests): `icars run --external` and icars-device-manager children with their stderr
// in log files, the paper house's devices split over three device managers on one shared
// simulated clock, the moments when the users change what the occupancy sensors see, and the
// mediator's JSON trace read back into task runs and the behaviors and tasks that got stuck.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "child_process.h"
#include "icars/clock/time.h"
#include "icars/sim/house.h"

namespace icars_test {

namespace fs = std::filesystem;
using icars::Time;

// --- Logs and exit statuses ---------------------------------------------------------------

std::string read_file(const fs::path& path);  // "" when it cannot be read
std::string tail(const std::string& text, std::size_t lines = 30);
// Whether a log holds a sanitizer report (leak, memory error, undefined behavior).
bool sanitizer_report(const std::string& log);
std::string describe_status(int status);  // "exit status 0", "killed by signal 9"

// The value of environment variable `name`; nullopt when it is unset or empty.
std::optional<std::string> environment_variable(const char* name);

// A run's settings from <PREFIX>_SEED (default: random), _DAYS (7, at least `min_days`), _SPEED
// (3600 simulated seconds per wall-clock second, 1 to 20000), _KEEP (a directory for the
// artifacts) and the switch <PREFIX>_<toggle> ("0": off; default on). Throws
// std::invalid_argument naming the variable that is wrong.
struct RunSettings {
  int days = 7;
  double speed = 3600;
  std::uint64_t seed = 0;
  bool enabled = true;  // the toggle: kills, faults
  std::string keep;     // directory for the artifacts, or ""
};
RunSettings run_settings(const std::string& prefix, const std::string& toggle, int min_days,
                         const std::string& why_min_days = "");

// The environment for the children: ASAN_OPTIONS as inherited plus leak detection and a 16 MiB
// quarantine (ASan's default 256 MiB makes a busy process's RSS climb for hours: with 16 MiB it
// levels off within the first simulated day, and use-after-free is still detected).
std::vector<std::string> child_environment();

// A child process with its stderr in a log file and extra environment variables ("NAME=value");
// its stdout is read line by line. It inherits no other file descriptor of the test: a socket
// of the test's own (a fault proxy's) must close when the test closes it. Killed (SIGKILL) and
// reaped on destruction.
class Program {
 public:
  Program(fs::path log, const std::vector<std::string>& env, const std::vector<std::string>& argv);

  pid_t pid() const { return process_->pid(); }
  const fs::path& log() const { return log_; }
  std::string stderr_text() const { return read_file(log_); }
  // Lines printed so far (waiting at most ~2 ms for more; read_line needs 2 ms to poll at all).
  std::vector<std::string> lines();
  // True once the process has exited (a zombie, not yet reaped) or is gone; a stopped process
  // (SIGSTOP) has not exited.
  bool exited() const;
  void signal(int sig) const { process_->signal(sig); }
  void freeze() { process_->freeze(); }  // SIGSTOP, returning once it is stopped
  void thaw() const { process_->thaw(); }  // SIGCONT
  int wait() { return process_->wait(); }

 private:
  fs::path log_;
  std::unique_ptr<planet_test::ChildProcess> process_;
};

// What is wrong with how a process ended: not exit status 0 (with its stderr's tail), a sanitizer
// report in its stderr. Empty when it ended well.
std::vector<std::string> exit_problems(const std::string& who, int status, const std::string& log);

// The directory for a run's logs and records: `keep`, or else <test temp dir>/<name>_<pid>.
fs::path run_directory(const std::string& keep, const std::string& name);

// `icars run POLICY --world HOUSE --external` on 127.0.0.1, quiet, tracing to `trace`, stopping by
// itself at 18:00 of day `days` (the paper house starts at 18:00).
std::vector<std::string> mediator_command(const std::string& icars, const std::string& policy,
                                          const std::string& house, double speed, int days, const fs::path& trace);

// Starts `icars run` (argv without the program) and waits up to 60 s for the port its
// mediating server listens on, collecting its stdout in `output`. Returns "" when it exited or
// never said.
std::string start_mediator(Program& server, std::vector<std::string>& output);

// --- The house on a shared clock --------------------------------------------------------------

// Every device manager maps the wall clock to simulated time from the same --epoch (the wall
// time, in ms since 1970, at which the house is at its start time), so a manager restarted at
// any time resumes where the others are.
struct SharedClock {
  Time start{0};
  std::int64_t epoch_ms = 0;
  double speed = 1;
  static std::int64_t wall_ms();
  Time now() const;
  // Wall time for `simulated` of simulated time.
  std::chrono::milliseconds wall(Time simulated) const;
};

// One icars-device-manager: which of the house's devices it hosts, its current process
// (incarnation) and what it reported.
struct Manager {
  std::string name;
  std::vector<std::string> devices;
  bool simulation = false;          // hosts the engines and the Simulation device (the clock)
  std::set<std::string> furniture;  // watched by its occupancy sensors
  std::size_t expected_devices = 0;

  std::unique_ptr<Program> process;
  int incarnation = 0;
  bool registered = false;  // the current incarnation registered at least once
  std::chrono::steady_clock::time_point started_wall;
  Time down_since{0};
  int kills = 0, registrations = 0;                  // first registrations of incarnations
  std::uint64_t rounds = 0;                          // every REGISTERED line, reconnections too
  std::vector<std::string> state_lines;              // "STATE restored FILE", one per incarnation
  std::vector<double> reregistration_ms;             // wall time from restart to registration
  std::vector<std::pair<Time, Time>> outages;  // killed .. registered again

  // The command line of a new incarnation: the house, the devices, the clock (--speedup,
  // --epoch), the engines and Simulation only on the simulation manager. Add more options after.
  std::vector<std::string> command(const std::string& device_manager, const std::string& house_file,
                                   const std::string& server, const SharedClock& clock) const;
  // Starts a new incarnation with its stderr in dir/<name>-<incarnation>.stderr.
  void launch(const fs::path& dir, const std::vector<std::string>& env, const std::vector<std::string>& argv);
  // Reads its output: registrations (a device count other than expected_devices is added to
  // `failures`), state lines. `now` stamps the end of an outage.
  void read_output(Time now, std::vector<std::string>& failures);
};

// Pumps (`pump`) until the mediator has exited, at most 120 s of wall time past `end`.
void wait_for_end(Program& mediator, const SharedClock& clock, Time end, const std::function<void()>& pump);

// SIGTERM to every manager's current incarnation; waits up to 60 s for each and returns their
// wait statuses by name. One that ignores SIGTERM is added to `failures`.
std::map<std::string, int> stop_managers(std::vector<Manager>& managers, std::vector<std::string>& failures);

// The paper house's devices over three managers: "robot" (the robot's four), "living" (the
// living room's) and "bedroom" (the bedroom's, with the speech and vision engines and the
// Simulation device, the house's clock).
std::vector<Manager> split_paper_house(const icars::sim::House& house);
// The furniture the managers' occupancy sensors watch.
std::set<std::string> sensed_furniture(const std::vector<Manager>& managers);

// The moments of a day when a user sits or lies down on, or gets up from, furniture that a
// sensor watches: the only inputs that move the paper policy's statechart.
struct Moment {
  std::string furniture;
  Time time_of_day;
  bool occupied = false;  // sits or lies down (true), or gets up
};
std::vector<Moment> occupancy_moments(const icars::sim::House& house, const std::set<std::string>& sensed);
// The first moment strictly after `t` (in any day), of the given furniture or of any.
Time next_moment(const std::vector<Moment>& moments, Time t, const std::string& furniture = "");
// The users' largest schedule jitter.
Time schedule_jitter(const icars::sim::House& house);

// A house file split over three managers (split_paper_house), with its occupancy moments and
// the schedule's jitter.
struct PaperHouse {
  icars::sim::House house;
  std::vector<Manager> managers;
  std::vector<Moment> moments;
  Time jitter{0};
};
PaperHouse load_paper_house(const std::string& house_file);

// --- The trace -----------------------------------------------------------------------------------

using nlohmann::json;
std::vector<json> read_json_lines(const fs::path& path);

// A JSON-lines file read as it grows: each read() returns the records of the lines completed
// since the last one (a line still being written waits for its newline), so following a long
// trace costs what was added, not the whole file each time. Throws on a line that is not JSON.
class JsonLinesTail {
 public:
  explicit JsonLinesTail(fs::path path) : path_(std::move(path)) {}
  std::vector<json> read();

 private:
  fs::path path_;
  std::streamoff offset_ = 0;
  std::string partial_;  // the start of a line not yet finished
};
std::string str(const json& j, const char* key);  // "" when absent or not a string

struct TaskRun {
  std::string task;
  Time started{0}, stopped = Time::max();  // max: still running at the end
};

// The task runs of a trace and the behaviors that got stuck: still running when their task
// stopped (a behavior's path starts with its task's root), or never ended.
struct TaskTimeline {
  std::vector<TaskRun> runs;
  std::vector<std::string> stuck;
};
TaskTimeline follow_tasks(const std::vector<json>& trace);

// Adds to `timeline.stuck` the tasks that ran on too long. A task of the paper policy ends at
// the latest when a sensor next sees the user sit, lie down or get up (RestMode and SleepMode on
// UserLeft, Observation on TimeToRest/Sleep, Standby on SituationChanged). One still running
// `slack` after that moment is stuck. The moment that started a task lies within 15 minutes of
// its start (jitter, the walk, the mediator's clock following the house's by a poll), and the
// moments are at least 30 minutes apart. `next_change(t)` is the first moment the mediator can
// see after `t`; runs whose limit is at or after `end` are not judged.
void find_overdue_tasks(TaskTimeline& timeline, const std::function<Time(Time)>& next_change, Time slack,
                        Time end);

}  // namespace icars_test
