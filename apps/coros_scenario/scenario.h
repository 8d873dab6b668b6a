// icars-coros: the COROS courier delivery scenario (COROS 5.2) run as it would be deployed —
// one process per agent — on one host, and reported.
//
// A scenario is N simulated robots and one user agent, each an `icars-agent <config.json>`
// process sharing a broadcast port. The user auctions deliveries between offices, the robots
// bid their planned path lengths and the winners drive; a robot may be killed on purpose to
// show the user auctioning its task again. Everything is learnt from the agents' stdout
// events (one JSON object per line) and the robots' track files, never from inside them.
//
// plan_scenario() (scenario_plan.h) validates the options against the map and writes nothing;
// run_scenario() writes the configurations, supervises the agent processes (starting them,
// the kill rule, the timeout, stopping them), feeds their events to the summary
// (ScenarioReport, scenario_report.h) and prints it; run_agents() does the same and returns
// the report.
#pragma once

#include "scenario_plan.h"

namespace icars::coros_scenario {

class ScenarioReport;  // scenario_report.h

// Runs the scenario and prints the summary; returns the exit code (0: every delivery
// succeeded, 1: not). Throws UsageError before starting anything.
int run_scenario(const ScenarioOptions& options);

// The same run without the summary, the files (--json, --svg) or the dashboard: returns what
// the agents' events and the robots' tracks said, for programs that run scenarios and read the
// outcome (bench/coros_processes.cc). Prints the run's lines unless options.quiet; the working
// directory is removed unless options.keep_dir names it. Throws UsageError before starting
// anything.
ScenarioReport run_agents(const ScenarioOptions& options);

}  // namespace icars::coros_scenario
