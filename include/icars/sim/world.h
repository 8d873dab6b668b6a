// The simulated house running on a SimClock: robots that drive along planned paths, users who
// live their daily schedule (walking from room to room, sitting, lying down, speaking), and
// the positions of every device.
//
// Simulated devices (ICARS section 5: TV, lights, occupancy sensors, the robot's wheels,
// microphone, speaker and camera) are built on this: a wheel base calls move_robot(), a
// microphone listens to on_utterance() and keeps what is loud enough at its device_pose(), a
// bed sensor watches occupied("bed") through on_user(). All methods are thread-safe.
// Listeners and `done` callbacks are always called on the thread that advances the clock,
// from a clock event, with no World lock held — so they may call back into the World —
// and never inside the call that caused them.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "icars/clock/sim_clock.h"
#include "icars/sim/house.h"

namespace icars::sim {

struct Utterance {
  std::string user, text, room;
  Point at;
  Time time{0};
  double loudness_db = 60.0;  // at 1 m from the speaker
};

enum class Posture { standing, walking, sitting, lying };
std::string_view to_string(Posture posture);

struct UserState {
  std::string user, room;
  std::string furniture;  // sat or lying on, or ""
  Point at;
  Posture posture = Posture::standing;
  friend bool operator==(const UserState&, const UserState&) = default;
};

// A robot's state as a device manager's state file keeps it (home::SimStateFile):
// where it stands, or the motion it is driving, which the clock alone carries on — so a
// driving robot needs no write per step to be restored exactly.
struct RobotState {
  std::string robot;
  Time at{0};            // the clock's time when the state was taken
  Pose pose;                // where the robot was at `at`
  std::vector<Point> path;  // the path it is driving, from where it set off; empty: standing
  Time start{0};         // when it set off along `path`
  // A wait on the way (another robot has the narrow door ahead): `pause` long, `pause_at`
  // metres along the path.
  double pause_at = 0;
  Time pause{0};
  bool moving() const { return !path.empty(); }
  friend bool operator==(const RobotState&, const RobotState&) = default;
};

struct WorldOptions {
  Time report_every{500};   // pose reports while a robot moves
  double snap_distance = 1.5;  // m: a blocked move target is replaced by the nearest free spot
};

class World {
 public:
  // Places robots and users at their start and schedules the users' activities from
  // max(clock.now(), house.start_time) on (construct the clock at house.start_time). Each
  // activity is shifted by a seed-driven jitter of up to the user's time_jitter and each
  // utterance's loudness by up to loudness_jitter_db: the same house and seed give the same
  // run. Activities run one after another: one due while the user is still walking starts on
  // arrival.
  World(House house, SimClock& clock, WorldOptions options = {});
  ~World();  // cancels the World's pending events; do not destroy while the clock advances
  World(const World&) = delete;
  World& operator=(const World&) = delete;

  const House& house() const;
  SimClock& clock();

  // Unknown robot, user or device ids throw std::invalid_argument.
  Pose robot_pose(const std::string& robot) const;  // exact at clock().now(), also mid-motion
  std::string robot_room(const std::string& robot) const;  // "" in a doorway outside rooms
  bool robot_moving(const std::string& robot) const;

