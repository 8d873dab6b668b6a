// Turns an agent's bad datagrams into few events: at most one per source address per period
// (a second), each carrying how many came since the source's last one, so a flood of garbage
// costs a bounded trickle of events and the counts still add up (docs/coros.md, "Bad
// datagrams"). Not thread-safe: the agent uses it on its own thread; time is passed in.
#pragma once

#include <asio/ip/udp.hpp>
#include <chrono>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace icars::coros {

class BadDatagramReporter {
 public:
  using Clock = std::chrono::steady_clock;
  enum class Reason {
    malformed,  // the transport could not decode it
    refused,    // decoded, and a handler rejected it
  };
  // One event's worth: the bad datagrams of one source since its previous report.
  struct Report {
    std::string source;  // the source's IP address, or "other" (more sources than tracked)
    std::string from;    // ip:port of the last one counted
    std::string error;   // what was wrong with the last one counted
    std::uint64_t count = 0;
    std::uint64_t malformed = 0;
    std::uint64_t refused = 0;
  };

  explicit BadDatagramReporter(std::chrono::milliseconds period = std::chrono::seconds(1),
                               std::size_t max_sources = 256);

  // Counts a bad datagram. The first of a source with no report in the last period is
  // reported at once (returned); later ones wait for the source's next report (due()).
  std::optional<Report> add(const asio::ip::udp::endpoint& from, Reason reason, std::string error,
                            Clock::time_point now);
  // Reports for the sources whose period has ended with datagrams counted in it (each opens
  // a new period); sources quiet for a whole period are forgotten.
  std::vector<Report> due(Clock::time_point now);
  // When due() next has something to do, or nullopt when no source is tracked.
  std::optional<Clock::time_point> next_due() const;
  // Everything counted and not yet reported, e.g. when the agent stops.
  std::vector<Report> flush();

 private:
  struct Source {
    Clock::time_point period_end;
    Report pending;  // count 0: nothing since the last report
  };
  std::chrono::milliseconds period_;
  std::size_t max_sources_;
  std::map<std::string, Source> sources_;
};

}  // namespace icars::coros
