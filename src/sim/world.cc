#include "icars/sim/world.h"

#include <fmt/format.h>

#include <atomic>
#include <cmath>
#include <deque>
#include <map>
#include <mutex>
#include <numbers>
#include <random>
#include <stdexcept>
#include <thread>
#include <unordered_set>
#include <variant>

#include "icars/sim/planner.h"

namespace icars::sim {

std::string_view to_string(Posture posture) {
  switch (posture) {
    case Posture::standing:
      return "standing";
    case Posture::walking:
      return "walking";
    case Posture::sitting:
      return "sitting";
    case Posture::lying:
      return "lying";
  }
  return "?";
}

namespace {

Time travel_time(double metres, double speed) {
  return Time(std::llround(metres / speed * 1000.0));
}

// A body moving along a path at constant speed from `start`, waiting `pause` on the way
// `pause_at` metres along it.
struct Motion {
  std::vector<Point> path;
  double length = 0;
  double speed = 1;
  Time start{0};
  double pause_at = 0;
  Time pause{0};

  Time end() const { return start + travel_time(length, speed) + pause; }
  Pose last() const { return point_along(path, length); }  // exactly the end of the path
  double along(Time now) const {
    const double elapsed = static_cast<double>((now - start).count()) / 1000.0;
    double d = elapsed * speed;
    if (pause.count() > 0 && d > pause_at) {
      const double resume = pause_at / speed + static_cast<double>(pause.count()) / 1000.0;
      d = elapsed <= resume ? pause_at : pause_at + (elapsed - resume) * speed;
    }
    return std::clamp(d, 0.0, length);
  }
  Pose at(Time now) const { return point_along(path, along(now)); }
  // When the body is `d` metres along the path (arriving there, for the pause's place).
  Time when_at(double d) const {
    Time t = start + travel_time(d, speed);
    if (pause.count() > 0 && d > pause_at) t += pause;
    return t;
  }
};

// Robots take turns at a door narrower than two of them side by side with this to spare; a
// robot is in a door while its centre is within its radius and this of the opening.
constexpr double kDoorClearance = 0.1;
// A robot waiting for a door stops this far before it, and lets this much time pass after the
// other robot is through.
constexpr double kDoorWaitBefore = 0.2;
constexpr Time kDoorMargin{500};

double distance_to_segment(Point p, Point a, Point b) {
  const double dx = b.x - a.x, dy = b.y - a.y;
  const double len2 = dx * dx + dy * dy;
  const double t = len2 == 0 ? 0 : std::clamp(((p.x - a.x) * dx + (p.y - a.y) * dy) / len2, 0.0, 1.0);
  return std::hypot(p.x - (a.x + t * dx), p.y - (a.y + t * dy));
}

// The stretch of `path` [first, last] (metres along it) where a body of `radius` is in `door`.
std::optional<std::pair<double, double>> door_stretch(const std::vector<Point>& path, double length,
                                                      const Door& door, double radius) {
  constexpr double kStep = 0.05;
  std::optional<std::pair<double, double>> out;
  for (double d = 0;; d = std::min(d + kStep, length)) {
    if (distance_to_segment(point_along(path, d).position(), door.a, door.b) < radius + kDoorClearance) {
      if (!out) out.emplace(d, d);
      out->second = d;
    }
    if (d >= length) break;
  }
  return out;
}

std::uint64_t splitmix64(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

// Orientation test for segment intersection.
double cross(Point o, Point a, Point b) {
  return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x);
}

bool segments_cross(Point p1, Point p2, Point q1, Point q2) {
  const double d1 = cross(q1, q2, p1);
  const double d2 = cross(q1, q2, p2);
  const double d3 = cross(p1, p2, q1);
  const double d4 = cross(p1, p2, q2);
  return ((d1 > 0 && d2 < 0) || (d1 < 0 && d2 > 0)) && ((d3 > 0 && d4 < 0) || (d3 < 0 && d4 > 0));
}

}  // namespace

struct World::Impl : std::enable_shared_from_this<Impl> {
  using PoseListener = std::function<void(const std::string&, const Pose&, bool)>;
  using UserListener = std::function<void(const UserState&)>;
  using UtteranceListener = std::function<void(const Utterance&)>;

  struct PoseNote {
    std::string robot;
    Pose pose;
    bool moving;
  };
  struct DoneNote {
    std::function<void(bool)> done;
    bool arrived;
  };
  using Note = std::variant<PoseNote, UserState, Utterance, DoneNote>;
  using Notes = std::vector<Note>;

