#include "icars/coros/errands.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>

namespace icars::coros {

namespace {
constexpr double kSnapDistance = 1.5;  // m, as sim::WorldOptions::snap_distance
}  // namespace

std::string_view to_string(ErrandNews::Kind kind) {
  switch (kind) {
    case ErrandNews::Kind::awarded:
      return "awarded";
    case ErrandNews::Kind::reauctioned:
      return "reauctioned";
    case ErrandNews::Kind::unassigned:
      return "unassigned";
  }
  return "errand";
}

// --- ErrandMarket -------------------------------------------------------------------------------

void ErrandMarket::init(Agent& agent) {
  SimpleOperator::init(agent);
  started_ = Clock::now();
  actions_ = std::make_unique<ActionHandler>(agent);
  agent.processor().on<BidMessage>([this](const BidMessage& m, const Envelope& e) { on_bid(m, e); });
  agent.processor().on<DeclineMessage>([this](const DeclineMessage& m, const Envelope& e) { on_decline(m, e); });
  agent.processor().on<AwardAckMessage>([this](const AwardAckMessage& m, const Envelope& e) { on_award_ack(m, e); });
  agent.neighbors().on_change([this](const AgentState& s, bool joined) {
    if (s.role != "robot") return;
    if (joined) return;
    // Out of the neighbour table it cannot bid; whether it may win again when it is back is the
    // user's to say (robot_failed / set_available), not its announcements'.
    lose(s.id, fmt::format("{} stopped announcing itself", s.id));
  });
}

bool ErrandMarket::every_robot_bid(const Errand& e) const {
  // Until every robot had the time to announce itself, the neighbour table does not say who
  // will bid: the round waits for its window.
  if (Clock::now() - started_ < agent().config().neighbor_expiry) return false;
  const auto out = excluded(e);
  for (const auto& n : agent().neighbors().neighbors_with_role("robot")) {
    if (std::find(out.begin(), out.end(), n.id) != out.end()) continue;
    if (!e.bids.contains(n.id) && !e.declined.contains(n.id)) return false;
  }
  return true;
}

void ErrandMarket::shutdown() {
  for (auto& [id, e] : errands_) stop_messages(e);
  for (auto& r : revokers_) r->complete();
  revokers_.clear();
}

void ErrandMarket::offer(const std::string& errand, Place stop, Listener listener) {
  if (errands_.contains(errand)) throw CorosError("errand '" + errand + "' is already on offer");
  Errand e;
  e.stop = std::move(stop);
  e.listener = std::move(listener);
  errands_.emplace(errand, std::move(e));
  queue_.push_back(errand);
  next();
}

void ErrandMarket::tell(const Errand& e, ErrandNews news) const {
  if (e.listener) e.listener(news);
}

std::vector<std::string> ErrandMarket::excluded(const Errand& e) const {
  std::set<std::string> all = e.excluded;
  all.insert(unavailable_.begin(), unavailable_.end());
  return {all.begin(), all.end()};
}

void ErrandMarket::stop_messages(Errand& e) {
  if (e.closer) e.closer->cancel();
  if (e.announcer) e.announcer->complete();
  if (e.awarder) e.awarder->complete();
}

void ErrandMarket::next() {
  while (active_.empty() && !queue_.empty()) {
    const std::string id = queue_.front();
    queue_.pop_front();
    auto it = errands_.find(id);
    if (it == errands_.end()) continue;  // released while queued
    active_ = id;
    start_round(id, it->second);
  }
}

void ErrandMarket::start_round(const std::string& id, Errand& e) {
  stop_messages(e);
  e.between_rounds = false;
  ++e.round;
  e.robot.clear();
  e.held = false;
  e.cost = 0;
  e.bids.clear();
  e.bidders.clear();
  e.declined.clear();
  e.round_started = Clock::now();
  const auto& c = agent().config();
  const ErrandAuctionMessage m{id, e.round, agent().id(), e.stop, static_cast<std::int32_t>(c.bid_window.count()),
                               excluded(e)};
  const int copies = std::max(1, options_.announcements);
  e.announcer = std::make_shared<GroupAction>(
      [this, m] {
        agent().broadcast(m);
        return false;
      },
      std::max(std::chrono::milliseconds(1), c.bid_window / copies), copies);
  const int round = e.round;
  e.closer = agent().after(c.bid_window, [this, id, round] {
    auto it = errands_.find(id);
    if (it != errands_.end() && it->second.round == round && it->second.robot.empty()) close_round(id);
  });
  agent().emit({{"event", "errand_auction"},
                {"errand", id},
                {"round", e.round},
                {"stop", e.stop.name.empty() ? fmt::format("{:.2f},{:.2f}", e.stop.x, e.stop.y) : e.stop.name},
                {"exclude", m.exclude}});
  actions_->handle(e.announcer);
}

void ErrandMarket::on_bid(const BidMessage& m, const Envelope& env) {
  auto it = errands_.find(m.task_id);
  if (it == errands_.end() || m.robot != env.sender) return;
  Errand& e = it->second;
  // A bid of an earlier round still counts while this round is open (a robot's cost does not
  // depend on the round); a bid for a later round than this one cannot be genuine.
  if (m.round > e.round || !e.robot.empty()) return;
  const auto out = excluded(e);
  if (std::find(out.begin(), out.end(), m.robot) != out.end()) return;
  if (!(m.cost >= 0) || !std::isfinite(m.cost)) return;
  // A late bid for a round already closed without bids: the next round opens now instead of
  // after its pause, and the bid counts there.
  if (e.between_rounds) start_round(m.task_id, e);
  e.bids[m.robot] = m.cost;
  e.bidders[m.robot] = env.from;
  if (every_robot_bid(e)) close_round(m.task_id);
}

void ErrandMarket::on_decline(const DeclineMessage& m, const Envelope& env) {
  auto it = errands_.find(m.task_id);
  if (it == errands_.end() || m.robot != env.sender) return;
  Errand& e = it->second;
  // Only this round's: a robot that could not bid in an earlier one may bid in this one.
  if (m.round != e.round || !e.robot.empty() || e.between_rounds || e.bids.contains(m.robot)) return;
  if (!e.declined.emplace(m.robot, m.reason).second) return;
  agent().emit({{"event", "errand_declined"}, {"errand", m.task_id}, {"round", e.round}, {"robot", m.robot},
                {"reason", m.reason}});
  if (every_robot_bid(e)) close_round(m.task_id);
}

void ErrandMarket::close_round(const std::string& id) {
  Errand& e = errands_.at(id);
  if (!e.robot.empty()) return;
  if (e.closer) e.closer->cancel();
  if (e.announcer) e.announcer->complete();
  if (e.bids.empty()) {
    if (e.round >= options_.max_rounds) {
      ErrandNews news;
      news.kind = ErrandNews::Kind::unassigned;
      news.errand = id;
      news.round = e.round;
      news.excluded = excluded(e);
      news.reason = fmt::format("no robot bid in {} rounds", e.round);
      agent().emit({{"event", "errand_unassigned"}, {"errand", id}, {"round", e.round}, {"reason", news.reason}});
      auto listener = std::move(e.listener);
      errands_.erase(id);
      if (active_ == id) active_.clear();
      if (listener) listener(news);
      next();
      return;
    }
    const int round = e.round;
    agent().emit({{"event", "errand_no_bids"}, {"errand", id}, {"round", round}});
    e.between_rounds = true;
    e.closer = agent().after(agent().config().bid_window, [this, id, round] {
      auto it = errands_.find(id);
      if (it != errands_.end() && it->second.round == round && it->second.robot.empty()) start_round(id, it->second);
    });
    return;
  }
  const auto best = winning_bid(e.bids);
  e.robot = best->first;
  e.cost = best->second;
  const ErrandAwardMessage award{id, e.round, e.robot, e.stop, e.cost};
  const auto to = e.bidders.at(e.robot);
  const int round = e.round;
  const std::string winner = e.robot;
  e.awarder = std::make_shared<GroupAction>(
      [this, award, to] {
        agent().send(to, award);
        return false;  // until AWARD_ACK completes it
      },
      agent().config().retry_period, agent().config().max_retries, [this, id, round, winner] {
        auto it = errands_.find(id);
        if (it == errands_.end() || it->second.round != round || it->second.held) return;
        auction_again(id, it->second, winner, winner + " did not acknowledge the award");
      });
  actions_->handle(e.awarder);
}

void ErrandMarket::auction_again(std::string id, Errand& e, const std::string& robot, const std::string& why) {
  e.excluded.insert(robot);
  tell(e, ErrandNews{ErrandNews::Kind::reauctioned, id, e.round, robot, e.cost, e.bids, excluded(e), why, 0});
  if (auto it = errands_.find(id); it != errands_.end()) start_round(id, it->second);  // the listener may release it
}

void ErrandMarket::on_award_ack(const AwardAckMessage& m, const Envelope& env) {
  auto it = errands_.find(m.task_id);
  if (it == errands_.end() || m.robot != env.sender) return;
  Errand& e = it->second;
  if (m.round != e.round || e.robot != m.robot || e.held) return;
  if (e.awarder) e.awarder->complete();
  if (!m.accepted) {
    auction_again(m.task_id, e, m.robot, m.robot + " refused the award: " + m.reason);
    return;
  }
  e.held = true;
  const double ms = std::chrono::duration<double, std::milli>(Clock::now() - e.round_started).count();
  nlohmann::json bids = nlohmann::json::object();
  for (const auto& [robot, cost] : e.bids) bids[robot] = cost;
  agent().emit({{"event", "errand_awarded"},
                {"errand", m.task_id},
                {"round", e.round},
                {"robot", e.robot},
                {"cost", e.cost},
                {"bids", bids},
                {"ms", ms}});
  const std::string id = m.task_id;
  if (active_ == id) active_.clear();
  tell(e, ErrandNews{ErrandNews::Kind::awarded, id, e.round, e.robot, e.cost, e.bids, excluded(e), "", ms});
  next();
}

void ErrandMarket::reassign(const std::string& errand, const std::string& why) {
  auto it = errands_.find(errand);
  if (it == errands_.end() || !it->second.held) return;
  Errand& e = it->second;
  const std::string robot = e.robot;
  revoke(errand, e);
  e.excluded.insert(robot);
  e.held = false;
  e.robot.clear();
  agent().emit({{"event", "errand_reauction"}, {"errand", errand}, {"robot", robot}, {"reason", why}});
  tell(e, ErrandNews{ErrandNews::Kind::reauctioned, errand, e.round, robot, e.cost, e.bids, excluded(e), why, 0});
  if (!errands_.contains(errand)) return;  // the listener released it
  queue_.push_front(errand);  // repairs go first
  next();
}

void ErrandMarket::robot_failed(const std::string& robot, const std::string& why) {
  unavailable_.insert(robot);
  lose(robot, why);
}

void ErrandMarket::lose(const std::string& robot, const std::string& why) {
  std::vector<std::string> held;
  for (const auto& [id, e] : errands_) {
    if (e.robot == robot && e.held) held.push_back(id);
  }
  for (const auto& id : held) reassign(id, why);
  // An auction waiting for its bid, or its acknowledgement, need not wait.
  if (!active_.empty()) {
    auto it = errands_.find(active_);
    if (it != errands_.end()) {
      Errand& e = it->second;
      if (e.robot == robot && !e.held) {
        auction_again(active_, e, robot, why);
      } else if (e.robot.empty()) {
        e.bids.erase(robot);
        if (!e.bids.empty() && every_robot_bid(e)) close_round(active_);
      }
    }
  }
}

void ErrandMarket::set_available(const std::string& robot) { unavailable_.erase(robot); }

void ErrandMarket::revoke(const std::string& id, const Errand& e) {
  if (e.robot.empty()) return;
  const RevokeMessage m{id, e.round, e.robot};
  auto it = e.bidders.find(e.robot);
  if (it == e.bidders.end()) return;
  const auto to = it->second;
  // No acknowledgement: a robot that misses every copy keeps a stale stop in its route, which
  // only makes its later bids too high, until the errand's auctioneer leaves or a newer round
  // of the errand is heard of.
  auto sender = std::make_shared<GroupAction>(
      [this, m, to] {
        agent().send(to, m);
        return false;
      },
      agent().config().retry_period, 3);
  revokers_.erase(std::remove_if(revokers_.begin(), revokers_.end(), [](const auto& r) { return r->done(); }),
                  revokers_.end());
  revokers_.push_back(sender);
  actions_->handle(sender);
}

void ErrandMarket::release(const std::string& errand) {
  auto it = errands_.find(errand);
  if (it == errands_.end()) return;
  Errand& e = it->second;
  stop_messages(e);
  revoke(errand, e);
  agent().emit({{"event", "errand_released"}, {"errand", errand}, {"robot", e.robot}});
  errands_.erase(it);
  // Out of the queue too: an id offered again would otherwise be auctioned once per entry.
  queue_.erase(std::remove(queue_.begin(), queue_.end(), errand), queue_.end());
  if (active_ == errand) active_.clear();
  next();
}

// --- ErrandBidder -------------------------------------------------------------------------------

ErrandBidder::ErrandBidder(std::shared_ptr<const MapPlanner> map, Locator where, Objective objective)
    : map_(std::move(map)), where_(std::move(where)), objective_(objective) {}

void ErrandBidder::init(Agent& agent) {
  SimpleOperator::init(agent);
  auto& p = agent.processor();
  p.on<ErrandAuctionMessage>([this](const ErrandAuctionMessage& m, const Envelope& e) { on_auction(m, e); });
  p.on<ErrandAwardMessage>([this](const ErrandAwardMessage& m, const Envelope& e) { on_award(m, e); });
  p.on<RevokeMessage>([this](const RevokeMessage& m, const Envelope& e) { on_revoke(m, e); });
  agent.neighbors().on_change([this](const AgentState& s, bool joined) {
    if (joined) return;
    // Stops given by an auctioneer that is gone are nobody's business any more.
    std::vector<std::pair<std::string, int>> gone;
    for (const auto& c : route_) {
      if (c.auctioneer == s.id) gone.emplace_back(c.errand, c.round);
    }
    for (const auto& [errand, round] : gone) drop(errand, round, s.id + " left");
  });
  announce_state();
  state_timer_ = agent.every(agent.config().hello_period, [this] { announce_state(); });
}

void ErrandBidder::shutdown() {
  if (state_timer_) state_timer_->cancel();
}

void ErrandBidder::announce_state() {
  if (auto at = where_()) {
    agent().set_position(at->x, at->y);
    agent().set_status(route_.empty() ? "idle" : "busy");
  } else {
    agent().set_status("failed");
  }
  agent().set_load(static_cast<int>(route_.size()));
}

std::optional<sim::Point> ErrandBidder::locate(const Place& stop) const {
  if (stop.name.empty()) {
    if (!std::isfinite(stop.x) || !std::isfinite(stop.y)) return std::nullopt;
    return sim::Point{stop.x, stop.y};
  }
  try {
    return map_->locate(stop.name);
  } catch (const CorosError&) {
    return std::nullopt;
  }
}

std::optional<double> ErrandBidder::leg(sim::Point from, sim::Point to) const {
  // A stop inside an obstacle (a user on the sofa) is driven to as near as the robot gets, as
  // the simulated world and a navigation stack do.
  if (!map_->grid().free(to)) {
    const auto near = map_->grid().nearest_free(to, kSnapDistance, from);
    if (!near) return std::nullopt;
    to = *near;
  }
  return map_->path_cost(from, to);
}

std::optional<double> ErrandBidder::cost_of(const Place& stop) const {
  const auto to = locate(stop);
  const auto here = where_();
  if (!to || !here) return std::nullopt;  // a robot that cannot work bids for nothing
  if (objective_ == Objective::append) return leg(route_.empty() ? *here : route_.back().at, *to);
  double total = 0;
  sim::Point from = *here;
  for (const auto& c : route_) {
    const auto part = leg(from, c.at);
    if (part) total += *part;  // a committed stop it cannot reach now costs nothing to skip
    from = c.at;
  }
  const auto last = leg(from, *to);
  if (!last) return std::nullopt;
  return total + *last;
}

std::vector<std::string> ErrandBidder::route() const {
  std::vector<std::string> out;
  for (const auto& c : route_) out.push_back(c.errand);
  return out;
}

void ErrandBidder::on_auction(const ErrandAuctionMessage& m, const Envelope& e) {
  if (m.auctioneer != e.sender) return;
  if (newest_round_.size() > 4096) forget_old_rounds();
  auto& newest = newest_round_[m.errand];
  if (m.round > newest) {
    newest = m.round;
    drop(m.errand, m.round - 1, fmt::format("{} auctions it again (round {})", m.auctioneer, m.round));
  }
  if (std::find(m.exclude.begin(), m.exclude.end(), agent().id()) != m.exclude.end()) return;
  for (const auto& c : route_) {
    if (c.errand == m.errand) return;  // already ours
  }
  // Every copy of an announcement gets the same bid without planning again.
  if (costs_.size() > 1024) costs_.clear();
  auto [it, planned] = costs_.try_emplace(m.errand);
  Cost& cached = it->second;
  if (planned || cached.version != version_ || cached.round != m.round) {
    cached.cost = cost_of(m.stop);
    cached.version = version_;
    cached.round = m.round;
  }
  if (!cached.cost) {
    // Said, so that the market does not wait the window out for this robot.
    const std::string reason = !locate(m.stop) ? "the stop is not on this robot's map"
                               : !where_()     ? "the robot cannot work now"
                                               : "no path to " + m.stop.name;
    agent().send(e.from, DeclineMessage{m.errand, m.round, agent().id(), reason});
    return;
  }
  agent().send(e.from, BidMessage{m.errand, m.round, agent().id(), *cached.cost});
}

void ErrandBidder::on_award(const ErrandAwardMessage& m, const Envelope& e) {
  if (m.robot != agent().id()) return;
  auto& newest = newest_round_[m.errand];
  if (m.round < newest) {
    agent().send(e.from, AwardAckMessage{m.errand, m.round, agent().id(), false,
                                         fmt::format("round {} is stale (round {} heard of)", m.round, newest)});
    return;
  }
  newest = m.round;
  const bool known = std::any_of(route_.begin(), route_.end(), [&](const Commitment& c) { return c.errand == m.errand; });
  if (!known) {
    const auto at = locate(m.stop);
    if (!at || !where_()) {
      agent().send(e.from, AwardAckMessage{m.errand, m.round, agent().id(), false,
                                           at ? "the robot cannot work now" : "the stop is not on this robot's map"});
      return;
    }
    route_.push_back(Commitment{m.errand, e.sender, m.round, *at});
    ++version_;
    costs_.erase(m.errand);
    agent().emit({{"event", "errand_taken"}, {"errand", m.errand}, {"round", m.round}, {"cost", m.cost},
                  {"route", route_.size()}});
    announce_state();
  }
  agent().send(e.from, AwardAckMessage{m.errand, m.round, agent().id(), true, ""});
}

void ErrandBidder::on_revoke(const RevokeMessage& m, const Envelope& e) {
  if (m.robot != agent().id()) return;
  for (const auto& c : route_) {
    if (c.errand == m.task_id && c.auctioneer != e.sender) return;  // only its auctioneer may
  }
  drop(m.task_id, m.round, "released by " + e.sender);
}

void ErrandBidder::forget_old_rounds() {
  std::map<std::string, int> kept;
  for (const auto& c : route_) kept[c.errand] = newest_round_[c.errand];
  newest_round_ = std::move(kept);
}

void ErrandBidder::drop(const std::string& errand, int up_to_round, const std::string& why) {
  const auto before = route_.size();
  route_.erase(std::remove_if(route_.begin(), route_.end(),
                              [&](const Commitment& c) { return c.errand == errand && c.round <= up_to_round; }),
               route_.end());
  if (route_.size() == before) return;
  ++version_;
  costs_.erase(errand);
  agent().emit({{"event", "errand_dropped"}, {"errand", errand}, {"reason", why}, {"route", route_.size()}});
  announce_state();
}

}  // namespace icars::coros
