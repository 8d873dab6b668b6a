// The behaviors of a smart home with a robotic mediator (ICARS paper 5.3, Table 6; Fig. 11b):
// what the paper's application — and applications like it — are composed from in a policy.
//
//   Sense              propagates the events of sensor services (occupancy, speech, motion...)
//   GoToUser           finds the user with the robot's camera and drives to them
//   VoiceTVControl     voice commands → TV (power, channel, volume)
//   VoiceAudioControl  voice commands → the robot's speaker (music, volume)
//   LookAtSound        turns the robot towards sounds (Fig. 11b)
//   MoodControl        lights off, calm music for a while
//   PatrolHome         drives a round of waypoints, reporting motion it sees
//   GoTo, Speak, SetLights   single actions, for composing other applications
//
// register_behaviors() adds them all, with their declared parameters, to a registry.
#pragma once

#include <map>
#include <memory>
#include <string>
#include <vector>

#include "icars/behavior/behavior.h"
#include "icars/behavior/registry.h"
#include "icars/home/adaptors.h"
#include "icars/home/services.h"

namespace icars::home {

void register_behaviors(behavior::BehaviorRegistry& registry);
// A registry with the generic behaviors (Wait, Emit) and the house behaviors: what `icars` runs.
behavior::BehaviorRegistry behavior_registry();

// Fig. 11b: binds the robot's wheels and the sound localizer of its microphone array at entry;
// on every sound loud and clear enough turns the robot towards where the localizer estimated it
// came from (the robot's heading now plus the sound's bearing from the array's front). The robot:
// the one named, the first with a microphone array, or with robot="any" every robot with one,
// each turning to what its own array hears.
class LookAtSound : public behavior::Behavior {
 public:
  explicit LookAtSound(const behavior::Params& p)
      : min_level_db_(p.number("min_level_db")), min_confidence_(p.number("min_confidence")), robot_(p.string("robot")) {}

 protected:
  void entry() override;
  void handle_event(const behavior::Event&) override {}

 private:
  void on_sound(const std::string& robot, const behavior::Event& e);
  double min_level_db_;
  double min_confidence_;
  std::string robot_;
  std::map<std::string, std::shared_ptr<NavigationService>> wheels_;  // by robot
};

}  // namespace icars::home
