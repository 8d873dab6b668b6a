// The live dashboard's cost to the mediator and its delay to a page (a plain program printing
// medians).
//
//   dashboard_bench [--runs 5] [--records 200000] [--pages 20] [--latency-records 2000] [--rate 1000]
//                   [--days 2]
//
// "Pages" are cpp-httplib clients reading /api/events as a browser's EventSource does (they parse
// every record's JSON, as the page does; they do not draw), in this process.
//   mediator    the real mediator, `icars run paper_home --world paper_house --days D --speed max
//               --http`, as a child process: paused from its dashboard as soon as it runs, 0 or
//               --pages pages connected, resumed; its throughput is the simulated time it gets
//               through per wall second from the resume to its summary.
// The rest in this process, over loopback HTTP: a Dashboard (icars/dashboard/) attached to a
// behavior::Trace as `icars run --http` attaches it.
//   trace       records/s the trace takes (the mediator's cost of each record it traces: the
//               trace's sinks run on the recording thread) with the dashboard attached and 0,
//               then --pages pages reading, next to the trace with no dashboard at all. Each
//               record is a typical `behavior` record (~230 bytes of JSON).
//   latency     time from Trace::record() to the record's arrival at a page, parsed, at --rate
//               records/s, with 1 and with --pages pages (median and p99 of --latency-records).
// Prints the median over --runs of each figure, and the ratio of records/s with pages to
// without.
#include <fmt/format.h>
#include <httplib.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <regex>
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>
#include <vector>

#include "bench_util.h"
#include "child_process.h"
#include "icars/behavior/trace.h"
#include "icars/dashboard/dashboard.h"

namespace {

using namespace std::chrono;
using Clock = steady_clock;
namespace d = icars::dashboard;
namespace b = icars::behavior;

b::TraceRecord typical(std::int64_t seq) {
  b::TraceRecord r;
  r.time = icars::Time{65'400'000 + seq};
  r.kind = "behavior";
  r.source = "RestMode/Rest/VoiceControl/Serve/VoiceTVControl";
  r.text = "RestMode/Rest/VoiceControl/Serve/VoiceTVControl started";
  r.with("event", std::string("start")).with("type", std::string("VoiceTVControl")).with("seq", seq);
  return r;
}

// A page: reads the stream, parses every record, and notes when each `seq` arrived.
class Page {
 public:
  // Without `arrivals`, `parse` says whether the page parses what it reads (as a browser on this
  // machine would) or only drains it (as one elsewhere costs this machine).
  Page(std::uint16_t port, std::vector<Clock::time_point>* arrivals, std::mutex* mutex, bool parse = true)
      : thread_([this, port, arrivals, mutex, parse] {
          httplib::Client c("127.0.0.1", port);
          c.set_read_timeout(60, 0);
          c.set_tcp_nodelay(true);
          std::string buffer;
          c.Get("/api/events", [&](const char* data, std::size_t n) {
            if (!parse && !arrivals) {
              received_ += static_cast<std::uint64_t>(std::count(data, data + n, '\n'));
              return !stop_.load();
            }
            buffer.append(data, n);
            std::size_t end = 0;
            while ((end = buffer.find("\n\n")) != std::string::npos) {
              const auto event = buffer.substr(0, end);
              buffer.erase(0, end + 2);
              const auto at = event.find("data: ");
              if (at == std::string::npos) continue;
              const auto j = nlohmann::json::parse(event.substr(at + 6), nullptr, false);
              ++received_;
              if (arrivals && j.is_object() && j.contains("seq")) {
                const auto seq = j["seq"].get<std::size_t>();
                std::lock_guard lock(*mutex);
                if (seq < arrivals->size()) (*arrivals)[seq] = Clock::now();
              }
            }
            return !stop_.load();
          });
        }) {}
  ~Page() {
    stop_ = true;
    thread_.join();
  }
  std::uint64_t received() const { return received_.load(); }
  std::atomic<bool>& stop() { return stop_; }

