// Test support: a Coordinator run from policy text on a SimClock advanced by hand, with the
// generic behaviors and two probes (Alive, FailLater) registered and every trace record kept.
#pragma once

#include <atomic>
#include <memory>
#include <string>
#include <vector>

#include "icars/clock/sim_clock.h"
#include "icars/control/collaboration.h"
#include "icars/control/coordinator.h"

namespace icars_test {

namespace b = icars::behavior;
namespace c = icars::control;
using namespace std::chrono_literals;

// Counts live instances, so tests see trees being destroyed.
inline std::atomic<int> g_alive{0};
class Alive final : public b::Behavior {
 public:
  explicit Alive(const b::Params&) { ++g_alive; }
  ~Alive() override { --g_alive; }
};

// Fails after `after`.
class FailLater final : public b::Behavior {
 public:
  explicit FailLater(const b::Params& p) : after_(p.duration("after")) {}

 protected:
  void entry() override {
    after(after_, [this] { fail("gave up"); });
  }

 private:
  icars::Time after_;
};

struct CoordinatorFixture {
  CoordinatorFixture() : runtime(clock), env{runtime, services, trace} {
    b::register_generic_behaviors(registry);
    registry.add<FailLater>("FailLater", "fails later", {b::param("after", b::ParamType::duration, "1min", "")});
    registry.add<Alive>("Alive", "runs until halted");
    trace.add_sink(log.sink());
  }
  // Parses, creates and starts the policy, and lets what it started settle.
  std::unique_ptr<c::Coordinator> start(const std::string& xml) {
    auto parsed = c::parse_policy(xml, "test.xml", registry);
    auto coordinator = c::PolicyFactory(registry).create(parsed.policy, env);
    coordinator->start();
    settle();
    return coordinator;
  }
  void advance(icars::Time d) {
    clock.advance_by(d);
    settle();
  }
  void settle() { ASSERT_TRUE(runtime.drain(10s)); }
  // The texts of the trace records of `kind`, in order.
  std::vector<std::string> texts(const std::string& kind) {
    std::vector<std::string> out;
    for (const auto& r : log.of_kind(kind)) out.push_back(r.text);
    return out;
  }
  std::vector<std::string> transitions() { return texts("transition"); }

  icars::SimClock clock{icars::Time{0}};
  b::Runtime runtime;
  icars::service::ServiceContainer services;
  b::Trace trace;
  b::TraceLog log;
  b::Environment env;
  b::BehaviorRegistry registry;
};

}  // namespace icars_test