  struct Robot {
    const RobotSpec* spec = nullptr;
    std::shared_ptr<const OccupancyGrid> grid;
    Pose pose;  // when not moving
    std::optional<Motion> motion;
    std::function<void(bool)> done;
    std::uint64_t report_timer = 0;
    std::uint64_t arrival_timer = 0;

    Pose pose_at(Time now) const { return motion ? motion->at(now) : pose; }
  };
  // A robot's motion holds a narrow door from when it enters to when it is through.
  struct DoorHold {
    std::string robot;
    Time from{0}, to{0};
  };

  struct Pending {
    ScheduleEntry entry;
    double loudness_db;
  };

  struct User {
    const UserSpec* spec = nullptr;
    std::shared_ptr<const OccupancyGrid> grid;
    UserState state;
    std::optional<Motion> walk;
    std::deque<Pending> queue;
    std::mt19937_64 rng;
  };

  Impl(House h, SimClock& c, WorldOptions o) : house(std::move(h)), clock(c), options(o) {}

  House house;
  SimClock& clock;
  WorldOptions options;

  mutable std::mutex mutex;
  std::map<double, std::shared_ptr<const OccupancyGrid>> grids;
  std::map<std::string, Robot, std::less<>> robots;
  std::map<std::string, User, std::less<>> users;
  std::map<std::string, std::vector<DoorHold>, std::less<>> door_holds;  // door -> holds
  std::map<std::string, std::string, std::less<>> occupancy;  // furniture -> user
  std::unordered_set<std::uint64_t> timers;                   // our pending clock events
  std::mutex delivery_mutex;                                  // held while listeners run
  std::atomic<std::thread::id> delivering_thread;
  // Listener ids order the calls: observers' ids (from 1) sort before reactors' (from 2^32).
  std::uint64_t next_observer = 1;
  std::uint64_t next_listener = std::uint64_t{1} << 32;
  std::uint64_t listener_id(World::Listening listening) {
    return listening == World::Listening::observing ? next_observer++ : next_listener++;
  }
  std::map<std::uint64_t, std::shared_ptr<PoseListener>> pose_listeners;
  std::map<std::uint64_t, std::shared_ptr<UserListener>> user_listeners;
  std::map<std::uint64_t, std::shared_ptr<UtteranceListener>> utterance_listeners;

  std::shared_ptr<const OccupancyGrid> grid_for(double radius) {
    auto& g = grids[radius];
    if (!g) g = std::make_shared<const OccupancyGrid>(house, radius);
    return g;
  }

  Robot& robot(std::string_view id) {
    const auto it = robots.find(id);
    if (it == robots.end()) throw std::invalid_argument(fmt::format("unknown robot \"{}\"", id));
    return it->second;
  }
  User& user(std::string_view id) {
    const auto it = users.find(id);
    if (it == users.end()) throw std::invalid_argument(fmt::format("unknown user \"{}\"", id));
    return it->second;
  }

  std::string room_name(Point p) const {
    const auto* r = house.room_at(p);
    return r ? r->name : std::string();
  }

  // Schedules `fn` on the clock; it runs under the World lock, and the notes it leaves are
  // delivered after the lock is released. Call with the lock held.
  std::uint64_t schedule(Time t, std::function<void(Notes&)> fn) {
    auto id = std::make_shared<std::uint64_t>(0);
    *id = clock.schedule_at(t, [weak = weak_from_this(), fn = std::move(fn), id] {
      const auto self = weak.lock();
      if (!self) return;
      Notes notes;
      {
        std::lock_guard lock(self->mutex);
        if (self->timers.erase(*id) == 0) return;  // cancelled while it was being started
        fn(notes);
      }
      self->deliver(notes);
    });
    timers.insert(*id);
    return *id;
  }

  void cancel(std::uint64_t& id) {
    if (id == 0) return;
    clock.cancel(id);
    timers.erase(id);
    id = 0;
  }

