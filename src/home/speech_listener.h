// A behavior that acts on spoken phrases: it listens to every available SpeechSensor and tells
// each the phrases it acts on while it runs, so the recognizer decodes against what the running
// policy can do (docs/speech.md). VoiceTVControl, VoiceAudioControl and VoiceCommands are ones.
#pragma once

#include <string>
#include <vector>

#include "icars/behavior/behavior.h"
#include "icars/home/services.h"

namespace icars::home {

class SpeechListener : public behavior::Behavior {
 protected:
  // From entry(): BehaviorError when no SpeechSensor is available. The phrases are withdrawn
  // when the behavior exits.
  void listen_for_phrases(std::vector<std::string> phrases) {
    const auto sensors = services().find(service::ServiceQuery::of_type("SpeechSensor").available());
    if (sensors.empty()) throw behavior::BehaviorError("no available SpeechSensor service");
    for (const auto& found : sensors) {
      auto sensor = std::static_pointer_cast<SpeechSensor>(found);
      on_release(sensor->hold_phrases(this, phrases));
      listen(sensor);
    }
  }
};

}  // namespace icars::home
