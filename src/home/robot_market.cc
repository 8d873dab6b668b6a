#include "icars/home/robot_market.h"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>

#include "icars/coros/discovery.h"

namespace icars::home {

std::string_view to_string(ErrandUpdate::Kind kind) {
  switch (kind) {
    case ErrandUpdate::Kind::assigned:
      return "assigned";
    case ErrandUpdate::Kind::turn:
      return "turn";
    case ErrandUpdate::Kind::reauctioned:
      return "reauctioned";
    case ErrandUpdate::Kind::unassigned:
      return "unassigned";
  }
  return "errand";
}

namespace {
// The robot a Navigation service drives: its carrier, or its device's id without "_wheels".
std::string robot_of(const service::Service& s) {
  if (!s.attributes().carrier.empty()) return s.attributes().carrier;
  const auto& device = s.attributes().device;
  constexpr std::string_view suffix = "_wheels";
  if (device.size() > suffix.size() && device.ends_with(suffix)) return device.substr(0, device.size() - suffix.size());
  return device;
}
}  // namespace

RobotMarket::RobotMarket(service::ServiceContainer& container, RobotMarketOptions options)
    : service::Service("robot_market", "RobotMarket", {}), container_(container), activity_(options.activity) {
  options.agent.role = "market";
  // Errand ids name this market's run, so a restarted mediator's errands are new to the robots.
  const auto started = std::chrono::duration_cast<std::chrono::microseconds>(
                           std::chrono::system_clock::now().time_since_epoch())
                           .count();
  prefix_ = fmt::format("{}.{:x}.", options.agent.id, started);
  agent_ = std::make_unique<coros::Agent>(options.agent);
  agent_->add_operator(std::make_shared<coros::DiscoveryOperator>());
  market_ = std::make_shared<coros::ErrandMarket>(options.market);
  agent_->add_operator(market_);
  agent_->start();
  watcher_ = container_.watch([this](const std::shared_ptr<service::Service>& s, const service::ServiceChange& c) {
    on_service(s, c);
  });
  for (const auto& s : container_.find(service::ServiceQuery::of_type("Navigation"))) {
    if (!s->available()) on_service(s, service::ServiceChange::unavailable);
  }
  set_available(true);
}

RobotMarket::~RobotMarket() { stop(); }

void RobotMarket::stop() {
  std::call_once(stopped_, [this] {
    container_.remove_watcher(watcher_);
    agent_->stop();
    set_available(false);
  });
}

void RobotMarket::on_service(const std::shared_ptr<service::Service>& s, service::ServiceChange change) {
  if (s->type() != "Navigation") return;
  const std::string robot = robot_of(*s);
  const bool gone = change == service::ServiceChange::unavailable || change == service::ServiceChange::removed;
  const bool back = change == service::ServiceChange::available ||
                    (change == service::ServiceChange::added && s->available());
  if (gone) {
    agent_->post([this, robot, why = s->id() + " is unavailable", h = std::make_shared<Activity::Hold>(hold())] {
      market_->robot_failed(robot, why);
    });
  } else if (back) {
    agent_->post([this, robot] { market_->set_available(robot); });
  }
}

std::string RobotMarket::offer(const std::string& label, coros::Place stop, Listener listener) {
  const std::string id = prefix_ + std::to_string(next_++);
  {
    std::lock_guard lock(mutex_);
    ++open_;
  }
  agent_->post([this, id, label, stop = std::move(stop), listener = std::move(listener),
                h = std::make_shared<Activity::Hold>(hold())]() mutable {
    auto& entry = entries_[id];
    entry.listener = std::move(listener);
    entry.auctioning = std::move(*h);
    agent_->emit({{"event", "errand_offered"}, {"errand", id}, {"label", label}});
    market_->offer(id, std::move(stop), [this](const coros::ErrandNews& news) { on_news(news); });
  });
  return id;
}

void RobotMarket::tell(const std::string& errand, const ErrandUpdate& update) {
  auto it = entries_.find(errand);
  if (it != entries_.end() && it->second.listener) it->second.listener(update);
}

void RobotMarket::on_news(const coros::ErrandNews& news) {
  auto it = entries_.find(news.errand);
  if (it == entries_.end()) return;
  ErrandUpdate u;
  u.errand = news.errand;
  u.robot = news.robot;
  u.reason = news.reason;
  u.round = news.round;
  u.cost = news.cost;
  u.bids = news.bids;
  u.excluded = news.excluded;
  u.auction_ms = news.auction_ms;
  switch (news.kind) {
    case coros::ErrandNews::Kind::awarded: {
      it->second.robot = news.robot;
      it->second.turn = false;
      auto held = std::move(it->second.auctioning);  // released once the behavior has heard
      queues_[news.robot].push_back(news.errand);
      u.kind = ErrandUpdate::Kind::assigned;
      tell(news.errand, u);
      if (queues_[news.robot].front() == news.errand) advance(news.robot);
      return;
    }
    case coros::ErrandNews::Kind::reauctioned: {
      it->second.auctioning = hold();
      leave_queue(news.errand, news.robot);
      u.kind = ErrandUpdate::Kind::reauctioned;
      tell(news.errand, u);
      return;
    }
    case coros::ErrandNews::Kind::unassigned: {
      u.kind = ErrandUpdate::Kind::unassigned;
      auto listener = std::move(it->second.listener);
      entries_.erase(it);
      {
        std::lock_guard lock(mutex_);
        --open_;
      }
      if (listener) listener(u);
      return;
    }
  }
}

void RobotMarket::leave_queue(const std::string& errand, const std::string& robot) {
  auto e = entries_.find(errand);
  if (e != entries_.end()) {
    e->second.robot.clear();
    e->second.turn = false;
  }
  auto q = queues_.find(robot);
  if (q == queues_.end()) return;
  auto& list = q->second;
  const bool first = !list.empty() && list.front() == errand;
  list.erase(std::remove(list.begin(), list.end(), errand), list.end());
  // The robot's next errand is its holder's to drive, unless the robot itself is out: then
  // every errand it holds is being auctioned again anyway.
  if (first && !market_->unavailable().contains(robot)) advance(robot);
}

void RobotMarket::advance(const std::string& robot) {
  auto q = queues_.find(robot);
  if (q == queues_.end() || q->second.empty()) return;
  const std::string errand = q->second.front();
  auto e = entries_.find(errand);
  if (e == entries_.end() || e->second.turn) return;
  e->second.turn = true;
  ErrandUpdate u;
  u.kind = ErrandUpdate::Kind::turn;
  u.errand = errand;
  u.robot = robot;
  tell(errand, u);
}

void RobotMarket::done(const std::string& errand) {
  agent_->post([this, errand, h = std::make_shared<Activity::Hold>(hold())] {
    auto it = entries_.find(errand);
    if (it == entries_.end()) return;
    const std::string robot = it->second.robot;
    entries_.erase(it);
    {
      std::lock_guard lock(mutex_);
      --open_;
    }
    market_->release(errand);
    if (!robot.empty()) leave_queue(errand, robot);
  });
}

void RobotMarket::failed(const std::string& errand, std::string why) {
  agent_->post([this, errand, why = std::move(why), h = std::make_shared<Activity::Hold>(hold())] {
    market_->reassign(errand, why);
  });
}

std::vector<std::string> RobotMarket::robots() const {
  if (!available()) return {};  // stopped: its thread answers no more
  return agent_->call([this] {
    std::vector<std::string> out;
    for (const auto& n : agent_->neighbors().neighbors_with_role("robot")) out.push_back(n.id);
    return out;
  });
}

std::size_t RobotMarket::open_errands() const {
  std::lock_guard lock(mutex_);
  return open_;
}

}  // namespace icars::home