  // Listeners run under delivery_mutex (never under `mutex`), so that remove_listener() can
  // wait for a call in progress. Only the thread advancing the clock delivers.
  void deliver(const Notes& notes) {
    if (notes.empty()) return;
    std::lock_guard delivering(delivery_mutex);
    delivering_thread = std::this_thread::get_id();
    struct Reset {
      std::atomic<std::thread::id>& id;
      ~Reset() { id = std::thread::id(); }
    } reset{delivering_thread};
    for (const auto& note : notes) {
      if (const auto* p = std::get_if<PoseNote>(&note)) {
        for (const auto& fn : snapshot(pose_listeners)) (*fn)(p->robot, p->pose, p->moving);
      } else if (const auto* u = std::get_if<UserState>(&note)) {
        for (const auto& fn : snapshot(user_listeners)) (*fn)(*u);
      } else if (const auto* s = std::get_if<Utterance>(&note)) {
        for (const auto& fn : snapshot(utterance_listeners)) (*fn)(*s);
      } else if (const auto* d = std::get_if<DoneNote>(&note)) {
        if (d->done) d->done(d->arrived);
      }
    }
  }

  template <typename Fn>
  std::vector<std::shared_ptr<Fn>> snapshot(const std::map<std::uint64_t, std::shared_ptr<Fn>>& m) {
    std::lock_guard lock(mutex);
    std::vector<std::shared_ptr<Fn>> out;
    out.reserve(m.size());
    for (const auto& [id, fn] : m) out.push_back(fn);
    return out;
  }

  // --- robots --------------------------------------------------------------------------------

  // Ends the current motion where the robot is now; its `done` hears false.
  void release_doors(const std::string& robot) {
    for (auto& [door, holds] : door_holds) {
      std::erase_if(holds, [&](const DoorHold& h) { return h.robot == robot; });
    }
  }

  // Makes motion `m` of `r` wait before every narrow door another robot's motion holds at the
  // time `m` would pass, and holds the doors it passes. Lock held; `r` has no motion.
  void take_turns_at_doors(const Robot& r, Motion& m, Time now) {
    release_doors(r.spec->id);
    for (auto& [door, holds] : door_holds) std::erase_if(holds, [&](const DoorHold& h) { return h.to < now; });
    for (const auto& door : house.doors) {
      const auto stretch = door_stretch(m.path, m.length, door, r.spec->radius);
      if (!stretch) continue;
      auto& holds = door_holds[door.name];
      const double width = std::hypot(door.b.x - door.a.x, door.b.y - door.a.y);
      // A robot starting in the doorway goes on through: it is the one the others wait for.
      for (int turn = 0; stretch->first > kDoorWaitBefore && turn < 16; ++turn) {
        const Time enter = m.when_at(stretch->first), leave = m.when_at(stretch->second);
        const auto conflict = std::find_if(holds.begin(), holds.end(), [&](const DoorHold& h) {
          const auto other = robots.find(h.robot);
          const double other_radius = other == robots.end() ? 0 : other->second.spec->radius;
          const bool narrow = width < 2 * (r.spec->radius + other_radius) + kDoorClearance;
          return h.robot != r.spec->id && narrow && h.from < leave && enter < h.to;
        });
        if (conflict == holds.end()) break;
        const double wait_at = stretch->first - kDoorWaitBefore;
        if (m.pause.count() == 0 || wait_at < m.pause_at) m.pause_at = wait_at;
        m.pause += conflict->to - enter + kDoorMargin;
      }
      holds.push_back(DoorHold{r.spec->id, m.when_at(stretch->first), m.when_at(stretch->second)});
    }
  }

  void halt(Robot& r, Time now, Notes& notes) {
    release_doors(r.spec->id);
    if (!r.motion) return;
    r.pose = r.motion->at(now);
    r.motion.reset();
    cancel(r.report_timer);
    cancel(r.arrival_timer);
    if (r.done) notes.push_back(DoneNote{std::exchange(r.done, {}), false});
  }

  // Sets the robot driving along `m` (started at or before `now`): a pose report now, then
  // every report_every, and the arrival at m.end(). Call with the lock held and no motion.
  void drive(Robot& r, Motion m, std::function<void(bool)> done, Time now) {
    r.motion = std::move(m);
    r.done = std::move(done);
    r.pose.theta = r.motion->at(now).theta;
    schedule_report(r, now);  // the start; the report reschedules itself
    r.arrival_timer = schedule(r.motion->end(), [this, &r](Notes& n) {
      r.arrival_timer = 0;
      cancel(r.report_timer);
      r.pose = r.motion->last();
      r.motion.reset();
      n.push_back(PoseNote{r.spec->id, r.pose, false});
      if (r.done) n.push_back(DoneNote{std::exchange(r.done, {}), true});
    });
  }

