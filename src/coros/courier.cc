#include "icars/coros/courier.h"

#include <fmt/format.h>

#include <algorithm>

namespace icars::coros {

namespace {
std::string round_key(const std::string& task, int round) {
  return fmt::format("{}#{}", task, round);
}
sim::Point at(const Place& p) { return {p.x, p.y}; }
}  // namespace

CourierDeliveryTask::CourierDeliveryTask(const Place& pickup, const Place& dropoff)
    : SequenceTask("deliver from " + pickup.name + " to " + dropoff.name,
                   {std::make_shared<MoveToTask>(pickup.name, at(pickup)),
                    std::make_shared<MoveToTask>(dropoff.name, at(dropoff))}) {}

// --- the robot's side ----------------------------------------------------------------------

CourierRobotOperator::CourierRobotOperator(std::shared_ptr<Robot> robot,
                                           std::shared_ptr<const MapPlanner> map)
    : RobotOperator(std::move(robot)), map_(std::move(map)) {}

CourierRobotOperator::~CourierRobotOperator() {
  planner_.stop();
  planner_.join();
}

void CourierRobotOperator::shutdown() {
  planner_.stop();
  planner_.join();  // a plan in progress finishes; its answer is posted to a stopping agent
  RobotOperator::shutdown();
}

void CourierRobotOperator::init(Agent& agent) {
  RobotOperator::init(agent);
  auto& p = agent.processor();
  p.on<AuctionMessage>([this](const AuctionMessage& m, const Envelope& e) { on_auction(m, e); });
  p.on<AwardMessage>([this](const AwardMessage& m, const Envelope& e) { on_award(m, e); });
  p.on<RevokeMessage>([this](const RevokeMessage& m, const Envelope& e) { on_revoke(m, e); });
  p.on<ResultAckMessage>(
      [this](const ResultAckMessage& m, const Envelope& e) { on_result_ack(m, e); });
  // Task states are broadcast at every stage and again every few HELLO periods, so monitors
  // that missed a datagram catch up.
  status_timer_ = agent.every(agent.config().hello_period * 3, [this] {
    for (auto& [id, a] : assignments_) {
      TaskStatusMessage s{a.task_id,
                          a.round,
                          this->agent().id(),
                          a.auctioneer,
                          std::string(to_string(a.stage)),
                          a.distance,
                          Agent::wall_seconds()};
      this->agent().broadcast(s);
    }
  });
}

CourierRobotOperator::Route CourierRobotOperator::route() const {
  Route r;
  r.from = robot().pose().position();
  for (const auto& key : performer().keys()) {
    const auto it = assignments_.find(key);
    if (it == assignments_.end()) continue;
    r.legs.push_back(
        {it->second.pickup, it->second.dropoff, it->second.stage >= TaskStage::picked_up});
  }
  return r;
}

std::optional<double> CourierRobotOperator::route_cost(const MapPlanner& map, const Route& route,
                                                       const Place& pickup, const Place& dropoff) {
  // The distance the robot would drive until the new delivery is done: what is left of its
  // queue, in order, then to the pickup and on to the dropoff.
  sim::Point from = route.from;
  double total = 0;
  auto leg = [&](const Place& to) {
    const auto c = map.path_cost(from, at(to));
    if (!c) return false;
    total += *c;
    from = at(to);
    return true;
  };
  for (const auto& l : route.legs) {
    if (!l.picked_up && !leg(l.pickup)) return std::nullopt;
    if (!leg(l.dropoff)) return std::nullopt;
  }
  if (!leg(pickup) || !leg(dropoff)) return std::nullopt;
  return total;
}

std::optional<double> CourierRobotOperator::cost_of(const Place& pickup,
                                                    const Place& dropoff) const {
  return route_cost(*map_, route(), pickup, dropoff);
}

void CourierRobotOperator::on_auction(const AuctionMessage& m, const Envelope& e) {
  int& newest = newest_round_[m.task_id];
  newest = std::max(newest, m.round);
  if (auto it = assignments_.find(m.task_id);
      it != assignments_.end() && it->second.round < m.round) {
    drop(m.task_id, fmt::format("the task is auctioned again (round {})", m.round));
  }
  if (std::find(m.exclude.begin(), m.exclude.end(), agent().id()) != m.exclude.end()) return;
  if (assignments_.contains(m.task_id) || finished_.contains(round_key(m.task_id, m.round))) return;
  if (robot().status() == RobotStatus::failed) {
    agent().send(e.from, DeclineMessage{m.task_id, m.round, agent().id(), "the robot has failed"});
    return;
  }
  const std::string key = round_key(m.task_id, m.round);
  if (auto bid = bids_.find(key); bid != bids_.end()) {
    agent().send(e.from, BidMessage{m.task_id, m.round, agent().id(), bid->second});
    return;
  }
  // A task auctioned again costs what it cost in the last round, as long as this robot's
  // commitments have not changed and it has not moved on since.
  auto& waiting = planning_[m.task_id];
  if (std::find(waiting.begin(), waiting.end(), std::pair{e.from, m.round}) == waiting.end()) {
    waiting.emplace_back(e.from, m.round);
  }
  if (auto c = costs_.find(m.task_id); c != costs_.end() &&
                                       c->second.route_version == route_version_ &&
                                       Clock::now() - c->second.at < std::chrono::seconds(2)) {
    bid(m, c->second.cost);
    return;
  }
  if (waiting.size() > 1) return;  // being planned: answered with the others
  // Planning takes milliseconds to a good part of a second on a big map: it runs on the
  // planner thread so HELLOs and acks keep flowing; copies of the auction (of any round) that
  // arrive meanwhile are answered together when the cost is known.
  asio::post(planner_, [this, m, r = route(), map = map_, version = route_version_] {
    const auto cost = route_cost(*map, r, m.pickup, m.dropoff);
    agent().post([this, m, cost, version] {
      if (version == route_version_) costs_[m.task_id] = {version, cost, Clock::now()};
      bid(m, cost);
    });
  });
}

void CourierRobotOperator::bid(const AuctionMessage& m, std::optional<double> cost) {
  const auto waiting = std::move(planning_[m.task_id]);
  planning_.erase(m.task_id);
  if (!cost) {
    const std::string reason = "no path to " + m.pickup.name + " or " + m.dropoff.name;
    agent().emit({{"event", "no_bid"}, {"task", m.task_id}, {"round", m.round}, {"reason", reason}});
    // Said, so that the auctioneer does not wait the window out for this robot.
    for (const auto& [to, round] : waiting) agent().send(to, DeclineMessage{m.task_id, round, agent().id(), reason});
    return;
  }
  // Every auction copy that waited gets the bid of its own round; the auctioneer also counts
  // a bid of an earlier round while the current one is open.
  for (const auto& [to, round] : waiting) {
    if (bids_.emplace(round_key(m.task_id, round), *cost).second) {
      agent().emit({{"event", "bid"}, {"task", m.task_id}, {"round", round}, {"cost", *cost}});
    }
    agent().send(to, BidMessage{m.task_id, round, agent().id(), *cost});
  }
}

void CourierRobotOperator::on_award(const AwardMessage& m, const Envelope& e) {
  if (m.robot != agent().id()) return;
  auto ack = [&](bool accepted, const std::string& reason) {
    agent().send(e.from, AwardAckMessage{m.task_id, m.round, agent().id(), accepted, reason});
  };
  const std::string key = round_key(m.task_id, m.round);
  int& newest = newest_round_[m.task_id];
  if (m.round < newest) {
    ack(false, fmt::format("round {} is stale, round {} exists", m.round, newest));
    return;
  }
  newest = m.round;
  if (finished_.contains(key)) {
    ack(true, "");
    return;
  }
  if (auto it = assignments_.find(m.task_id); it != assignments_.end()) {
    if (it->second.round == m.round) {
      ack(true, "");  // a copy of an award already taken
      return;
    }
    drop(m.task_id, fmt::format("replaced by round {}", m.round));
  }
  Assignment a;
  a.task_id = m.task_id;
  a.auctioneer = e.sender;
  a.round = m.round;
  a.pickup = m.pickup;
  a.dropoff = m.dropoff;
  a.reply_to = e.from;
  a.started_s = robot().clock_seconds();
  a.start_odometer = robot().odometer();
  assignments_.emplace(m.task_id, a);
  ++route_version_;
  ack(true, "");
  set_stage(assignments_.at(m.task_id), TaskStage::assigned);

  auto task = std::make_shared<CourierDeliveryTask>(m.pickup, m.dropoff);
  const std::string task_id = m.task_id;
  task->on_step([this, task_id](std::size_t step) {
    auto it = assignments_.find(task_id);
    if (it == assignments_.end()) return;
    if (step == 0) {
      it->second.start_odometer = robot().odometer();  // it may have waited in the queue
      set_stage(it->second, TaskStage::to_pickup);
    }
    if (step == 1) {
      set_stage(it->second, TaskStage::picked_up);
      set_stage(it->second, TaskStage::to_dropoff);
    }
  });
  performer().perform(task_id, task,
                      [this](const std::string& id, TaskOutcome outcome) { finish(id, outcome); });
  refresh_state();
}

void CourierRobotOperator::set_stage(Assignment& a, TaskStage stage) {
  a.stage = stage;
  if (stage != TaskStage::delivered && stage != TaskStage::failed) {
    a.distance = robot().odometer() - a.start_odometer;
  }
  agent().emit({{"event", "task_stage"},
                {"task", a.task_id},
                {"round", a.round},
                {"stage", to_string(stage)},
                {"distance", a.distance}});
  TaskState s;
  s.id = a.task_id;
  s.auctioneer = a.auctioneer;
  s.robot = agent().id();
  s.round = a.round;
  s.stage = stage;
  s.pickup = a.pickup;
  s.dropoff = a.dropoff;
  s.distance = a.distance;
  s.updated = Clock::now();
  agent().tasks().update(s);
  agent().broadcast(TaskStatusMessage{a.task_id, a.round, agent().id(), a.auctioneer,
                                      std::string(to_string(stage)), a.distance,
                                      Agent::wall_seconds()});
}

void CourierRobotOperator::finish(const std::string& task_id, const TaskOutcome& outcome) {
  auto it = assignments_.find(task_id);
  if (it == assignments_.end()) return;
  Assignment& a = it->second;
  a.distance = outcome.distance;
  set_stage(a, outcome.success ? TaskStage::delivered : TaskStage::failed);
  ++route_version_;
  finished_.insert(round_key(a.task_id, a.round));
  const ResultMessage result{a.task_id,        a.round,
                             agent().id(),     outcome.success,
                             outcome.distance, robot().clock_seconds() - a.started_s,
                             outcome.detail};
  const auto to = a.reply_to;
  a.result_sender = std::make_shared<GroupAction>(
      [this, result, to] {
        agent().send(to, result);
        return false;  // until RESULT_ACK completes it
      },
      agent().config().retry_period, agent().config().max_retries,
      [this, task_id] {
        // Keep the assignment: its "delivered" state is still broadcast every few HELLO
        // periods, and the auctioneer takes that as the result.
        agent().emit({{"event", "result_unacknowledged"}, {"task", task_id}});
      });
  actions().handle(a.result_sender);
  refresh_state();
}

void CourierRobotOperator::on_result_ack(const ResultAckMessage& m, const Envelope&) {
  auto it = assignments_.find(m.task_id);
  if (it == assignments_.end() || it->second.round != m.round) return;
  if (it->second.result_sender) it->second.result_sender->complete();
  assignments_.erase(it);
}

void CourierRobotOperator::on_revoke(const RevokeMessage& m, const Envelope&) {
  int& newest = newest_round_[m.task_id];
  newest = std::max(newest, m.round + 1);
  auto it = assignments_.find(m.task_id);
  if (it != assignments_.end() && it->second.round <= m.round && !it->second.result_sender) {
    drop(m.task_id, "revoked by " + it->second.auctioneer);
  }
}

void CourierRobotOperator::drop(const std::string& task_id, const std::string& why) {
  auto it = assignments_.find(task_id);
  if (it == assignments_.end()) return;
  if (it->second.result_sender) it->second.result_sender->complete();
  agent().emit(
      {{"event", "dropped"}, {"task", task_id}, {"round", it->second.round}, {"reason", why}});
  performer().cancel(task_id);
  assignments_.erase(it);
  ++route_version_;
  refresh_state();
}

// --- the user's side: the auctioneer -------------------------------------------------------

CourierUserOperator::CourierUserOperator(std::shared_ptr<const MapPlanner> map, Options options)
    : map_(std::move(map)), options_(options) {}

void CourierUserOperator::init(Agent& agent) {
  SimpleOperator::init(agent);
  actions_ = std::make_unique<ActionHandler>(agent);
  auto& p = agent.processor();
  p.on<BidMessage>([this](const BidMessage& m, const Envelope& e) { on_bid(m, e); });
  p.on<DeclineMessage>([this](const DeclineMessage& m, const Envelope& e) { on_decline(m, e); });
  p.on<AwardAckMessage>(
      [this](const AwardAckMessage& m, const Envelope& e) { on_award_ack(m, e); });
  p.on<TaskStatusMessage>(
      [this](const TaskStatusMessage& m, const Envelope& e) { on_status(m, e); });
  p.on<ResultMessage>([this](const ResultMessage& m, const Envelope& e) { on_result(m, e); });
  agent.neighbors().on_change([this](const AgentState& s, bool joined) {
    if (!joined) on_neighbor_left(s);
  });
  if (!agent.config().deliveries.empty()) start_configured_deliveries();
}

void CourierUserOperator::shutdown() {
  for (auto& [id, a] : auctions_) {
    if (a.closer) a.closer->cancel();
    if (a.announcer) a.announcer->complete();
    if (a.awarder) a.awarder->complete();
  }
  if (start_timer_) start_timer_->cancel();
  delivery_timers_.clear();
}

void CourierUserOperator::start_configured_deliveries() {
  const auto begun = Clock::now();
  start_timer_ = agent().every(std::chrono::milliseconds(50), [this, begun] {
    const auto& c = agent().config();
    const auto robots = static_cast<int>(agent().neighbors().neighbors_with_role("robot").size());
    const bool enough = c.expect_robots > 0 && robots >= c.expect_robots;
    if (!enough && Clock::now() - begun < c.start_after) return;
    start_timer_->cancel();
    agent().emit(
        {{"event", "deliveries_start"}, {"robots", robots}, {"deliveries", c.deliveries.size()}});
    configured_started_ = true;
    for (std::size_t i = 0; i < c.deliveries.size(); ++i) {
      const auto [pickup, dropoff] = c.deliveries[i];
      const auto delay = c.delivery_interval * static_cast<std::int64_t>(i);
      auto go = [this, pickup = pickup, dropoff = dropoff] {
        try {
          request(pickup, dropoff);
        } catch (const CorosError& e) {
          agent().emit({{"event", "delivery_rejected"},
                        {"pickup", pickup},
                        {"dropoff", dropoff},
                        {"error", e.what()}});
          ++rejected_;
          check_all_done();
        }
      };
      if (delay.count() == 0) {
        go();
      } else {
        delivery_timers_.push_back(agent().after(delay, go));
      }
    }
    check_all_done();  // when every configured delivery was rejected
  });
}

std::string CourierUserOperator::request(const std::string& pickup, const std::string& dropoff) {
  const sim::Point a = map_->locate(pickup), b = map_->locate(dropoff);
  DeliveryRecord record;
  record.task_id = fmt::format("{}-{}", agent().id(), next_task_++);
  record.pickup = Place{pickup, a.x, a.y};
  record.dropoff = Place{dropoff, b.x, b.y};
  record.requested = Clock::now();
  const std::string id = record.task_id;
  start_round(deliveries_.emplace(id, std::move(record)).first->second);
  return id;
}

TaskState CourierUserOperator::state_of(const DeliveryRecord& r, TaskStage stage) const {
  TaskState s;
  s.id = r.task_id;
  s.auctioneer = agent().id();
  s.robot = r.robot;
  s.round = r.round;
  s.stage = stage;
  s.pickup = r.pickup;
  s.dropoff = r.dropoff;
  s.cost = r.cost;
  s.distance = r.distance;
  s.updated = Clock::now();
  return s;
}

bool CourierUserOperator::all_finished() const {
  return std::all_of(deliveries_.begin(), deliveries_.end(),
                     [](const auto& d) { return d.second.finished; });
}

void CourierUserOperator::start_round(DeliveryRecord& record) {
  ++record.round;
  record.robot.clear();
  record.bids.clear();
  record.cost = 0;
  record.auction_started = Clock::now();
  Auction& au = auctions_[record.task_id];
  if (au.closer) au.closer->cancel();
  if (au.announcer) au.announcer->complete();
  if (au.awarder) au.awarder->complete();
  au = Auction{};

  const auto& c = agent().config();
  const AuctionMessage m{record.task_id, record.round,
                         agent().id(),   record.pickup,
                         record.dropoff, static_cast<std::int32_t>(c.bid_window.count()),
                         record.excluded};
  const int copies = std::max(1, options_.announcements);
  au.announcer = std::make_shared<GroupAction>(
      [this, m] {
        agent().broadcast(m);
        return false;
      },
      std::max(std::chrono::milliseconds(1), c.bid_window / copies), copies);
  const std::string id = record.task_id;
  const int round = record.round;
  au.closer = agent().after(c.bid_window, [this, id, round] {
    auto it = deliveries_.find(id);
    if (it != deliveries_.end() && it->second.round == round) close_round(id);
  });
  agent().tasks().update(state_of(record, TaskStage::announced));
  agent().emit({{"event", "auction"},
                {"task", id},
                {"round", round},
                {"pickup", record.pickup.name},
                {"dropoff", record.dropoff.name},
                {"exclude", record.excluded}});
  actions_->handle(au.announcer);
}

void CourierUserOperator::on_bid(const BidMessage& m, const Envelope& e) {
  auto it = deliveries_.find(m.task_id);
  if (it == deliveries_.end()) return;
  DeliveryRecord& r = it->second;
  // A bid of an earlier round of this task still counts while the current round is open: a
  // robot's cost does not depend on the round, and a slow planner's bid is not wasted.
  if (r.finished || m.round > r.round || !r.robot.empty() || m.robot != e.sender) return;
  if (std::find(r.excluded.begin(), r.excluded.end(), m.robot) != r.excluded.end()) return;
  if (!(m.cost >= 0) || !std::isfinite(m.cost)) return;
  // A late bid for a round already closed without bids: the next round (already announced in
  // the "reauction" event) opens now instead of after its pause, and the bid counts there.
  Auction& au = auctions_[m.task_id];
  if (au.between_rounds) start_round(r);  // resets `au` for the new round
  if (!r.bids.contains(m.robot)) {
    agent().emit({{"event", "bid_received"},
                  {"task", m.task_id},
                  {"round", r.round},
                  {"bid_round", m.round},
                  {"robot", m.robot},
                  {"cost", m.cost}});
  }
  r.bids[m.robot] = m.cost;
  au.bidders[m.robot] = e.from;
  if (every_known_robot_bid(r)) close_round(m.task_id);
}

void CourierUserOperator::on_decline(const DeclineMessage& m, const Envelope& e) {
  auto it = deliveries_.find(m.task_id);
  if (it == deliveries_.end() || m.robot != e.sender) return;
  DeliveryRecord& r = it->second;
  // Only this round's: a robot that could not bid in an earlier one may bid in this one. A round
  // that already closed (won, or without bids and pausing) has nothing to wait for.
  if (r.finished || m.round != r.round || !r.robot.empty() || r.bids.contains(m.robot)) return;
  Auction& au = auctions_[m.task_id];
  if (au.between_rounds || !au.declined.emplace(m.robot, m.reason).second) return;
  agent().emit({{"event", "declined"}, {"task", m.task_id}, {"round", r.round}, {"robot", m.robot}, {"reason", m.reason}});
  if (every_known_robot_bid(r)) close_round(m.task_id);
}

bool CourierUserOperator::every_known_robot_bid(const DeliveryRecord& r) const {
  const auto au = auctions_.find(r.task_id);
  for (const auto& n : agent().neighbors().neighbors_with_role("robot")) {
    if (std::find(r.excluded.begin(), r.excluded.end(), n.id) != r.excluded.end()) continue;
    if (au != auctions_.end() && au->second.declined.contains(n.id)) continue;
    if (!r.bids.contains(n.id)) return false;
  }
  return true;
}

void CourierUserOperator::close_round(const std::string& task_id) {
  DeliveryRecord& r = deliveries_.at(task_id);
  Auction& au = auctions_[task_id];
  if (!r.robot.empty() || r.finished) return;
  if (au.closer) au.closer->cancel();
  if (au.announcer) au.announcer->complete();
  if (r.bids.empty()) {
    r.history.push_back(fmt::format("round {}: no bids", r.round));
    if (r.round >= options_.max_rounds) {
      r.finished = true;
      r.detail = fmt::format("no robot bid in {} rounds", r.round);
      conclude(r);
      return;
    }
    agent().emit(
        {{"event", "reauction"}, {"task", task_id}, {"round", r.round + 1}, {"reason", "no bids"}});
    au.between_rounds = true;
    const int round = r.round;
    au.closer = agent().after(agent().config().bid_window, [this, task_id, round] {
      auto it = deliveries_.find(task_id);
      if (it != deliveries_.end() && it->second.round == round && !it->second.finished) {
        start_round(it->second);
      }
    });
    return;
  }
  const auto best = winning_bid(r.bids);
  r.robot = best->first;
  r.cost = best->second;
  r.history.push_back(fmt::format("round {}: {} won at {:.2f} m of {} bids", r.round, r.robot,
                                  r.cost, r.bids.size()));
  nlohmann::json bids = nlohmann::json::object();
  for (const auto& [robot, cost] : r.bids) bids[robot] = cost;
  agent().emit({{"event", "awarded"},
                {"task", task_id},
                {"round", r.round},
                {"robot", r.robot},
                {"cost", r.cost},
                {"bids", bids}});
  const AwardMessage award{task_id, r.round, r.robot, r.pickup, r.dropoff, r.cost};
  const auto to = au.bidders.at(r.robot);
  const int round = r.round;
  const std::string winner = r.robot;
  au.awarder = std::make_shared<GroupAction>(
      [this, award, to] {
        agent().send(to, award);
        return false;  // until AWARD_ACK completes it
      },
      agent().config().retry_period, agent().config().max_retries,
      [this, task_id, round, winner] {
        auto it = deliveries_.find(task_id);
        if (it == deliveries_.end() || it->second.round != round) return;
        reauction(it->second, winner, winner + " did not acknowledge the award");
      });
  actions_->handle(au.awarder);
}

void CourierUserOperator::on_award_ack(const AwardAckMessage& m, const Envelope&) {
  auto it = deliveries_.find(m.task_id);
  if (it == deliveries_.end()) return;
  DeliveryRecord& r = it->second;
  if (r.finished || m.round != r.round || m.robot != r.robot) return;  // stale or stray
  Auction& au = auctions_[m.task_id];
  if (!au.awarder || au.awarder->done()) return;  // a copy of an ack already handled
  au.awarder->complete();
  if (!m.accepted) {
    reauction(r, m.robot, m.robot + " refused: " + m.reason);
    return;
  }
  r.assigned_at = Clock::now();
  agent().tasks().update(state_of(r, TaskStage::assigned));
  agent().emit(
      {{"event", "assigned"}, {"task", r.task_id}, {"round", r.round}, {"robot", r.robot}});
}

void CourierUserOperator::on_status(const TaskStatusMessage& m, const Envelope& e) {
  TaskState s = TaskState::from_status(m, e.sender);
  if (auto it = deliveries_.find(m.task_id); it != deliveries_.end()) {
    s.pickup = it->second.pickup;
    s.dropoff = it->second.dropoff;
    s.cost = it->second.cost;
    // A status from the current round's robot also confirms the award (its ack was lost).
    DeliveryRecord& r = it->second;
    Auction& au = auctions_[m.task_id];
    if (m.round == r.round && m.robot == r.robot && au.awarder && !au.awarder->done()) {
      on_award_ack(AwardAckMessage{m.task_id, m.round, m.robot, true, ""}, e);
    }
    // A "delivered" state from the current round's robot stands for a RESULT that was lost
    // every time it was sent.
    if (s.stage == TaskStage::delivered && m.round == r.round && m.robot == r.robot &&
        !r.finished) {
      on_result(ResultMessage{m.task_id, m.round, m.robot, true, m.distance, 0,
                              "result taken from the robot's task state"},
                e);
      return;
    }
  }
  agent().tasks().update(s);
}

void CourierUserOperator::on_result(const ResultMessage& m, const Envelope& e) {
  agent().send(e.from, ResultAckMessage{m.task_id, m.round, m.robot});  // stops the resending
  auto it = deliveries_.find(m.task_id);
  if (it == deliveries_.end()) return;
  DeliveryRecord& r = it->second;
  if (r.finished || m.round != r.round || m.robot != r.robot) return;
  if (!m.success) {
    reauction(r, m.robot, m.robot + " failed: " + m.detail);
    return;
  }
  r.success = true;
  r.distance = m.distance;
  r.duration_s = m.duration_s;
  r.detail = m.detail;
  r.history.push_back(fmt::format("round {}: {} delivered, {:.2f} m in {:.1f} s", r.round, m.robot,
                                  m.distance, m.duration_s));
  agent().tasks().update(state_of(r, TaskStage::delivered));
  conclude(r);
}

void CourierUserOperator::conclude(DeliveryRecord& r) {
  r.finished = true;
  r.finished_at = Clock::now();
  if (auto au = auctions_.find(r.task_id); au != auctions_.end()) {
    if (au->second.closer) au->second.closer->cancel();
    if (au->second.announcer) au->second.announcer->complete();
    if (au->second.awarder) au->second.awarder->complete();
  }
  agent().emit({{"event", "delivery_finished"},
                {"task", r.task_id},
                {"robot", r.robot},
                {"success", r.success},
                {"distance", r.distance},
                {"duration_s", r.duration_s},
                {"rounds", r.round},
                {"detail", r.detail},
                {"history", r.history}});
  if (finished_fn_) finished_fn_(r);
  check_all_done();
}

void CourierUserOperator::check_all_done() {
  const auto& wanted = agent().config().deliveries;
  if (all_done_sent_ || !configured_started_ || !all_finished() ||
      deliveries_.size() + rejected_ < wanted.size()) {
    return;
  }
  all_done_sent_ = true;
  int ok = 0;
  for (const auto& [id, d] : deliveries_) ok += d.success ? 1 : 0;
  agent().emit({{"event", "all_done"},
                {"deliveries", deliveries_.size() + rejected_},
                {"succeeded", ok},
                {"rejected", rejected_}});
}

void CourierUserOperator::on_neighbor_left(const AgentState& gone) {
  std::vector<std::string> open;  // auctions that may now have every bid they wait for
  for (auto& [id, r] : deliveries_) {
    if (r.finished) continue;
    if (r.robot.empty()) {
      open.push_back(id);
      continue;
    }
    if (r.robot != gone.id) continue;
    agent().broadcast(RevokeMessage{r.task_id, r.round, gone.id});
    reauction(r, gone.id,
              fmt::format("{} stopped answering (no HELLO for {} ms)", gone.id,
                          agent().config().neighbor_expiry.count()));
  }
  // A robot that left without bidding is no longer waited for.
  for (const auto& id : open) {
    const DeliveryRecord& r = deliveries_.at(id);
    if (r.robot.empty() && !r.finished && !r.bids.empty() && every_known_robot_bid(r)) {
      close_round(id);
    }
  }
}

void CourierUserOperator::reauction(DeliveryRecord& r, const std::string& robot,
                                    const std::string& why) {
  if (r.finished) return;
  if (std::find(r.excluded.begin(), r.excluded.end(), robot) == r.excluded.end()) {
    r.excluded.push_back(robot);
  }
  r.history.push_back(fmt::format("round {}: {}", r.round, why));
  agent().emit(
      {{"event", "reauction"}, {"task", r.task_id}, {"round", r.round + 1}, {"reason", why}});
  if (r.round >= options_.max_rounds) {
    r.finished = true;
    r.detail = fmt::format("gave up after {} rounds: {}", r.round, why);
    conclude(r);
    return;
  }
  start_round(r);
}

}  // namespace icars::coros
