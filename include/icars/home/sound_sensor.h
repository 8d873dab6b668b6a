// The SoundSensor: the mediating server's service for a Microphone (ICARS paper Fig. 11). It
// opens the microphone's live capture (a PLANET stream of audio frames, with the stream's flow
// control), cuts it into sounds with voice-activity detection, and publishes each as a
// SoundEvent carrying every channel's audio, so nothing needs a push-to-talk. A capture that
// breaks (the device restarted, a malformed frame, the link dropped) is reported, what was
// heard of a sound in progress is published as interrupted, and the capture is opened again
// while the device is registered, resuming where it broke (the microphone sends its recent
// frames again), so nothing said meanwhile is lost and nothing is heard twice.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "home.planet.h"
#include "icars/audio/direction.h"
#include "icars/audio/vad.h"
#include "icars/clock/activity.h"
#include "icars/service/adaptor.h"

namespace icars::planet {
class InputStream;
}

namespace icars::home {

class SoundSensor final : public service::AdaptorOf<home::MicrophonePrx> {
 public:
  SoundSensor(const df::DeviceInfo& d, const df::CapabilityInfo& c);
  ~SoundSensor() override;

  // `fn(event)` runs for every sound, on the server's io thread. Returns an id for unsubscribe.
  std::uint64_t subscribe(std::function<void(const SoundEvent&)> fn) { return events_.add(std::move(fn)); }
  void unsubscribe(std::uint64_t id) { events_.remove(id); }

  // The microphone's format and array geometry, once read after a bind.
  std::optional<MicrophoneInfo> info() const;

  struct Stats {
    std::uint64_t frames = 0;        // audio frames received
    std::uint64_t sounds = 0;        // SoundEvents published
    std::uint64_t interrupted = 0;   // of which the capture ended mid-sound
    std::uint64_t captures = 0;      // captures opened
    std::uint64_t broken = 0;        // captures that ended with an error
    std::string last_error;          // why the last one broke
  };
  Stats stats() const;
  // Holds the lock-step clock of the server this sensor is bound in (if it runs in lock-step)
  // while work on one of its sounds goes on elsewhere: the work happens at the sound's time.
  Activity::Hold hold_work() const;

 protected:
  void on_bind(planet::Communicator& communicator, const std::shared_ptr<planet::Link>& link) override;
  void on_unbind() override;
  void on_removed() override;

 private:
  struct Capture;
  void start_capture(std::uint64_t generation);
  void read_next(const std::shared_ptr<Capture>& capture);
  void capture_ended(const std::shared_ptr<Capture>& capture, const std::string& error);
  // False for a frame already heard (a capture resumed after a break sends the microphone's
  // recent frames again); otherwise the frame is the new resume point.
  bool resume_at(const audio::AudioBlock& block);
  void publish(const audio::Utterance& u, const Capture& capture);
  void stop_capture();

  service::Listeners<SoundEvent> events_;
  mutable std::mutex mutex_;
  planet::Communicator* communicator_ = nullptr;
  std::shared_ptr<planet::Link> link_;
  std::uint64_t generation_ = 0;  // changes on every bind and unbind: older captures stop
  std::shared_ptr<Capture> capture_;
  std::optional<MicrophoneInfo> info_;
  Stats stats_;
  std::chrono::milliseconds reopen_delay_{500};
  std::uint64_t resume_from_ = 0;  // end of the last frame heard: where a new capture resumes
};

// The audio of `e` as a block (AudioError if its byte count does not fit its channels).
audio::AudioBlock audio_of(const SoundEvent& e);
// Where `e` came from, for a microphone array of at least two channels (nullopt otherwise).
std::optional<audio::DirectionEstimate> locate_sound(const SoundEvent& e, const MicrophoneInfo& info);

}  // namespace icars::home