  // Why a robot state cannot be restored, by throwing std::invalid_argument. Lock held.
  void check(const RobotState& state) {
    auto& r = robot(state.robot);
    const auto near_free = [&](Point p) {
      return std::isfinite(p.x) && std::isfinite(p.y) &&
             r.grid->nearest_free(p, 2 * r.grid->resolution()).has_value();
    };
    if (!std::isfinite(state.pose.theta)) {
      throw std::invalid_argument(
          fmt::format("robot \"{}\": heading {} is not a finite angle", state.robot, state.pose.theta));
    }
    if (!near_free(state.pose.position())) {
      throw std::invalid_argument(fmt::format(
          "robot \"{}\" at ({}, {}) is not on a free spot of house \"{}\" for its radius {} m",
          state.robot, state.pose.x, state.pose.y, house.name, r.spec->radius));
    }
    for (const auto& p : state.path) {
      if (!near_free(p)) {
        throw std::invalid_argument(fmt::format(
            "robot \"{}\": path point ({}, {}) is not on a free spot of house \"{}\" for its "
            "radius {} m",
            state.robot, p.x, p.y, house.name, r.spec->radius));
      }
    }
    if (state.moving() && state.start > state.at) {
      throw std::invalid_argument(
          fmt::format("robot \"{}\": its motion starts at {} ms, after the state was taken ({} ms)",
                      state.robot, state.start.count(), state.at.count()));
    }
  }

  void schedule_report(Robot& r, Time t) {
    r.report_timer = schedule(t, [this, &r](Notes& notes) {
      r.report_timer = 0;
      const auto now = clock.now();
      notes.push_back(PoseNote{r.spec->id, r.pose_at(now), true});
      if (r.motion && now + options.report_every < r.motion->end()) {
        schedule_report(r, now + options.report_every);
      }
    });
  }

  // --- users ---------------------------------------------------------------------------------

  void notify(User& u, Notes& notes, Time now) {
    auto state = u.state;
    if (u.walk) state.at = u.walk->at(now).position();
    notes.push_back(std::move(state));
  }

  // Queues the user's activities of `day` from `not_before` on, then the next day's.
  void schedule_day(User& u, std::int64_t day, Time not_before) {
    const Time day_start = kDay * day;
    const auto jitter_ms = u.spec->time_jitter.count();
    Time previous = std::max(day_start, not_before);
    for (const auto& entry : u.spec->schedule) {
      // Draw for every entry, scheduled or not: the draws do not depend on the start time.
      const auto jitter = Time(
          static_cast<std::int64_t>(u.rng() % static_cast<std::uint64_t>(2 * jitter_ms + 1)) -
          jitter_ms);
      const double unit = static_cast<double>(u.rng() >> 11) * 0x1.0p-53;  // [0, 1)
      const double loudness = u.spec->loudness_db + (2 * unit - 1) * u.spec->loudness_jitter_db;
      if (day_start + entry.at < not_before) continue;
      const Time t = std::max(day_start + entry.at + jitter, previous);
      previous = t;
      schedule(t, [this, &u, p = Pending{entry, loudness}](Notes& notes) {
        u.queue.push_back(p);
        run_next(u, notes, clock.now());
      });
    }
    if (u.spec->daily) {
      schedule(day_start + kDay,
               [this, &u, day](Notes&) { schedule_day(u, day + 1, kDay * (day + 1)); });
    }
  }

  // Starts queued activities until one takes time (a walk) or the queue is empty.
  void run_next(User& u, Notes& notes, Time now) {
    while (!u.walk && !u.queue.empty()) {
      const auto p = std::move(u.queue.front());
      u.queue.pop_front();
      const auto& e = p.entry;
      switch (e.activity) {
        case Activity::say:
          notes.push_back(
              Utterance{u.spec->id, e.text, u.state.room, u.state.at, now, p.loudness_db});
          break;
        case Activity::stand:
          get_up(u, notes, now);
          break;
        case Activity::go_to:
          get_up(u, notes, now);
          walk(u, e.target, Posture::standing, notes, now);
          break;
        case Activity::sit:
        case Activity::lie: {
          const auto posture = e.activity == Activity::sit ? Posture::sitting : Posture::lying;
          if (u.state.furniture == e.target) {  // already on it: sit up or lie down
            if (u.state.posture != posture) {
              u.state.posture = posture;
              notify(u, notes, now);
            }
            break;
          }
          get_up(u, notes, now);
          walk(u, e.target, posture, notes, now);
          break;
        }
      }
    }
  }