  // Plans from the robot's pose to `target` around the other robots where they stand now (when
  // there is no way around them, through them), and drives along the path at the robot's speed,
  // reporting the pose to pose listeners when it starts (moving), every report_every, and on
  // arrival (not moving). Robots take turns at a narrow door (narrower than two of them side by
  // side with 10 cm to spare): a robot whose path crosses one in the time another robot's motion
  // holds it waits before the door until the door is free, still reported as moving. A target inside an obstacle (a user on the sofa) is replaced by
  // the nearest free reachable spot within snap_distance. Returns the path, or nullopt (and no
  // motion, no `done`) when unreachable. Otherwise `done` runs exactly once: true on arrival,
  // false if stop_robot() or a later move_robot() ends this motion first.
  std::optional<std::vector<Point>> move_robot(const std::string& robot, Point target,
                                               std::function<void(bool arrived)> done = {});
  // Stops where the robot is now; pose listeners then hear it stopped. No-op when not moving.
  void stop_robot(const std::string& robot);
  // Turns the robot in place to heading `theta` (radians, house frame), stopping a motion in
  // progress as stop_robot() does (its `done` hears false). Pose listeners then hear the new
  // heading, not moving, from a clock event at the current time, even when the heading did
  // not change. The heading is normalised to (-pi, pi]; a non-finite one throws
  // std::invalid_argument.
  void turn_robot(const std::string& robot, double theta);
  // Who hears a change first. Observers (a trace, a plot: they record what happened) hear it
  // before reactors (devices: they act on it), so the record of a cause is written before any
  // reaction to it, whichever thread that reaction runs on. In each group, in registration order.
  enum class Listening { reacting, observing };
  std::uint64_t on_robot_pose(
      std::function<void(const std::string& robot, const Pose& pose, bool moving)> fn,
      Listening listening = Listening::reacting);

  // A robot driven elsewhere (by another device manager's world, known from its announcements)
  // stands at `pose` here, so that this world's robots plan around it; a motion it had here ends
  // (its `done` hears false). Pose listeners are not told: the robot is not this world's to report.
  void place_robot(const std::string& robot, const Pose& pose);

  // Every robot's state now, ordered by id.
  std::vector<RobotState> robot_states() const;
  // Throws std::invalid_argument naming the robot and what is wrong when restore_robot()
  // would refuse `state`: an unknown robot, a non-finite number, a pose or path point that is
  // not on (or within two grid cells of) a free spot for the robot's radius, a motion that
  // starts after `at`.
  void check_robot_state(const RobotState& state) const;
  // Puts a robot back into a state taken by robot_states(), ending a motion in progress (its
  // `done` hears false). Standing: the robot stands at state.pose. Driving: the motion goes on
  // along state.path at the robot's speed as if nothing had happened — with the clock at or
  // past state.at the robot is where the motion puts it now (at the end of the path,
  // arrived, when it is over); with the clock behind state.at (a restart without a common
  // epoch) the motion is shifted in time so the robot resumes from state.pose. `done` runs as
  // for move_robot() when a motion is restored (true on arrival), never for a standing robot.
  // Pose listeners hear the pose from a clock event at the current time. Throws as
  // check_robot_state() does.
  void restore_robot(const RobotState& state, std::function<void(bool arrived)> done = {});

  UserState user(const std::string& user) const;  // position exact at clock().now()
  // Called when a user's room, posture or furniture changes (not for every step of a walk).
  std::uint64_t on_user(std::function<void(const UserState&)> fn, Listening listening = Listening::reacting);
  std::uint64_t on_utterance(std::function<void(const Utterance&)> fn, Listening listening = Listening::reacting);
  // An utterance by `user` now, at the user's position and nominal loudness (tests, demos);
  // listeners hear it from a clock event at the current time (advance_by(0) delivers it).
  void say(const std::string& user, const std::string& text);

  bool occupied(const std::string& furniture) const;  // someone sits or lies on it
  Pose device_pose(const std::string& device) const;  // carried devices move with the robot
  // Level in dB of an utterance heard at `at`: its loudness minus 20 log10(distance / 1 m)
  // (distance at least 1 m), minus 10 dB for every wall between (open doors do not count).
  double sound_level(const Utterance& utterance, Point at) const;

  // After this returns the listener is not running and never runs again (it waits for a call
  // in progress on the clock's thread), so its owner may be destroyed. Called from inside a
  // listener, it does not wait: the running call finishes normally.
  void remove_listener(std::uint64_t id);

 private:
  struct Impl;
  std::shared_ptr<Impl> impl_;
};

}  // namespace icars::sim
