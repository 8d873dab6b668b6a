#include "run_outputs.h"

#include <cstdio>

namespace icars::app {

Time stop_time(Time start, Time until, int days) {
  const auto day = kDay * (start / kDay);
  auto stop_at = day + until;
  if (stop_at <= start) stop_at += kDay;
  return stop_at + kDay * (days - 1);
}

void add_trace_outputs(behavior::Trace& trace, bool quiet, const std::string& file,
                       std::function<void(behavior::TraceRecord&)> decorate) {
  if (!quiet) trace.add_sink(behavior::timeline_printer(stdout, {"robot", "user", "command"}));
  if (file.empty()) return;
  auto writer = behavior::json_lines_writer(file);
  if (!decorate) {
    trace.add_sink(std::move(writer));
    return;
  }
  trace.add_sink([writer = std::move(writer), decorate = std::move(decorate)](const behavior::TraceRecord& r) {
    auto copy = r;
    decorate(copy);
    writer(copy);
  });
}

}  // namespace icars::app