  void get_up(User& u, Notes& notes, Time now) {
    if (u.state.furniture.empty()) return;
    occupancy.erase(u.state.furniture);
    if (const auto spot = house.locate(u.state.furniture)) u.state.at = *spot;
    u.state.furniture.clear();
    u.state.posture = Posture::standing;
    u.state.room = room_name(u.state.at);
    notify(u, notes, now);
  }

  // Walks to `target` (a waypoint, room, or furniture's approach spot), then takes `posture`
  // (sitting or lying: on the furniture `target`).
  void walk(User& u, const std::string& target, Posture posture, Notes& notes, Time now) {
    const auto spot = house.locate(target);
    // A parsed house guarantees every target has a reachable spot; a hand-built one might
    // not, and then the activity is skipped with the user where they are.
    if (!spot) return;
    auto path = plan_path(*u.grid, u.state.at, *spot);
    if (!path) return;
    Motion m{std::move(*path), 0, u.spec->speed, now};
    m.length = path_length(m.path);
    if (m.length < 1e-6) {
      arrive(u, target, posture, notes, now);
      return;
    }
    u.walk = std::move(m);
    u.state.posture = Posture::walking;
    notify(u, notes, now);
    // Room changes happen where the path crosses from one room into another.
    const double step = std::min(0.05, house.resolution);
    std::string room = u.state.room;
    for (double along = step; along < u.walk->length; along += step) {
      auto here = room_name(point_along(u.walk->path, along).position());
      if (here.empty() || here == room) continue;
      room = here;
      schedule(now + travel_time(along, u.spec->speed), [this, &u, here](Notes& n) {
        u.state.room = here;
        notify(u, n, clock.now());
      });
    }
    schedule(u.walk->end(), [this, &u, target, posture](Notes& n) {
      const auto t = clock.now();
      arrive(u, target, posture, n, t);
      run_next(u, n, t);
    });
  }

