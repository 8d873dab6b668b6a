// The summary of a run of a mediating server and the data of its plot, gathered record by
// record from the server's trace (a trace sink) so that a run of any length keeps a bounded
// amount: counts, time per state, the first failures, the last effect per device. Only a
// summary that keeps a plot keeps its positions and transitions (the plot shows every one).
// It reads the records' typed fields (numbers, flags), never numbers out of their text.
#pragma once

#include <cstdio>
#include <map>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "icars/behavior/trace.h"
#include "icars/sim/house.h"
#include "icars/sim/svg_plot.h"

namespace icars::report {

// What the summary counted, as numbers (print() writes them for people).
struct RunCounts {
  int transitions = 0;
  int behaviors_started = 0, behaviors_succeeded = 0, behaviors_failed = 0, behaviors_halted = 0;
  int calls = 0, failed_calls = 0;
  int commands_sent = 0, commands_acknowledged = 0, commands_failed = 0;
  int effects = 0, voice_commands_heard = 0;
  double robot_distance_m = 0;
};

class RunSummary {
 public:
  explicit RunSummary(bool keep_plot);
  // The sink reads nothing but the record; it is called under the trace's lock.
  behavior::Trace::Sink sink();

  RunCounts counts() const;
  // Times each state was entered and the time spent in it up to `to` (a state still active
  // counts until then), in the order the states were first seen.
  struct StateTime {
    std::string state;
    int entered = 0;
    Time spent{0};
  };
  std::vector<StateTime> states(Time to) const;
  // The first five behavior failures, "[d0 18:10:00] <text>".
  std::vector<std::string> failures() const;
  // The last effect per device ("power on", "channel 5").
  std::map<std::string, std::string> device_states() const;

  // "=== summary: ..." and what follows, as `icars run` prints it; `clock` says how the clock
  // ran ("lock-step at 600x").
  void print(std::FILE* out, const std::string& policy, Time from, Time to, double wall_seconds,
             const std::string& clock) const;
  // The robots' and users' tracks and the transitions, marked where the first robot was then,
  // for the run from `from` to `to` (the plot's subtitle). Every robot and user of the house
  // has a track, which begins at `from` where the house starts them (RobotSpec::start,
  // UserSpec::start) unless the trace placed them at or before `from`. Needs keep_plot.
  sim::PlotData plot(const std::string& title, const sim::House& house, Time from, Time to) const;

 private:
  void add(const behavior::TraceRecord& r);

  const bool keep_plot_;
  mutable std::mutex mutex_;
  RunCounts counts_;
  std::map<std::string, std::pair<int, Time>> states_;  // times entered, time spent
  std::map<std::string, Time> entered_;                 // active states: since when
  std::vector<std::string> order_;
  std::vector<std::string> failures_;  // the first five
  std::map<std::string, std::string> device_state_;
  std::map<std::string, std::pair<double, double>> last_pose_;
  std::vector<behavior::TraceRecord> plotted_;
};

}  // namespace icars::report