 private:
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> received_{0};
  std::thread thread_;
};

bool wait_for_pages(d::Dashboard& dashboard, std::size_t n) {
  for (int i = 0; i < 2000; ++i) {
    if (dashboard.hub().clients() >= n) return true;
    std::this_thread::sleep_for(5ms);
  }
  return false;
}

// Records per second the trace takes: the recording thread's cost, sinks included.
double trace_rate(b::Trace& trace, std::int64_t records) {
  const auto start = Clock::now();
  for (std::int64_t i = 0; i < records; ++i) trace.record(typical(i));
  return static_cast<double>(records) / duration<double>(Clock::now() - start).count();
}

struct Latency {
  double median_ms, p99_ms;
};

Latency latency(std::size_t pages, std::size_t records, double rate) {
  d::Dashboard dashboard({.hub = {.queue = 65536, .history = 2000, .max_clients = 128}}, {});
  const auto port = dashboard.start();
  b::Trace trace;
  trace.add_sink([&dashboard](const b::TraceRecord& r) { dashboard.record(r); });
  std::mutex mutex;
  std::vector<Clock::time_point> sent(records), arrived(records);
  std::vector<std::unique_ptr<Page>> others;
  for (std::size_t i = 1; i < pages; ++i) others.push_back(std::make_unique<Page>(port, nullptr, nullptr, true));
  const Page measured(port, &arrived, &mutex);
  if (!wait_for_pages(dashboard, pages)) throw std::runtime_error("the pages did not connect");
  const auto period = duration<double>(1.0 / rate);
  const auto start = Clock::now();
  for (std::size_t i = 0; i < records; ++i) {
    std::this_thread::sleep_until(start + duration_cast<Clock::duration>(period * static_cast<double>(i)));
    sent[i] = Clock::now();
    trace.record(typical(static_cast<std::int64_t>(i)));
  }
  const auto deadline = Clock::now() + 30s;
  while (Clock::now() < deadline) {
    std::lock_guard lock(mutex);
    if (arrived.back() != Clock::time_point{}) break;
  }
  dashboard.stop();
  std::vector<double> ms;
  for (std::size_t i = 0; i < records; ++i) {
    if (arrived[i] != Clock::time_point{}) ms.push_back(duration<double, std::milli>(arrived[i] - sent[i]).count());
  }
  if (ms.size() < records * 99 / 100) throw std::runtime_error("more than 1% of the records never reached the page");
  std::sort(ms.begin(), ms.end());
  return {ms[ms.size() / 2], ms[std::min(ms.size() - 1, ms.size() * 99 / 100)]};
}

const std::string kIcars = ICARS_BINARY;

// "d7 07:30:00" → ms since day 0, 00:00.
std::int64_t parse_day_time(const std::string& text) {
  int day = 0, h = 0, m = 0, sec = 0;
  if (std::sscanf(text.c_str(), "d%d %d:%d:%d", &day, &h, &m, &sec) != 4) throw std::runtime_error("no time in " + text);
  return ((static_cast<std::int64_t>(day) * 24 + h) * 60 + m) * 60'000 + sec * 1000;
}

// Simulated hours per wall second of a paper week run by the real mediator with `pages` pages.
double mediator_rate(std::size_t pages, int days, bool parse) {
  const auto token_file = std::filesystem::temp_directory_path() / ("icars-dashboard-bench-" + std::to_string(::getpid()));
  const std::string token(64, 'a');
  std::ofstream(token_file) << token << "\n";
  planet_test::ChildProcess icars({kIcars, "run", std::string(ICARS_POLICIES_DIR) + "/paper_home.xml", "--world",
                                         std::string(ICARS_HOUSES_DIR) + "/paper_house.xml", "--days",
                                         std::to_string(days), "--speed", "max", "--quiet", "--http", "127.0.0.1:0",
                                         "--http-token-file", token_file.string()});
  int port = 0;
  const std::regex url(R"(http://127\.0\.0\.1:(\d+)/)");
  while (auto line = icars.read_line(60s)) {
    std::smatch m;
    if (line->starts_with("[icars] dashboard:") && std::regex_search(*line, m, url)) {
      port = std::stoi(m[1]);
      break;
    }
  }
  std::filesystem::remove(token_file);  // read by now
  if (port == 0) throw std::runtime_error("icars printed no dashboard");
  httplib::Client c("127.0.0.1", port);
  const httplib::Headers auth{{"Authorization", "Bearer " + token}};
  // The clock runs once the house registered and the policy started: pause it then.
  bool paused = false;
  for (const auto until = Clock::now() + 60s; !paused && Clock::now() < until;) {
    const auto r = c.Post("/api/pause", auth, "{}", "application/json");
    paused = r && r->status == 200;
    if (!paused) std::this_thread::sleep_for(1ms);
  }
  if (!paused) throw std::runtime_error("the mediator could not be paused");
  std::vector<std::unique_ptr<Page>> readers;
  for (std::size_t i = 0; i < pages; ++i) {
    readers.push_back(std::make_unique<Page>(static_cast<std::uint16_t>(port), nullptr, nullptr, parse));
  }
  const auto newest = [&] {
    const auto r = c.Get("/api/snapshot");
    const auto j = r ? nlohmann::json::parse(r->body, nullptr, false) : nlohmann::json();
    return std::pair{j.is_object() && !j["records"].empty() ? j["records"].back().value("t", std::int64_t{0}) : 0,
                     j.is_object() ? j.value("pages", std::size_t{0}) : 0};
  };
  // Every page connected, and what was under way at the pause done.
  std::int64_t paused_at = -1;
  for (const auto until = Clock::now() + 60s; Clock::now() < until;) {
    std::this_thread::sleep_for(200ms);
    const auto [t, connected] = newest();
    if (connected >= pages && t == paused_at) break;
    paused_at = t;
  }
  const auto start = Clock::now();
  const auto r = c.Post("/api/resume", auth, "{}", "application/json");
  if (!r || r->status != 200) throw std::runtime_error("the mediator could not be resumed");
  std::int64_t end_at = -1;
  const std::regex summary(R"(=== summary: policy \S+, (d\d+ [0-9:]+) to (d\d+ [0-9:]+))");
  while (auto line = icars.read_line(600s)) {
    std::smatch m;
    if (std::regex_search(*line, m, summary)) {
      end_at = parse_day_time(m[2]);
      break;
    }
  }
  const auto wall = duration<double>(Clock::now() - start).count();
  for (auto& p : readers) p->stop() = true;
  icars.wait_for(60s);
  if (end_at < 0) throw std::runtime_error("the mediator printed no summary");
  return static_cast<double>(end_at - paused_at) / 3'600'000.0 / wall;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"the live dashboard: the mediator's cost per traced record, and a record's delay to a page"};
  int runs = 5;
  std::int64_t records = 200'000;
  std::size_t pages = 20;
  std::size_t latency_records = 2000;
  double rate = 1000;
  int days = 2;
  bool parse = false;
  app.add_flag("--parse", parse,
               "the pages parse every record on this machine (default: they only drain the stream, as browsers "
               "on other machines cost this one)");
  app.add_option("--days", days, "simulated days the mediator runs per measurement")->check(CLI::Range(1, 30));
  app.add_option("--runs", runs, "repetitions (medians are printed)")->check(CLI::Range(1, 1000));
  app.add_option("--records", records, "records traced per throughput measurement")->check(CLI::Range(1000, 100'000'000));
  app.add_option("--pages", pages, "pages connected in the second measurements")->check(CLI::Range(1, 100));
  app.add_option("--latency-records", latency_records, "records timed per latency measurement")->check(CLI::Range(100, 1'000'000));
  app.add_option("--rate", rate, "records per second during the latency measurement")->check(CLI::Range(1.0, 100000.0));
  CLI11_PARSE(app, argc, argv);