  void arrive(User& u, const std::string& target, Posture posture, Notes& notes, Time now) {
    if (u.walk) u.state.at = u.walk->path.back();
    u.walk.reset();
    u.state.posture = posture;
    if (posture == Posture::sitting || posture == Posture::lying) {
      const auto* f = house.find_furniture(target);
      u.state.at = f->area.center();
      u.state.furniture = target;
      occupancy[target] = u.spec->id;
    }
    u.state.room = room_name(u.state.at);
    notify(u, notes, now);
  }
};

World::World(House house, SimClock& clock, WorldOptions options)
    : impl_(std::make_shared<Impl>(std::move(house), clock, options)) {
  auto& s = *impl_;
  std::lock_guard lock(s.mutex);
  for (const auto& spec : s.house.robots) {
    auto& r = s.robots[spec.id];
    r.spec = &spec;
    r.grid = s.grid_for(spec.radius);
    r.pose = spec.start;
  }
  const auto now = clock.now();
  const Time not_before = std::max(now, s.house.start_time);
  for (std::size_t i = 0; i < s.house.users.size(); ++i) {
    const auto& spec = s.house.users[i];
    auto& u = s.users[spec.id];
    u.spec = &spec;
    u.grid = s.grid_for(spec.radius);
    u.state = UserState{spec.id, s.room_name(spec.start), "", spec.start, Posture::standing};
    u.rng.seed(splitmix64(s.house.seed ^ splitmix64(i)));
    s.schedule_day(u, not_before / kDay, not_before);
  }
}

World::~World() {
  std::lock_guard lock(impl_->mutex);
  for (const auto id : impl_->timers) impl_->clock.cancel(id);
  impl_->timers.clear();
}

const House& World::house() const { return impl_->house; }
SimClock& World::clock() { return impl_->clock; }

Pose World::robot_pose(const std::string& robot) const {
  std::lock_guard lock(impl_->mutex);
  return impl_->robot(robot).pose_at(impl_->clock.now());
}

std::string World::robot_room(const std::string& robot) const {
  return impl_->room_name(robot_pose(robot).position());
}

bool World::robot_moving(const std::string& robot) const {
  std::lock_guard lock(impl_->mutex);
  return impl_->robot(robot).motion.has_value();
}

std::optional<std::vector<Point>> World::move_robot(const std::string& robot, Point target,
                                                    std::function<void(bool)> done) {
  auto& s = *impl_;
  Impl::Notes notes;
  std::optional<std::vector<Point>> result;
  {
    std::lock_guard lock(s.mutex);
    auto& r = s.robot(robot);
    const auto now = s.clock.now();
    const auto from = r.pose_at(now);
    const auto plan = [&](const OccupancyGrid& grid) -> std::optional<std::vector<Point>> {
      const auto goal = s.options.snap_distance > 0
                            ? grid.nearest_free(target, s.options.snap_distance, from.position())
                            : std::optional<Point>(target);
      if (!goal) return std::nullopt;
      return plan_path(grid, from.position(), *goal);
    };
    // Around the other robots where they are now; through them when there is no way around (a
    // robot standing in a doorway).
    std::vector<OccupancyGrid::Disc> others;
    for (const auto& [id, other] : s.robots) {
      if (&other != &r) others.push_back({other.pose_at(now).position(), other.spec->radius});
    }
    std::optional<std::vector<Point>> path;
    if (!others.empty()) path = plan(r.grid->with_discs(others));
    if (!path) path = plan(*r.grid);
    if (!path) return std::nullopt;
    result = path;

    s.halt(r, now, notes);  // a superseded motion ends here
    if (!notes.empty()) {   // its `done` runs from the clock, not inside this call
      s.schedule(now, [notes](Impl::Notes& n) { n.insert(n.end(), notes.begin(), notes.end()); });
      notes.clear();
    }
    Motion m{std::move(*path), 0, r.spec->speed, now};
    m.length = path_length(m.path);
    if (s.robots.size() > 1) s.take_turns_at_doors(r, m, now);
    s.drive(r, std::move(m), std::move(done), now);
  }
  return result;
}

void World::stop_robot(const std::string& robot) {
  auto& s = *impl_;
  std::lock_guard lock(s.mutex);
  auto& r = s.robot(robot);
  if (!r.motion) return;
  const auto now = s.clock.now();
  Impl::Notes notes;
  s.halt(r, now, notes);
  notes.insert(notes.begin(), Impl::PoseNote{r.spec->id, r.pose, false});
  s.schedule(now, [notes](Impl::Notes& n) { n.insert(n.end(), notes.begin(), notes.end()); });
}

void World::turn_robot(const std::string& robot, double theta) {
  if (!std::isfinite(theta)) {
    throw std::invalid_argument(
        fmt::format("heading {} for robot \"{}\" is not a finite angle in radians", theta, robot));
  }
  double heading = std::remainder(theta, 2 * std::numbers::pi);  // [-pi, pi]
  if (heading <= -std::numbers::pi) heading += 2 * std::numbers::pi;
  auto& s = *impl_;
  std::lock_guard lock(s.mutex);
  auto& r = s.robot(robot);
  const auto now = s.clock.now();
  Impl::Notes notes;
  s.halt(r, now, notes);
  r.pose.theta = heading;
  notes.insert(notes.begin(), Impl::PoseNote{r.spec->id, r.pose, false});
  s.schedule(now, [notes](Impl::Notes& n) { n.insert(n.end(), notes.begin(), notes.end()); });
}

std::uint64_t World::on_robot_pose(std::function<void(const std::string&, const Pose&, bool)> fn,
                                   Listening listening) {
  std::lock_guard lock(impl_->mutex);
  const auto id = impl_->listener_id(listening);
  impl_->pose_listeners.emplace(id, std::make_shared<Impl::PoseListener>(std::move(fn)));
  return id;
}

void World::place_robot(const std::string& robot, const Pose& pose) {
  if (!std::isfinite(pose.x) || !std::isfinite(pose.y) || !std::isfinite(pose.theta)) {
    throw std::invalid_argument(fmt::format("robot \"{}\" placed at a pose that is not finite", robot));
  }
  auto& s = *impl_;
  std::lock_guard lock(s.mutex);
  auto& r = s.robot(robot);
  const auto now = s.clock.now();
  Impl::Notes notes;
  s.halt(r, now, notes);
  r.pose = pose;
  std::erase_if(notes, [](const Impl::Note& n) { return std::holds_alternative<Impl::PoseNote>(n); });
  if (!notes.empty()) {
    s.schedule(now, [notes](Impl::Notes& n) { n.insert(n.end(), notes.begin(), notes.end()); });
  }
}

std::vector<RobotState> World::robot_states() const {
  std::lock_guard lock(impl_->mutex);
  const auto now = impl_->clock.now();
  std::vector<RobotState> out;
  out.reserve(impl_->robots.size());
  for (const auto& [id, r] : impl_->robots) {
    RobotState state{id, now, r.pose_at(now), {}, Time{0}};
    if (r.motion) {
      state.path = r.motion->path;
      state.start = r.motion->start;
      state.pause_at = r.motion->pause_at;
      state.pause = r.motion->pause;
    }
    out.push_back(std::move(state));
  }
  return out;
}

void World::check_robot_state(const RobotState& state) const {
  std::lock_guard lock(impl_->mutex);
  impl_->check(state);
}

void World::restore_robot(const RobotState& state, std::function<void(bool)> done) {
  auto& s = *impl_;
  std::lock_guard lock(s.mutex);
  s.check(state);
  auto& r = s.robot(state.robot);
  const auto now = s.clock.now();
  Impl::Notes notes;
  s.halt(r, now, notes);
  if (!state.moving()) {
    r.pose = state.pose;
    notes.insert(notes.begin(), Impl::PoseNote{r.spec->id, r.pose, false});
  } else {
    Motion m{state.path, path_length(state.path), r.spec->speed, state.start, state.pause_at, state.pause};
    if (now < state.at) m.start -= state.at - now;  // resume from state.pose
    if (now < m.end()) {
      s.drive(r, std::move(m), std::move(done), now);
    } else {  // over while the state was kept: arrived
      r.pose = m.last();
      notes.push_back(Impl::PoseNote{r.spec->id, r.pose, false});
      if (done) notes.push_back(Impl::DoneNote{std::move(done), true});
    }
  }
  if (!notes.empty()) {
    s.schedule(now, [notes](Impl::Notes& n) { n.insert(n.end(), notes.begin(), notes.end()); });
  }
}

UserState World::user(const std::string& user) const {
  std::lock_guard lock(impl_->mutex);
  auto& u = impl_->user(user);
  auto state = u.state;
  if (u.walk) state.at = u.walk->at(impl_->clock.now()).position();
  return state;
}

std::uint64_t World::on_user(std::function<void(const UserState&)> fn, Listening listening) {
  std::lock_guard lock(impl_->mutex);
  const auto id = impl_->listener_id(listening);
  impl_->user_listeners.emplace(id, std::make_shared<Impl::UserListener>(std::move(fn)));
  return id;
}

std::uint64_t World::on_utterance(std::function<void(const Utterance&)> fn, Listening listening) {
  std::lock_guard lock(impl_->mutex);
  const auto id = impl_->listener_id(listening);
  impl_->utterance_listeners.emplace(id, std::make_shared<Impl::UtteranceListener>(std::move(fn)));
  return id;
}

void World::say(const std::string& user, const std::string& text) {
  auto& s = *impl_;
  std::lock_guard lock(s.mutex);
  auto& u = s.user(user);
  const auto now = s.clock.now();
  const auto at = u.walk ? u.walk->at(now).position() : u.state.at;
  Utterance utterance{u.spec->id, text, s.room_name(at), at, now, u.spec->loudness_db};
  s.schedule(now, [utterance](Impl::Notes& n) { n.push_back(utterance); });
}

bool World::occupied(const std::string& furniture) const {
  std::lock_guard lock(impl_->mutex);
  return impl_->occupancy.contains(furniture);
}

Pose World::device_pose(const std::string& device) const {
  const auto* spec = impl_->house.device(device);
  if (!spec) throw std::invalid_argument(fmt::format("unknown device \"{}\"", device));
  if (spec->carrier.empty()) return spec->pose;
  return robot_pose(spec->carrier);
}

double World::sound_level(const Utterance& utterance, Point at) const {
  const double d = std::max(1.0, distance(utterance.at, at));
  double level = utterance.loudness_db - 20.0 * std::log10(d);
  for (const auto& w : impl_->house.walls) {
    if (segments_cross(utterance.at, at, w.a, w.b)) level -= 10.0;
  }
  return level;
}

void World::remove_listener(std::uint64_t id) {
  {
    std::lock_guard lock(impl_->mutex);
    impl_->pose_listeners.erase(id);
    impl_->user_listeners.erase(id);
    impl_->utterance_listeners.erase(id);
  }
  if (impl_->delivering_thread.load() != std::this_thread::get_id()) {
    std::lock_guard wait_for_delivery(impl_->delivery_mutex);
  }
}

}  // namespace icars::sim
