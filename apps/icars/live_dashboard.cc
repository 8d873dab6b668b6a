#include "live_dashboard.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <fstream>

#include "home.planet.h"
#include "icars/control/policy_check.h"
#include "icars/dashboard/trace_file.h"
#include "icars/dashboard/views.h"
#include "icars/home/adaptors.h"
#include "icars/home/behaviors.h"
#include "icars/home/sim/house_vocabulary.h"
#include "icars/planet/security.h"
#include "security_options.h"

namespace icars::app {

using nlohmann::json;
using dashboard::ControlError;

void DriverControl::attach(LockStepDriver* driver) {
  std::lock_guard lock(mutex_);
  driver_ = driver;
}

json DriverControl::pause() {
  std::lock_guard lock(mutex_);
  if (!driver_) throw ControlError(409, "only a lock-step run (the embedded house) can be paused");
  driver_->stop();
  paused_ = true;
  return {{"paused", true}};
}

json DriverControl::resume() {
  std::lock_guard lock(mutex_);
  if (!driver_) throw ControlError(409, "only a lock-step run (the embedded house) can be paused and resumed");
  driver_->start();
  paused_ = false;
  return {{"paused", false}};
}

json DriverControl::speed(double speedup) {
  std::lock_guard lock(mutex_);
  if (!driver_) throw ControlError(409, "only a lock-step run (the embedded house) changes its speed");
  if (speedup > 100000) throw ControlError(400, "speed is at most 100000 simulated seconds per second");
  driver_->set_speedup(speedup);
  if (paused_) driver_->stop();  // a paused run stays paused at its new speed
  return {{"speed", speedup}, {"paused", paused_}};
}

namespace {

std::string token_of(const DashboardSettings& settings) {
  if (settings.token_file.empty()) return planet::random_token();
  return read_token_file(settings.token_file);
}

json services_view(service::ServiceContainer& container) {
  json out = json::array();
  for (const auto& s : container.all()) {
    const auto& a = s->attributes();
    out.push_back({{"id", s->id()},
                   {"type", s->type()},
                   {"device", a.device},
                   {"capability", a.capability},
                   {"room", a.room},
                   {"carrier", a.carrier},
                   {"available", s->available()}});
  }
  return out;
}

}  // namespace

std::shared_ptr<dashboard::Dashboard> start_run_dashboard(const DashboardSettings& settings, const sim::House& house,
                                                          server::MediatingServer& server, DriverControl& driver) {
  dashboard::DashboardOptions options;
  options.listen = settings.listen;
  options.token = token_of(settings);
  options.tls_cert = settings.tls_cert;
  options.tls_key = settings.tls_key;
  options.logger = spdlog::default_logger();
  dashboard::Views views;
  views.house = [view = dashboard::house_view(house)] { return view; };
  views.policy = [&server]() -> json {
    const auto policy = server.running_policy();
    return policy ? dashboard::policy_view(*policy) : json(nullptr);
  };
  views.services = [&server] { return services_view(server.container()); };
  views.time = [start = house.start_time.count()] { return json{{"start_ms", start}, {"end_ms", nullptr}}; };
  dashboard::Controls controls;
  controls.say = [&server, users = house.users](const std::string& user, const std::string& text) -> json {
    if (std::none_of(users.begin(), users.end(), [&](const sim::UserSpec& u) { return u.id == user; })) {
      std::vector<std::string> names;
      for (const auto& u : users) names.push_back(u.id);
      throw ControlError(400, fmt::format("the house has no user '{}' (users: {})", user, fmt::join(names, ", ")));
    }
    const auto simulation = server.container().find_first<home::SimulationService>(
        service::ServiceQuery::of_type("Simulation").available());
    if (!simulation) throw ControlError(409, "no Simulation service: the house's simulator is not registered");
    try {
      simulation->proxy().say(user, text);
    } catch (const planet::RemoteException& e) {
      throw ControlError(400, e.what());
    } catch (const planet::Error& e) {
      throw ControlError(503, e.what());
    }
    return {{"user", user}, {"said", text}};
  };
  controls.run_policy = [&server, vocabulary = home::house_vocabulary(house)](const std::string& name) -> json {
    try {
      // What `icars run` checks before it starts a policy: names the house does not have.
      const auto parsed = control::parse_policy_file(server.policies().path_of(name), server.behaviors());
      if (auto problems = control::check_policy(parsed.policy, server.behaviors(), vocabulary); !problems.empty()) {
        throw control::PolicyError(std::move(problems));
      }
      server.run_policy(name);
      return {{"policy", parsed.policy.name}};
    } catch (const control::PolicyError& e) {
      // Files named from the repository, as the operator chose them: the page does not need to
      // learn where the server keeps its policies.
      const auto prefix = server.policies().directory() + "/";
      std::vector<std::string> lines;
      for (const auto& d : e.diagnostics()) {
        auto line = d.to_string();
        if (line.starts_with(prefix)) line.erase(0, prefix.size());
        lines.push_back(std::move(line));
      }
      throw ControlError(422, fmt::format("{}", fmt::join(lines, "\n")));
    }
  };
  controls.pause = [&driver] { return driver.pause(); };
  controls.resume = [&driver] { return driver.resume(); };
  controls.speed = [&driver](double speed) { return driver.speed(speed); };
  auto board = std::make_shared<dashboard::Dashboard>(std::move(options), std::move(views), std::move(controls));
  // The trace outlives nothing it is given: the sink holds the dashboard weakly.
  server.trace().add_sink([weak = std::weak_ptr<dashboard::Dashboard>(board)](const behavior::TraceRecord& r) {
    if (auto b = weak.lock()) b->record(r);
  });
  server.container().watch([weak = std::weak_ptr<dashboard::Dashboard>(board)](const auto&, const auto&) {
    if (auto b = weak.lock()) b->services_changed();
  });
  board->start();
  std::printf("[icars] dashboard: %s\n", board->url().c_str());
  return board;
}

int replay(const std::string& trace_path, const std::string& world, const std::string& policy_path,
           const DashboardSettings& settings) {
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  std::setvbuf(stdout, nullptr, _IOLBF, 0);
  try {
    const dashboard::TraceFile trace(trace_path);
    const auto house = sim::load_house(world);
    json policy = nullptr;
    if (!policy_path.empty()) {
      policy = dashboard::policy_view(control::parse_policy_file(policy_path, home::behavior_registry()).policy);
    }
    dashboard::DashboardOptions options;
    options.listen = settings.listen;
    options.tls_cert = settings.tls_cert;
    options.tls_key = settings.tls_key;
    options.logger = spdlog::default_logger();
    dashboard::Views views;
    views.mode = "replay";
    views.house = [view = dashboard::house_view(house)] { return view; };
    views.policy = [policy] { return policy; };
    views.time = [&trace] { return json{{"start_ms", trace.first_ms()}, {"end_ms", trace.last_ms()}}; };
    dashboard::Dashboard board(std::move(options), std::move(views));
    board.replay(trace.source());
    board.start();
    std::printf("[icars] replaying %s (%llu records, %s to %s): %s\n", trace_path.c_str(),
                static_cast<unsigned long long>(trace.size()), format_time(Time{trace.first_ms()}).c_str(),
                format_time(Time{trace.last_ms()}).c_str(), board.url().c_str());
    int signal = 0;
    sigwait(&signals, &signal);
    board.stop();
    return 0;
  } catch (const control::PolicyError& e) {
    for (const auto& d : e.diagnostics()) std::fprintf(stderr, "%s\n", d.to_string().c_str());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "icars replay: %s\n", e.what());
    return 2;
  }
}

}  // namespace icars::app
