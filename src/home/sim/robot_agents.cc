#include "icars/home/sim/robot_agents.h"

#include <cmath>
#include <map>
#include <set>
#include <stdexcept>

#include "icars/coros/discovery.h"
#include "icars/coros/robot.h"

namespace icars::home {

namespace {
// Puts the house's robots that other device managers drive where their agents say they are, so
// the robots driven here plan around them and wait for them at doors (docs/distribution.md).
class PlaceOtherRobots : public coros::SimpleOperator {
 public:
  PlaceOtherRobots(sim::World& world, std::set<std::string> here) : world_(world), here_(std::move(here)) {}
  void init(coros::Agent& agent) override {
    SimpleOperator::init(agent);
    timer_ = agent.every(agent.config().hello_period, [this] { place(); });
  }
  void shutdown() override {
    if (timer_) timer_->cancel();
  }

 private:
  void place() {
    for (const auto& n : agent().neighbors().neighbors_with_role("robot")) {
      if (here_.contains(n.id) || world_.house().robot(n.id) == nullptr) continue;
      if (!std::isfinite(n.x) || !std::isfinite(n.y)) continue;
      const auto seen = std::make_pair(n.x, n.y);
      if (placed_[n.id] == seen) continue;
      placed_[n.id] = seen;
      world_.place_robot(n.id, sim::Pose{n.x, n.y, 0});
    }
  }
  sim::World& world_;
  std::set<std::string> here_;
  std::map<std::string, std::pair<double, double>> placed_;
  std::shared_ptr<coros::Timer> timer_;
};
}  // namespace

RobotAgents::RobotAgents(sim::World& world, const std::vector<std::string>& robots,
                         const coros::AgentConfiguration& base) {
  for (const auto& id : robots) {
    const auto& specs = world.house().robots;
    auto spec = std::find_if(specs.begin(), specs.end(), [&](const sim::RobotSpec& r) { return r.id == id; });
    if (spec == specs.end()) throw std::invalid_argument("the house has no robot \"" + id + "\"");
    auto config = base;
    config.id = id;
    config.role = "robot";
    auto map = std::make_shared<const coros::MapPlanner>(world.house(), spec->radius);
    Robot r;
    r.agent = std::make_unique<coros::Agent>(config);
    r.agent->add_operator(std::make_shared<coros::DiscoveryOperator>());
    r.bidder = std::make_shared<coros::ErrandBidder>(map, [&world, id]() -> std::optional<sim::Point> {
      const auto pose = world.robot_pose(id);
      return sim::Point{pose.x, pose.y};
    }, coros::ErrandBidder::Objective::arrival);  // spread the work: the soonest done wins
    r.agent->add_operator(r.bidder);
    if (robots_.empty()) {
      r.agent->add_operator(std::make_shared<PlaceOtherRobots>(world, std::set<std::string>(robots.begin(), robots.end())));
    }
    robots_.emplace_back(id, std::move(r));
  }
}

RobotAgents::~RobotAgents() { stop(); }

void RobotAgents::start() {
  for (auto& [id, r] : robots_) r.agent->start();
}

void RobotAgents::stop() {
  for (auto& [id, r] : robots_) r.agent->stop();
}

std::vector<coros::Agent*> RobotAgents::agents() {
  std::vector<coros::Agent*> out;
  for (auto& [id, r] : robots_) out.push_back(r.agent.get());
  return out;
}

std::vector<std::string> RobotAgents::route(const std::string& robot) {
  for (auto& [id, r] : robots_) {
    if (id == robot) return r.agent->call([&r = r] { return r.bidder->route(); });
  }
  return {};
}

}  // namespace icars::home
