// The live dashboard of a mediating server (docs/dashboard.md): one web page, served from this
// process, that shows the house with the robots and users moving, the policy's statechart with
// its active states, the behavior tree of each running task, the services and the timeline —
// fed by the server's trace over Server-Sent Events — and offers the operator's controls (a
// user's sentence, switching the policy, pausing and the simulation's speed) behind a token.
// The same page replays a recorded trace.
//
//   Dashboard dashboard({.listen = "127.0.0.1:8080", .token = token}, views, controls);
//   server.trace().add_sink([&](const behavior::TraceRecord& r) { dashboard.record(r); });
//   dashboard.start();      // http://127.0.0.1:8080/?token=...
//
// HTTP (cpp-httplib, its own threads): the page and its assets, built into the binary;
// GET /api/snapshot, /api/records, /api/events (SSE); POST /api/say, /api/policy, /api/pause,
// /api/resume, /api/speed. Read-only views need no token; controls need
// `Authorization: Bearer <token>`. A request that cannot be served gets a 4xx status with
// {"error": "<why>"}: an unknown path (404), a body over `max_body` (413), malformed JSON or
// missing fields (400), no or a wrong token (401), controls that are off (403). A slow browser
// never slows the server: its queue is bounded (EventHub).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "icars/behavior/trace.h"
#include "icars/dashboard/event_hub.h"

namespace spdlog {
class logger;
}

namespace icars::dashboard {

struct DashboardOptions {
  std::string listen = "127.0.0.1:0";  // host:port; port 0 lets the system choose
  std::string token{};                 // the controls' token; empty: controls are off
  // HTTPS with this certificate and key; required to listen on an address other than loopback.
  std::string tls_cert{};
  std::string tls_key{};
  EventHubOptions hub{};
  std::size_t max_body = 64 * 1024;  // larger request bodies get 413
  std::size_t threads = 72;          // HTTP worker threads (each live page holds one)
  std::shared_ptr<spdlog::logger> logger{};  // default: stderr, named "dashboard"
};

// A control that cannot be done: the HTTP status and the reason shown to the operator.
class ControlError : public std::runtime_error {
 public:
  ControlError(int status, const std::string& reason) : std::runtime_error(reason), status_(status) {}
  int status() const { return status_; }

 private:
  int status_;
};

// What the page draws (each called on an HTTP thread; thread-safe). Empty: shown as null.
struct Views {
  std::string mode = "live";  // "live" or "replay"
  std::function<nlohmann::json()> house;     // house_view()
  std::function<nlohmann::json()> policy;    // policy_view() of the running policy
  std::function<nlohmann::json()> services;  // [{id, type, device, room, carrier, available}]
  std::function<nlohmann::json()> time;      // {"start_ms", "end_ms"}
};

// What the operator may do; each returns the result's JSON or throws ControlError. Empty: the
// control answers 409 ("not offered here").
struct Controls {
  std::function<nlohmann::json(const std::string& user, const std::string& text)> say;
  std::function<nlohmann::json(const std::string& policy)> run_policy;
  std::function<nlohmann::json()> pause;
  std::function<nlohmann::json()> resume;
  std::function<nlohmann::json(double speed)> speed;
};

// A recorded run's records by index (replay): how many, and a page of them as JSON lines.
struct RecordSource {
  std::function<std::uint64_t()> total;
  std::function<std::vector<std::string>(std::uint64_t from, std::size_t count)> read;
};

class Dashboard {
 public:
  // Checks the options: throws std::invalid_argument for a bad listen address, or a
  // non-loopback one without TLS; std::runtime_error for TLS files that cannot be used.
  Dashboard(DashboardOptions options, Views views, Controls controls = {});
  ~Dashboard();  // stop()
  Dashboard(const Dashboard&) = delete;
  Dashboard& operator=(const Dashboard&) = delete;

  // Replays `source` instead of a live feed (call before start()).
  void replay(RecordSource source);
  // Binds and serves on threads of its own; returns the port. Throws std::runtime_error when
  // the address cannot be bound.
  std::uint16_t start();
  // Ends every page's stream and stops serving. Idempotent.
  void stop();

  // A trace sink: the record goes to every live page. Never blocks on a page.
  void record(const behavior::TraceRecord& r);
  // Tells the pages the services changed (they are read and sent a moment later, on the
  // dashboard's thread: callable from anywhere, a service container's watcher included).
  void services_changed();

  // "http[s]://host:port/" and, with controls, "?token=...".
  std::string url() const;
  EventHub& hub();

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace icars::dashboard