  try {
    std::vector<double> none, zero, many, lat1_median, lat1_p99, latn_median, latn_p99, mediator0, mediatorn;
    for (int run = 0; run < runs; ++run) {
      mediator0.push_back(mediator_rate(0, days, parse));
      mediatorn.push_back(mediator_rate(pages, days, parse));
      {
        b::Trace trace;
        trace.add_sink([](const b::TraceRecord&) {});
        none.push_back(trace_rate(trace, records));
      }
      {
        d::Dashboard dashboard({.hub = {.queue = 4096, .history = 2000, .max_clients = 128}}, {});
        const auto port = dashboard.start();
        b::Trace trace;
        trace.add_sink([&dashboard](const b::TraceRecord& r) { dashboard.record(r); });
        zero.push_back(trace_rate(trace, records));
        std::vector<std::unique_ptr<Page>> readers;
        for (std::size_t i = 0; i < pages; ++i) readers.push_back(std::make_unique<Page>(port, nullptr, nullptr, parse));
        if (!wait_for_pages(dashboard, pages)) throw std::runtime_error("the pages did not connect");
        many.push_back(trace_rate(trace, records));
        for (auto& r : readers) r->stop() = true;
        dashboard.stop();
      }
      const auto one = latency(1, latency_records, rate);
      lat1_median.push_back(one.median_ms);
      lat1_p99.push_back(one.p99_ms);
      const auto all = latency(pages, latency_records, rate);
      latn_median.push_back(all.median_ms);
      latn_p99.push_back(all.p99_ms);
    }
    const auto m = [](const std::vector<double>& v) { return icars::bench::stats(v).median; };
    fmt::print("{} runs (medians of the runs); pages {}; {} records per trace measurement; latency: {} records at "
               "{:g}/s\n",
               runs, parse ? "parse every record here" : "drain their streams", records, latency_records, rate);
    fmt::print("{:<44} {:>14} {:>14}\n", fmt::format("mediator, paper_home {} days at max", days), "sim h / s",
               "/ no pages");
    fmt::print("{:<44} {:>14.1f} {:>14.3f}\n", "0 pages", m(mediator0), 1.0);
    fmt::print("{:<44} {:>14.1f} {:>14.3f}\n", fmt::format("{} pages reading", pages), m(mediatorn),
               m(mediatorn) / m(mediator0));
    fmt::print("{:<44} {:>14} {:>14}\n", "trace throughput", "records/s", "/ no pages");
    fmt::print("{:<44} {:>14.0f} {:>14}\n", "no dashboard", m(none), "");
    fmt::print("{:<44} {:>14.0f} {:>14.3f}\n", "dashboard, 0 pages", m(zero), 1.0);
    fmt::print("{:<44} {:>14.0f} {:>14.3f}\n", fmt::format("dashboard, {} pages reading", pages), m(many),
               m(many) / m(zero));
    fmt::print("{:<44} {:>14} {:>14}\n", "record -> page (parsed)", "median (ms)", "p99 (ms)");
    fmt::print("{:<44} {:>14.3f} {:>14.3f}\n", "1 page", m(lat1_median), m(lat1_p99));
    fmt::print("{:<44} {:>14.3f} {:>14.3f}\n", fmt::format("{} pages", pages), m(latn_median), m(latn_p99));
    return 0;
  } catch (const std::exception& e) {
    fmt::print(stderr, "dashboard_bench: {}\n", e.what());
    return 1;
  }
}
