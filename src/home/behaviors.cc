// The smart-home behaviors. Each one is an ECA behavior: entry binds services and subscribes,
// handle_event holds its rules, every service call is asynchronous (the runtime never waits on
// the network), and whatever it holds is released at exit by the behavior model.
#include "icars/home/behaviors.h"

#include "icars/home/robot_market.h"

#include "speech_listener.h"
#include "voice_commands.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <map>
#include <memory>
#include <numbers>
#include <set>

namespace icars::home {

namespace s = icars::service;
using namespace icars::behavior;  // the behavior model these behaviors are written in

namespace {

std::string lower(std::string text) {
  std::transform(text.begin(), text.end(), text.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return text;
}

bool mentions(const std::string& text, std::string_view words) { return text.find(words) != std::string::npos; }

// The first integer in `text` ("channel 5" → 5).
std::optional<int> number_in(const std::string& text) {
  for (std::size_t i = 0; i < text.size(); ++i) {
    if (!std::isdigit(static_cast<unsigned char>(text[i]))) continue;
    int v = 0;
    for (; i < text.size() && std::isdigit(static_cast<unsigned char>(text[i])) && v < 100000; ++i) {
      v = v * 10 + (text[i] - '0');
    }
    return v;
  }
  return std::nullopt;
}

// --- Sense ----------------------------------------------------------------------------------------

// Propagates the events of every sensor service of a type (optionally in one room): those in
// the container at entry, available or not (an adaptor's events flow again when its device
// comes back), and those added while it runs, among them a device that registered again under
// its id (a new service object). It never fails for lack of sensors: a house whose device
// manager is still starting gets its sensors when they register. With report_current, an
// occupancy sensor's state is reported once it can be read: at entry, or when it registers or
// becomes available later.
class Sense final : public Behavior {
 public:
  explicit Sense(const Params& p)
      : type_(p.string("service")), room_(p.string("room")), report_current_(p.boolean("report_current")),
        phrases_(p.list("phrases")) {}

 protected:
  void entry() override {
    bound_.clear();
    // The watch before the search: a sensor registering in between is then seen by one of them
    // (or both: bind_once binds it once), never by neither.
    auto changed = guard([this](std::shared_ptr<s::Service> service, s::ServiceChange change) {
      if (!matches(*service)) return;
      if (change == s::ServiceChange::added) bind_once(service);
      if (change == s::ServiceChange::available) report_once(service);
    });
    const auto watch = services().watch([changed](const std::shared_ptr<s::Service>& service, const s::ServiceChange& change) mutable {
      changed(service, change);
    });
    on_release([this, watch] { services().remove_watcher(watch); });
    auto query = of_type(type_);
    if (!room_.empty()) query.in_room(room_);
    for (const auto& sensor : services().find(query)) bind_once(sensor);
    if (bound_.empty()) note(fmt::format("waiting for a {} service", type_));
  }

 private:
  struct Bound {
    std::weak_ptr<s::Service> service;
    bool reported = false;
  };
  bool matches(const s::Service& service) const {
    return service.type() == type_ && (room_.empty() || service.attributes().room == room_);
  }
  // Only its sensors' events are passed on: its siblings' events reach it too, and passing those
  // on would bounce them between two Sense siblings for ever.
  template <class S>
  void sense(const std::shared_ptr<S>& sensor) {
    listen(sensor, [this](const Event& e) { propagate(e); });
  }
  // Binds `sensor` unless this very object is bound already; a new object under a bound id (its
  // device registered again after it was removed) replaces the old one.
  void bind_once(const std::shared_ptr<s::Service>& sensor) {
    if (const auto it = bound_.find(sensor->id()); it != bound_.end() && it->second.service.lock() == sensor) return;
    if (bind(sensor)) {
      bound_[sensor->id()] = Bound{sensor, false};
      report_once(sensor);
    } else {
      note(fmt::format("cannot sense {}: {} publishes no events it knows", sensor->id(), sensor->type()));
    }
  }
  bool bind(const std::shared_ptr<s::Service>& sensor) {
    if (auto o = std::dynamic_pointer_cast<OccupancyService>(sensor)) return sense(o), true;
    if (auto m = std::dynamic_pointer_cast<MotionSensorService>(sensor)) return sense(m), true;
    if (auto sp = std::dynamic_pointer_cast<SpeechSensor>(sensor)) {
      // What the policy's rules listen for is what the recognizer should hear.
      if (!phrases_.empty()) on_release(sp->hold_phrases(this, phrases_));
      return sense(sp), true;
    }
    if (auto so = std::dynamic_pointer_cast<SoundSensor>(sensor)) return sense(so), true;
    if (auto sl = std::dynamic_pointer_cast<SoundLocalizer>(sensor)) return sense(sl), true;
    if (auto n = std::dynamic_pointer_cast<NavigationService>(sensor)) return sense(n), true;
    if (auto u = std::dynamic_pointer_cast<UserLocator>(sensor)) return sense(u), true;
    if (auto ms = std::dynamic_pointer_cast<MeasurementService>(sensor)) return sense(ms), true;
    return false;
  }
  // With report_current: an occupancy sensor's state, once per bound object, as soon as it is
  // available (a sensor added while its device is still binding is read when it is).
  void report_once(const std::shared_ptr<s::Service>& sensor) {
    if (!report_current_) return;
    const auto it = bound_.find(sensor->id());
    if (it == bound_.end() || it->second.reported || it->second.service.lock() != sensor) return;
    auto o = std::dynamic_pointer_cast<OccupancyService>(sensor);
    if (!o || !o->available()) return;
    it->second.reported = true;
    report_occupancy(o);
  }
  // The state now, as the sensor would have reported it when it last changed.
  void report_occupancy(const std::shared_ptr<OccupancyService>& sensor) {
    invoke(*sensor, "furniture", [&](auto done) { sensor->proxy().furniture_async(done); },
           [this, sensor](std::exception_ptr e, std::string furniture = {}) {
             if (e) return;
             invoke(*sensor, "occupied", [&](auto done) { sensor->proxy().occupied_async(done); },
                    [this, sensor, furniture](std::exception_ptr e2, bool occupied = false) {
                      if (e2) return;
                      home::OccupancyEvent current;
                      current.device = sensor->attributes().device;
                      current.furniture = furniture;
                      current.occupied = occupied;
                      current.time_ms = now().count();
                      propagate(rename(planet::to_event(current)));
                    });
           });
  }

  std::string type_;
  std::string room_;
  bool report_current_;
  std::vector<std::string> phrases_;
  std::map<std::string, Bound> bound_;  // by service id
};

// --- Errands: robots the market chooses -----------------------------------------------------------

// A behavior that sends robots the RobotMarket chooses (robot="any") to stops, each stop one
// errand: auctioned among the robots, driven by the winner when its turn comes, auctioned again
// when the robot fails it (its Navigation service went away, it stopped announcing itself, or it
// made no progress for `stall_after`), until it is reached or no robot can take it. Every award
// and re-auction is a trace record of kind "auction" with the bids (docs/trace.md).
class ErrandDriving : public Behavior {
 protected:
  // reached: the robot stands at the stop; otherwise `why` says why the stop is given up
  // (no robot bid, the stop cannot be reached).
  using Finished = std::function<void(bool reached, const std::string& robot, const std::string& why)>;

  explicit ErrandDriving(Time stall_after) : stall_after_(stall_after) {}

  void bind_market() { market_ = require<RobotMarket>(of_type("RobotMarket")); }
  // Auctions `stop` (a place name, or x/y with no name); `finished` runs once.
  void send_robot(const std::string& label, coros::Place stop, Finished finished) {
    const auto errand = market_->offer(label, stop, guard([this](ErrandUpdate u) { on_update(u); }));
    stops_[errand] = Stop{label, std::move(stop), std::move(finished), "", 0};
  }
  std::size_t open_stops() const { return stops_.size(); }
  void exit() override {
    for (const auto& [errand, stop] : stops_) market_->withdraw(errand);
    for (const auto& entry : robots_) {
      const auto nav = entry.second.nav;
      if (!entry.second.errand.empty() && nav->available() && nav->proxy().bound()) {
        invoke(*nav, "stop", [&](auto done) { nav->proxy().stop_async(done); }, [](std::exception_ptr) {});
      }
    }
    stops_.clear();
    // The robots' position listeners end with this activation: a new one (a retry, the next
    // round of a repeat) finds and listens to the robots again.
    robots_.clear();
  }
  std::shared_ptr<RobotMarket> market_;

 private:
  struct Stop {
    std::string label;
    coros::Place stop;
    Finished finished;
    std::string robot;  // the holder, "" while auctioning
    std::uint64_t stall_timer = 0;
  };
  struct Wheels {
    std::shared_ptr<NavigationService> nav;
    std::string errand;  // being driven to, "" when idle
  };

  static std::string bids_text(const ErrandUpdate& u) {
    std::vector<std::string> parts;
    for (const auto& [robot, cost] : u.bids) parts.push_back(fmt::format("{} {:.2f} m", robot, cost));
    return parts.empty() ? "no bids" : fmt::format("{}", fmt::join(parts, ", "));
  }
  void trace_auction(const Stop& stop, const ErrandUpdate& u, const std::string& outcome, std::string text) {
    std::vector<std::pair<std::string, TraceValue>> fields{
        {"errand", u.errand}, {"stop", stop.label},  {"outcome", outcome},
        {"round", static_cast<std::int64_t>(u.round)}, {"robot", u.robot}, {"bids", bids_text(u)}};
    if (u.kind == ErrandUpdate::Kind::assigned) {
      fields.emplace_back("cost", u.cost);
      fields.emplace_back("auction_ms", u.auction_ms);
    }
    for (const auto& [robot, cost] : u.bids) fields.emplace_back("bid." + robot, cost);
    if (!u.excluded.empty()) fields.emplace_back("excluded", fmt::format("{}", fmt::join(u.excluded, ",")));
    if (!u.reason.empty()) fields.emplace_back("reason", u.reason);
    record("auction", std::move(text), std::move(fields));
  }

  void on_update(const ErrandUpdate& u) {
    auto it = stops_.find(u.errand);
    if (it == stops_.end()) return;
    Stop& stop = it->second;
    switch (u.kind) {
      case ErrandUpdate::Kind::assigned:
        stop.robot = u.robot;
        trace_auction(stop, u, "awarded",
                      fmt::format("{}: {} goes to {} (round {}; {})", path(), u.robot, stop.label, u.round, bids_text(u)));
        return;
      case ErrandUpdate::Kind::turn:
        drive(u.errand, u.robot);
        return;
      case ErrandUpdate::Kind::reauctioned:
        // A robot lost before it acknowledged its award never held the stop.
        trace_auction(stop, u, "reauction",
                      stop.robot == u.robot
                          ? fmt::format("{}: {} lost {} ({}); auctioned again", path(), u.robot, stop.label, u.reason)
                          : fmt::format("{}: {} won {} but was lost before it took it ({}); auctioned again", path(),
                                        u.robot, stop.label, u.reason));
        abandon(u.errand, u.robot);
        return;
      case ErrandUpdate::Kind::unassigned: {
        trace_auction(stop, u, "unassigned", fmt::format("{}: no robot for {}: {}", path(), stop.label, u.reason));
        auto finished = std::move(stop.finished);
        stops_.erase(it);
        finished(false, "", u.reason);
        return;
      }
    }
  }

  // The robot stops driving to `errand` (it lost it); a robot still there is stopped.
  void abandon(const std::string& errand, const std::string& robot) {
    auto s = stops_.find(errand);
    if (s != stops_.end()) {
      if (s->second.stall_timer != 0) cancel(s->second.stall_timer);
      s->second.stall_timer = 0;
      s->second.robot.clear();
    }
    auto w = robots_.find(robot);
    if (w == robots_.end() || w->second.errand != errand) return;
    w->second.errand.clear();
    auto nav = w->second.nav;
    if (nav->available() && nav->proxy().bound()) {
      invoke(*nav, "stop", [&](auto done) { nav->proxy().stop_async(done); }, [](std::exception_ptr) {});
    }
  }

  void drive(const std::string& errand, const std::string& robot) {
    auto& w = robots_[robot];
    if (!w.nav) {
      w.nav = discover<NavigationService>(of_type("Navigation").on_device(robot + "_wheels"));
      if (!w.nav) w.nav = discover<NavigationService>(of_type("Navigation").carried_by(robot));
      if (!w.nav) {
        robots_.erase(robot);
        market_->failed(errand, robot + " has no available Navigation service");
        return;
      }
      listen(w.nav, [this, robot](const Event& e) { on_position(robot, e); });
    }
    if (!w.nav->available()) {
      market_->failed(errand, w.nav->id() + " is unavailable");
      return;
    }
    Stop& stop = stops_.at(errand);
    w.errand = errand;
    arm_stall(errand, robot);
    auto nav = w.nav;
    auto refused = [this, errand, robot](std::exception_ptr e, double = 0) {
      if (!e) return;
      auto s = stops_.find(errand);
      if (s == stops_.end() || robots_[robot].errand != errand) return;
      robots_[robot].errand.clear();
      const auto why = describe(e);
      if (!robots_[robot].nav->available()) {
        market_->failed(errand, robot + " could not be sent: " + why);
        return;
      }
      finish(errand, false, robot, why);  // the house has no way there: no robot will do better
    };
    if (!stop.stop.name.empty()) {
      const auto target = stop.stop.name;
      invoke(*nav, fmt::format("go_to_waypoint({})", target),
             [&](auto done) { nav->proxy().go_to_waypoint_async(target, done); }, refused);
    } else {
      home::Pose pose;
      pose.x = stop.stop.x;
      pose.y = stop.stop.y;
      pose.theta = 0;
      invoke(*nav, fmt::format("go_to({:.1f}, {:.1f})", pose.x, pose.y),
             [&](auto done) { nav->proxy().go_to_async(pose, done); }, refused);
    }
  }

  // A robot that reports no motion for stall_after while driving has stalled.
  void arm_stall(const std::string& errand, const std::string& robot) {
    auto s = stops_.find(errand);
    if (s == stops_.end()) return;
    if (s->second.stall_timer != 0) cancel(s->second.stall_timer);
    s->second.stall_timer = after(stall_after_, [this, errand, robot] {
      auto s2 = stops_.find(errand);
      if (s2 == stops_.end()) return;
      s2->second.stall_timer = 0;
      if (robots_[robot].errand != errand) return;
      note(fmt::format("{} made no progress towards {} for {} s", robot, s2->second.label, stall_after_.count() / 1000));
      market_->failed(errand, fmt::format("{} stalled", robot));
    });
  }

  void on_position(const std::string& robot, const Event& e) {
    if (e.type() != "PositionEvent") return;
    auto w = robots_.find(robot);
    if (w == robots_.end() || w->second.errand.empty()) return;
    const std::string errand = w->second.errand;
    if (e.get<bool>("moving")) {
      arm_stall(errand, robot);
      return;
    }
    w->second.errand.clear();
    if (e.get<bool>("arrived")) {
      finish(errand, true, robot, "");
    } else {
      market_->failed(errand, fmt::format("{} stopped short of {}", robot, stops_.at(errand).label));
    }
  }

  void finish(const std::string& errand, bool reached, const std::string& robot, const std::string& why) {
    auto it = stops_.find(errand);
    if (it == stops_.end()) return;
    if (it->second.stall_timer != 0) cancel(it->second.stall_timer);
    auto finished = std::move(it->second.finished);
    stops_.erase(it);
    market_->done(errand);
    finished(reached, robot, why);
  }

  Time stall_after_;
  std::map<std::string, Stop> stops_;      // by errand
  std::map<std::string, Wheels> robots_;  // by robot
};

// --- Navigation helpers ---------------------------------------------------------------------------

// A behavior that drives the robot: go_to / go_to_waypoint and waiting for the arrival event;
// or, with robot="any", robots the market chooses (ErrandDriving).
class Driving : public ErrandDriving {
 protected:
  explicit Driving(const Params& p) : ErrandDriving(p.duration("stall_after")) {}
  static bool any(const std::string& robot) { return robot == "any"; }
  void bind_wheels(const std::string& robot) {
    auto query = of_type("Navigation");
    if (!robot.empty()) query.on_device(robot + "_wheels");
    wheels_ = require<NavigationService>(query);
    listen(wheels_);
  }
  // The completion of a go_to: a refusal (no path, unknown target) ends the drive.
  auto refused(std::function<void(std::string)> unreachable) {
    return [this, unreachable = std::move(unreachable)](std::exception_ptr e, double = 0) {
      if (!e) return;
      arrived_ = nullptr;
      unreachable(describe(e));
    };
  }
  // Drives to a named waypoint, furniture or room; `arrived(ok)` when it gets there (ok) or stops
  // short (not ok). A target the robot cannot reach calls unreachable(reason).
  void drive_to(const std::string& target, std::function<void(bool)> arrived,
                std::function<void(std::string)> unreachable) {
    arrived_ = std::move(arrived);
    invoke(*wheels_, fmt::format("go_to_waypoint({})", target),
           [&](auto done) { wheels_->proxy().go_to_waypoint_async(target, done); }, refused(std::move(unreachable)));
  }
  void drive_to(double x, double y, std::function<void(bool)> arrived, std::function<void(std::string)> unreachable) {
    arrived_ = std::move(arrived);
    home::Pose pose;
    pose.x = x;
    pose.y = y;
    pose.theta = 0;
    invoke(*wheels_, fmt::format("go_to({:.1f}, {:.1f})", x, y),
           [&](auto done) { wheels_->proxy().go_to_async(pose, done); }, refused(std::move(unreachable)));
  }
  // Position events: the end of a drive.
  bool on_position(const Event& e) {
    if (e.type() != "PositionEvent" || !arrived_) return false;
    if (e.get<bool>("moving")) return true;
    auto done = std::move(arrived_);
    arrived_ = nullptr;
    done(e.get<bool>("arrived"));
    return true;
  }
  void exit() override {
    if (wheels_ && wheels_->available() && wheels_->proxy().bound()) {
      // Halted mid-drive: the robot stops rather than finish a trip nobody wants.
      if (arrived_) invoke(*wheels_, "stop", [&](auto done) { wheels_->proxy().stop_async(done); }, [](std::exception_ptr) {});
    }
    if (market_) ErrandDriving::exit();
  }

  std::shared_ptr<NavigationService> wheels_;
  std::function<void(bool)> arrived_;
};

// --- GoToUser -------------------------------------------------------------------------------------

// Finds the user with the robot's camera (UserLocator), searching the given rooms or waypoints
// in turn, and drives to them. Succeeds next to the user (propagating ReachedUser), fails when
// the user is nowhere to be found or cannot be reached in time.
class GoToUser final : public Driving {
 public:
  explicit GoToUser(const Params& p)
      : Driving(p), user_(p.string("user")), search_(p.list("search")), robot_(p.string("robot")), timeout_(p.duration("timeout")) {}

 protected:
  void entry() override {
    if (any(robot_)) {
      bind_market();
    } else {
      bind_wheels(robot_);
    }
    locator_ = require<UserLocator>(robot_.empty() || any(robot_) ? of_type("UserLocator")
                                                                   : of_type("UserLocator").carried_by(robot_));
    places_ = search_;
    searcher_.clear();
    if (places_.empty()) {  // every room of the house as it is now
      std::set<std::string> rooms;
      for (const auto& service : services().all()) {
        if (!service->attributes().room.empty()) rooms.insert(service->attributes().room);
      }
      places_.assign(rooms.begin(), rooms.end());
    }
    next_ = 0;
    after(timeout_, [this] { fail(fmt::format("did not reach {} within {}", who(), format_duration(timeout_))); });
    look();
  }
  void handle_event(const Event& e) override { on_position(e); }

 private:
  std::string who() const { return user_.empty() ? "the user" : user_; }
  static std::string format_duration(Time d) { return fmt::format("{} s", d.count() / 1000); }

  void look() {
    if (market_) {
      // Robots the market chose: every robot's camera looks (the one that just searched a place
      // first), until one sees the user.
      cameras_.clear();
      if (!searcher_.empty()) {
        for (const auto& l : services().find(of_type("UserLocator").carried_by(searcher_).available())) cameras_.push_back(l);
      }
      for (const auto& l : services().find(of_type("UserLocator").available())) {
        if (std::find(cameras_.begin(), cameras_.end(), l) == cameras_.end()) cameras_.push_back(l);
      }
      look_with(0);
      return;
    }
    locator_->locate(guard([this](std::exception_ptr e, std::vector<UserLocation> seen) {
      if (e) {
        fail("could not look for the user: " + describe(e));
        return;
      }
      if (!saw(seen)) search_next();
    }));
  }
  // Approaches the user if `seen` holds them.
  bool saw(const std::vector<UserLocation>& seen) {
    for (const auto& u : seen) {
      if (!user_.empty() && u.person != user_) continue;
      note(fmt::format("sees {} at ({:.1f}, {:.1f})", u.person, u.x, u.y));
      approach(u);
      return true;
    }
    return false;
  }
  void look_with(std::size_t i) {
    if (i >= cameras_.size()) {
      search_next();
      return;
    }
    auto locator = std::dynamic_pointer_cast<UserLocator>(cameras_[i]);
    if (!locator) {
      look_with(i + 1);
      return;
    }
    locator->locate(guard([this, i](std::exception_ptr e, std::vector<UserLocation> seen) {
      if (e) note("could not look with " + cameras_[i]->id() + ": " + describe(e));
      if (e || !saw(seen)) look_with(i + 1);
    }));
  }
  void search_next() {
    if (next_ >= places_.size()) {
      fail(fmt::format("{} not found in {}", who(), fmt::join(places_, ", ")));
      return;
    }
    const auto place = places_[next_++];
    if (market_) {
      send_robot(place, coros::Place{place, 0, 0}, [this, place](bool reached, const std::string& robot, const std::string& why) {
        if (!reached) note(fmt::format("cannot search {}: {}", place, why));
        searcher_ = robot;
        reached ? look() : search_next();
      });
      return;
    }
    drive_to(place, [this](bool) { look(); }, [this, place](std::string why) {
      note(fmt::format("cannot search {}: {}", place, why));
      search_next();
    });
  }
  void reached(const UserLocation& u, const std::string& robot) {
    Event reached("ReachedUser");
    reached.set("user", u.person);
    reached.set("x", u.x);
    reached.set("y", u.y);
    if (!robot.empty()) reached.set("robot", robot);
    propagate(std::move(reached));
    succeed();
  }
  void approach(const UserLocation& u) {
    if (market_) {
      send_robot(u.person, coros::Place{"", u.x, u.y}, [this, u](bool ok, const std::string& robot, const std::string& why) {
        ok ? reached(u, robot) : fail(fmt::format("cannot reach {}: {}", u.person, why));
      });
      return;
    }
    drive_to(u.x, u.y,
             [this, u](bool ok) {
               if (!ok) {
                 fail(fmt::format("stopped before reaching {}", u.person));
                 return;
               }
               reached(u, "");
             },
             [this, u](std::string why) { fail(fmt::format("cannot reach {}: {}", u.person, why)); });
  }

  std::string user_;
  std::vector<std::string> search_;  // as given
  std::vector<std::string> places_;  // this activation's: search_, or every room
  std::string robot_;
  Time timeout_;
  std::shared_ptr<UserLocator> locator_;
  std::vector<std::shared_ptr<s::Service>> cameras_;  // robot="any": the locators to look with
  std::string searcher_;                                // robot="any": the robot that searched last
  std::size_t next_ = 0;
};

// --- GoTo -----------------------------------------------------------------------------------------

class GoTo final : public Driving {
 public:
  explicit GoTo(const Params& p) : Driving(p), target_(p.string("target")), robot_(p.string("robot")) {}

 protected:
  void entry() override {
    if (any(robot_)) {
      bind_market();
      send_robot(target_, coros::Place{target_, 0, 0}, [this](bool reached, const std::string&, const std::string& why) {
        reached ? succeed() : fail(why);
      });
      return;
    }
    bind_wheels(robot_);
    drive_to(target_, [this](bool ok) { ok ? succeed() : fail("stopped before reaching " + target_); },
             [this](std::string why) { fail(why); });
  }
  void handle_event(const Event& e) override { on_position(e); }

 private:
  std::string target_;
  std::string robot_;
};

// --- PatrolHome -----------------------------------------------------------------------------------

// Drives a round of waypoints (Table 6: Navigation, MotionSensor); propagates WaypointReached
// at each and MotionDetected for motion the house's motion sensors report meanwhile. A waypoint
// it cannot reach is skipped; the patrol fails if it reached none.
class PatrolHome final : public Driving {
 public:
  explicit PatrolHome(const Params& p)
      : Driving(p), waypoints_(p.list("waypoints")), rounds_(static_cast<int>(p.integer("rounds"))), robot_(p.string("robot")) {}

 protected:
  void entry() override {
    if (waypoints_.empty()) throw BehaviorError("no waypoints to patrol");
    if (any(robot_)) {
      bind_market();
    } else {
      bind_wheels(robot_);
    }
    for (const auto& m : services().find(of_type("MotionSensor").available())) {
      if (auto sensor = std::dynamic_pointer_cast<MotionSensorService>(m)) listen(sensor);
    }
    next_ = 0;
    round_ = 0;
    reached_ = 0;
    skipped_.clear();
    market_ ? share_round() : visit_next();
  }
  void handle_event(const Event& e) override {
    if (on_position(e)) return;
    if (e.type() == "MotionEvent" && e.get<bool>("motion")) {
      Event motion("MotionDetected");
      motion.set("room", e.get<std::string>("room"));
      motion.set("device", e.get<std::string>("device"));
      propagate(std::move(motion));
    }
  }

 private:
  // Ends a round: true when the patrol is over (succeeded or failed).
  bool round_over() {
    if (++round_ < rounds_) return false;
    if (reached_ == 0) {
      fail(fmt::format("reached no waypoint (skipped {})", fmt::join(skipped_, ", ")));
    } else {
      succeed();
    }
    return true;
  }
  // robot="any": the round's waypoints are auctioned one by one among the robots, each going
  // to the robot that adds the least driving to what it already has to do; the robots drive
  // their shares at once, and a robot's share goes to the others when it fails.
  void share_round() {
    for (std::size_t i = 0; i < waypoints_.size(); ++i) {
      const auto waypoint = waypoints_[i];
      send_robot(waypoint, coros::Place{waypoint, 0, 0},
                 [this, waypoint, i](bool ok, const std::string& robot, const std::string& why) {
                   if (ok) {
                     ++reached_;
                     Event reached("WaypointReached");
                     reached.set("waypoint", waypoint);
                     reached.set("index", static_cast<std::int32_t>(i));
                     reached.set("robot", robot);
                     propagate(std::move(reached));
                   } else {
                     note(fmt::format("skips {}: {}", waypoint, why));
                     skipped_.push_back(waypoint);
                   }
                   if (open_stops() == 0 && !round_over()) share_round();
                 });
    }
  }
  void visit_next() {
    if (next_ == waypoints_.size()) {
      next_ = 0;
      if (round_over()) return;
    }
    const auto waypoint = waypoints_[next_];
    const auto index = next_++;
    drive_to(waypoint,
             [this, waypoint, index](bool ok) {
               if (ok) {
                 ++reached_;
                 Event reached("WaypointReached");
                 reached.set("waypoint", waypoint);
                 reached.set("index", static_cast<std::int32_t>(index));
                 propagate(std::move(reached));
               } else {
                 skipped_.push_back(waypoint);
               }
               visit_next();
             },
             [this, waypoint](std::string why) {
               note(fmt::format("skips {}: {}", waypoint, why));
               skipped_.push_back(waypoint);
               visit_next();
             });
  }

  std::vector<std::string> waypoints_;
  int rounds_;
  std::string robot_;
  std::size_t next_ = 0;
  int round_ = 0;
  int reached_ = 0;
  std::vector<std::string> skipped_;
};

// --- Voice control --------------------------------------------------------------------------------

// Subscribes to every speech sensor, telling it the phrases a subclass acts on; a subclass
// says what the words do.
class VoiceControl : public SpeechListener {
 protected:
  void listen_to_speech(std::vector<std::string> phrases) { listen_for_phrases(std::move(phrases)); }
  void handle_event(const Event& e) override {
    if (e.type() == "SpeechEvent") on_command(lower(e.get<std::string>("text")));
  }
  virtual void on_command(const std::string& text) = 0;
  // "volume up" → +step, "volume down" → -step, else 0.
  static int volume_change(const std::string& text, int step) {
    return mentions(text, "up") ? step : mentions(text, "down") ? -step : 0;
  }
};

constexpr int kSpokenChannels = 30;  // "channel 1" .. "channel 30"

class VoiceTVControl final : public VoiceControl {
 public:
  explicit VoiceTVControl(const Params& p) : room_(p.string("room")), step_(static_cast<int>(p.integer("volume_step"))) {}

 protected:
  void entry() override {
    auto query = of_type("TVControl");
    if (!room_.empty()) query.in_room(room_);
    tv_ = require<TVControlService>(query);
    std::vector<std::string> phrases = {"turn on the tv", "turn off the tv", "tv on", "tv off",
                                        "volume up", "volume down", "tv volume up", "tv volume down"};
    for (int n = 1; n <= kSpokenChannels; ++n) phrases.push_back(fmt::format("channel {}", n));
    listen_to_speech(std::move(phrases));
  }
  void on_command(const std::string& text) override {
    if (!mentions(text, "tv") && !mentions(text, "channel") && !mentions(text, "volume")) return;
    auto& tv = *tv_;
    auto report = [this](std::exception_ptr e, auto&&...) {
      if (e) note("the TV did not do it: " + describe(e));
    };
    if (mentions(text, "turn on") || mentions(text, "tv on")) {
      invoke(tv, "set_power(true)", [&](auto done) { tv.proxy().set_power_async(true, done); }, report);
    } else if (mentions(text, "turn off") || mentions(text, "tv off")) {
      invoke(tv, "set_power(false)", [&](auto done) { tv.proxy().set_power_async(false, done); }, report);
    } else if (mentions(text, "channel")) {
      if (auto n = number_in(text)) {
        invoke(tv, fmt::format("set_channel({})", *n), [&](auto done) { tv.proxy().set_channel_async(*n, done); }, report);
      }
    } else if (mentions(text, "volume")) {
      const int delta = volume_change(text, step_);
      if (delta == 0) return;
      // Read, then write: the TV's own state is the truth (someone may have used the remote).
      invoke(tv, "state", [&](auto done) { tv.proxy().state_async(done); },
             [this, delta, report](std::exception_ptr e, home::TVState state = {}) {
               if (e || !state.on) return;
               const int volume = std::clamp(state.volume + delta, 0, 100);
               invoke(*tv_, fmt::format("set_volume({})", volume),
                      [&](auto done) { tv_->proxy().set_volume_async(volume, done); }, report);
             });
    }
  }

 private:
  std::string room_;
  int step_;
  std::shared_ptr<TVControlService> tv_;
};

class VoiceAudioControl final : public VoiceControl {
 public:
  explicit VoiceAudioControl(const Params& p)
      : track_(p.string("track")), step_(static_cast<int>(p.integer("volume_step"))) {}

 protected:
  void entry() override {
    speaker_ = require<SpeakerService>(of_type("AudioControl"));
    listen_to_speech({"play music", "play some music", "play a song", "stop", "stop the music", "stop music",
                      "volume up", "volume down", "music volume up", "music volume down"});
  }
  void on_command(const std::string& text) override {
    auto& sp = *speaker_;
    auto report = [this](std::exception_ptr e, auto&&...) {
      if (e) note("the speaker did not do it: " + describe(e));
    };
    if (mentions(text, "play") && (mentions(text, "music") || mentions(text, "song"))) {
      invoke(sp, fmt::format("play({})", track_), [&](auto done) { sp.proxy().play_async(track_, done); }, report);
    } else if (text == "stop" || mentions(text, "stop music") || mentions(text, "stop the music")) {
      invoke(sp, "stop", [&](auto done) { sp.proxy().stop_async(done); }, report);
    } else if (mentions(text, "volume") && !mentions(text, "tv")) {
      const int delta = volume_change(text, step_);
      if (delta == 0) return;
      invoke(sp, "state", [&](auto done) { sp.proxy().state_async(done); },
             [this, delta, report](std::exception_ptr e, home::SpeakerState state = {}) {
               if (e || state.playing.empty()) return;
               const int volume = std::clamp(state.volume + delta, 0, 100);
               invoke(*speaker_, fmt::format("set_volume({})", volume),
                      [&](auto done) { speaker_->proxy().set_volume_async(volume, done); }, report);
             });
    }
  }

 private:
  std::string track_;
  int step_;
  std::shared_ptr<SpeakerService> speaker_;
};

// --- MoodControl ----------------------------------------------------------------------------------

// Turns the lights off (or dims them), plays calm music for a while, then stops it and succeeds.
class MoodControl final : public Behavior {
 public:
  explicit MoodControl(const Params& p)
      : rooms_(p.list("rooms")), intensity_(static_cast<int>(p.integer("intensity"))), track_(p.string("track")),
        volume_(static_cast<int>(p.integer("volume"))), duration_(p.duration("duration")) {}

 protected:
  void entry() override {
    for (const auto& service : services().find(of_type("LightControl").available())) {
      auto light = std::static_pointer_cast<LightService>(service);
      if (!rooms_.empty() && std::find(rooms_.begin(), rooms_.end(), light->attributes().room) == rooms_.end()) continue;
      if (intensity_ == 0) {
        invoke(*light, "set_power(false)", [&](auto done) { light->proxy().set_power_async(false, done); }, tolerate());
      } else {
        invoke(*light, fmt::format("set_intensity({})", intensity_),
               [&](auto done) { light->proxy().set_intensity_async(intensity_, done); }, tolerate());
      }
    }
    if (track_.empty()) {  // a mood of lights alone
      after(duration_, [this] { succeed(); });
      return;
    }
    speaker_ = require<SpeakerService>(of_type("AudioControl"));
    invoke(*speaker_, fmt::format("set_volume({})", volume_),
           [&](auto done) { speaker_->proxy().set_volume_async(volume_, done); }, tolerate());
    invoke(*speaker_, fmt::format("play({})", track_), [&](auto done) { speaker_->proxy().play_async(track_, done); });
    playing_ = true;
    after(duration_, [this] {
      invoke(*speaker_, "stop", [&](auto done) { speaker_->proxy().stop_async(done); },
             [this](std::exception_ptr e) {
               playing_ = false;
               e ? fail(call_error("stop", e)) : succeed();
             });
    });
  }
  void exit() override {
    // Halted while the music plays: stop it (nobody is waiting for the reply).
    if (playing_ && speaker_) {
      playing_ = false;
      invoke(*speaker_, "stop", [&](auto done) { speaker_->proxy().stop_async(done); }, [](std::exception_ptr) {});
    }
  }

 private:
  std::function<void(std::exception_ptr)> tolerate() {
    return [this](std::exception_ptr e) {
      if (e) note("could not set the mood: " + describe(e));
    };
  }
  std::vector<std::string> rooms_;
  int intensity_;
  std::string track_;
  int volume_;
  Time duration_;
  std::shared_ptr<SpeakerService> speaker_;
  bool playing_ = false;
};

// --- Single actions -------------------------------------------------------------------------------

class Speak final : public Behavior {
 public:
  explicit Speak(const Params& p) : text_(p.string("text")) {}

 protected:
  void entry() override {
    speaker_ = require<SpeakerService>(of_type("AudioControl"));
    invoke(*speaker_, fmt::format("speak(\"{}\")", text_), [&](auto done) { speaker_->proxy().speak_async(text_, done); },
           [this](std::exception_ptr e) { e ? fail(call_error("speak", e)) : succeed(); });
  }

 private:
  std::string text_;
  std::shared_ptr<SpeakerService> speaker_;
};

class SetLights final : public Behavior {
 public:
  explicit SetLights(const Params& p)
      : rooms_(p.list("rooms")), on_(p.boolean("on")), intensity_(static_cast<int>(p.integer("intensity"))) {
    if (intensity_ < 0 || intensity_ > 100) throw ParamError("SetLights: intensity must be 0 (unchanged) to 100");
  }

 protected:
  void entry() override {
    auto lights = services().find(of_type("LightControl").available());
    pending_ = 0;
    failed_ = false;  // a retry starts this behavior again: the last attempt's failure is not this one's
    for (const auto& service : lights) {
      auto light = std::static_pointer_cast<LightService>(service);
      if (!rooms_.empty() && std::find(rooms_.begin(), rooms_.end(), light->attributes().room) == rooms_.end()) continue;
      ++pending_;
      if (on_ && intensity_ > 0) {
        invoke(*light, fmt::format("set_intensity({})", intensity_),
               [&](auto done) { light->proxy().set_intensity_async(intensity_, done); },
               [this](std::exception_ptr e) {
                 if (e) failed_ = true;
               });
      }
      invoke(*light, fmt::format("set_power({})", on_), [&](auto done) { light->proxy().set_power_async(on_, done); },
             [this](std::exception_ptr e) {
               if (e) failed_ = true;
               if (--pending_ == 0) failed_ ? fail("a light did not switch") : succeed();
             });
    }
    if (pending_ == 0) throw BehaviorError("no available light to switch");
  }

 private:
  std::vector<std::string> rooms_;
  bool on_;
  int intensity_;
  int pending_ = 0;
  bool failed_ = false;
};

}  // namespace

// --- LookAtSound ----------------------------------------------------------------------------------

void LookAtSound::entry() {
  wheels_.clear();
  std::vector<std::shared_ptr<SoundLocalizer>> arrays;
  auto query = of_type("SoundLocalizer").available();
  if (robot_ == "any") {
    for (const auto& s : services().find(query)) {
      if (auto l = std::dynamic_pointer_cast<SoundLocalizer>(s)) arrays.push_back(l);
    }
    if (arrays.empty()) throw BehaviorError("no available SoundLocalizer service");
  } else {
    if (!robot_.empty()) query.carried_by(robot_);
    arrays.push_back(require<SoundLocalizer>(query));
  }
  for (const auto& array : arrays) {
    const std::string robot = array->attributes().carrier;
    auto wheels = discover<NavigationService>(robot.empty() ? of_type("Navigation") : of_type("Navigation").carried_by(robot));
    if (!wheels) {
      if (robot_ == "any") continue;  // an array on a robot that cannot turn
      throw BehaviorError("no available Navigation service" + (robot.empty() ? std::string() : " on " + robot));
    }
    wheels_[robot] = wheels;
    listen(array, [this, robot](const Event& e) { on_sound(robot, e); });
  }
  if (wheels_.empty()) throw BehaviorError("no robot with a microphone array can turn");
}

void LookAtSound::on_sound(const std::string& robot, const Event& e) {
  if (e.type() != "SoundDirection") return;
  if (e.get<double>("level_db") < min_level_db_ || e.get<double>("confidence") < min_confidence_) return;
  const double bearing = e.get<double>("bearing");
  auto wheels = wheels_.at(robot);
  invoke(*wheels, "position", [&](auto done) { wheels->proxy().position_async(done); },
         [this, bearing, wheels](std::exception_ptr error, home::Pose at = {}) {
           if (error) return note("could not read where the robot faces: " + describe(error));
           const double direction = std::remainder(at.theta + bearing, 2 * std::numbers::pi);
           invoke(*wheels, fmt::format("turn_to({:.3f})", direction),
                  [&](auto done) { wheels->proxy().turn_to_async(direction, done); });
         });
}

void register_behaviors(BehaviorRegistry& registry) {
  using T = ParamType;
  constexpr const char* kRobotParam = "which robot (default: the first); \"any\": the robots bid for the work (RobotMarket)";
  constexpr const char* kStallParam = "robot=\"any\": a robot that reports no motion for this long while driving loses the stop to another";
  registry.add<Sense>("Sense", "propagates the events of sensor services",
                      {param("service", T::string, std::nullopt,
                             "service type: OccupancySensor, SpeechSensor, MotionSensor, SoundSensor, Navigation, UserLocator, "
                             "MeasurementSensor"),
                       param("room", T::string, "", "only sensors in this room").naming("room"),
                       param("report_current", T::boolean, "false",
                             "occupancy sensors: also report the current state at entry"),
                       param("phrases", T::list, "",
                             "speech sensors: the phrases the policy's rules act on, for the recognizer (default: free speech)")});
  registry.add<GoToUser>("GoToUser", "finds the user with the robot's camera and drives to them",
                         {param("user", T::string, "", "who to go to (default: whoever the camera sees first)").naming("user"),
                          param("search", T::list, "", "rooms or waypoints to search in order (default: every room)").naming("place"),
                          param("robot", T::string, "", kRobotParam).naming("robot"),
                          param("timeout", T::duration, "5min", "fail if not next to the user by then"),
                          param("stall_after", T::duration, "2min", kStallParam)});
  registry.add<GoTo>("GoTo", "drives the robot to a waypoint, furniture or room",
                     {param("target", T::string, std::nullopt, "where").naming("place"),
                      param("robot", T::string, "", kRobotParam).naming("robot"),
                      param("stall_after", T::duration, "2min", kStallParam)});
  registry.add<PatrolHome>("PatrolHome", "drives a round of waypoints, reporting motion",
                           {param("waypoints", T::list, std::nullopt, "the round, in order").naming("waypoint"),
                            param("rounds", T::integer, "1", "how many rounds"),
                            param("robot", T::string, "", kRobotParam + std::string("; \"any\" splits the round among the robots")).naming("robot"),
                            param("stall_after", T::duration, "2min", kStallParam)});
  registry.add<VoiceTVControl>("VoiceTVControl", "controls the TV by voice: turn on/off the TV, channel N, volume up/down",
                               {param("room", T::string, "", "the TV's room (default: any)").naming("room"),
                                param("volume_step", T::integer, "5", "volume change per command")});
  registry.add<VoiceAudioControl>("VoiceAudioControl", "controls the speaker by voice: play music, stop, volume up/down",
                                  {param("track", T::string, "relaxing music", "what 'play music' plays"),
                                   param("volume_step", T::integer, "5", "volume change per command")});
  registry.add<LookAtSound>("LookAtSound", "turns the robot towards sounds, located by its microphone array",
                            {param("robot", T::string, "",
                                   "which robot (default: the first with a microphone array); \"any\": every robot "
                                   "with one turns to what it hears").naming("robot"),
                             param("min_level_db", T::number, "45", "ignore quieter sounds"),
                             param("min_confidence", T::number, "0.03", "ignore sounds located less surely (0..1; a voice in a room is 0.05-0.5, diffuse noise under 0.02)")});
  registry.add<MoodControl>("MoodControl", "lights off or dimmed, calm music for a while",
                            {param("rooms", T::list, "", "lights of these rooms (default: all)").naming("room"),
                             param("intensity", T::integer, "0", "0: off, else dim to this percent"),
                             param("track", T::string, "calm music", "what to play (\"\": no music, lights only)"),
                             param("volume", T::integer, "20", "at this volume"),
                             param("duration", T::duration, "15min", "for this long")});
  registry.add<Speak>("Speak", "says something through the robot's speaker",
                      {param("text", T::string, std::nullopt, "what to say")});
  registry.add<SetLights>("SetLights", "switches lights on or off",
                          {param("on", T::boolean, std::nullopt, "on or off"),
                           param("rooms", T::list, "", "lights of these rooms (default: all)").naming("room"),
                           param("intensity", T::integer, "0", "switched on, dimmed to this percent (0: unchanged)")});
  register_voice_commands(registry);

  // What each propagates (policy checks follow the events up a task's tree with these).
  registry.declare_events("Sense", {event_spec<OccupancyEvent>(), event_spec<MotionEvent>(), event_spec<SpeechEvent>(),
                                    event_spec<UnrecognizedSpeech>(), event_spec<SoundDirection>(), event_spec<SoundEvent>(), event_spec<PositionEvent>(), event_spec<UserLocation>(),
                                    event_spec<MeasurementEvent>()});
  registry.declare_events("GoToUser", {{"ReachedUser", {"user", "x", "y", "robot"}}});
  registry.declare_events("PatrolHome", {{"WaypointReached", {"waypoint", "index", "robot"}}, {"MotionDetected", {"room", "device"}}});
  for (const char* quiet : {"GoTo", "VoiceTVControl", "VoiceAudioControl", "LookAtSound", "MoodControl", "Speak", "SetLights"}) {
    registry.declare_events(quiet, {});
  }
}

BehaviorRegistry behavior_registry() {
  BehaviorRegistry registry;
  register_generic_behaviors(registry);
  register_behaviors(registry);
  return registry;
}

}  // namespace icars::home
