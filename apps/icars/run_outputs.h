// What `icars run` and `icars serve` share around a mediating server: when a run stops, and
// where its trace goes (the timeline on stdout, a JSON-lines file).
#pragma once

#include <functional>
#include <string>

#include "icars/behavior/trace.h"
#include "icars/clock/time.h"

namespace icars::app {

// The stop time: `until` on the house's first day (the next day when that is not after the
// start), `days - 1` days later (the house's daily schedule repeats).
Time stop_time(Time start, Time until, int days);

// The timeline on stdout (unless `quiet`; it leaves out positions and the command record, which
// the "call" lines say) and, with a `file`, the JSON-lines trace, each record passed through
// `decorate` first when given. Throws std::runtime_error when the file cannot be written.
void add_trace_outputs(behavior::Trace& trace, bool quiet, const std::string& file,
                       std::function<void(behavior::TraceRecord&)> decorate = {});

}  // namespace icars::app
