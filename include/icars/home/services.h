// The adaptive services of the home (ICARS paper 3.3, 4.3.1, Figs. 4 and 10b): services composed
// from or augmenting the home's adaptor services, built by a service::Composer that watches the
// service container (home::composer() for a ServerOptions or a ServiceFramework).
//
// - SpeechSensor = SoundSensor + SpeechRecognizer: every sound's audio is recognized against the
//   phrases its listeners act on and published as a SpeechEvent carrying the phrase, or as an
//   UnrecognizedSpeech.
// - SoundLocalizer: the direction each sound of a microphone array came from.
// - CameraFactory: makes a camera sharable: one capture serves every user that asks within
//   `max_age`, so several behaviors looking through one robot camera cost one remote call.
// - UserLocator = CameraFactory + FaceRecognizer: finds the people the camera sees and
//   publishes where they are.
//
// A composite is available while all its parts are. CompositeFactories create composites as
// soon as their parts are in the container and keep them across the parts' reconnections.
#pragma once

#include <asio/steady_timer.hpp>
#include <asio/thread_pool.hpp>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <type_traits>
#include <vector>

#include "icars/home/adaptors.h"
#include "icars/home/sound_sensor.h"
#include "icars/service/service_container.h"
#include "icars/service/service_framework.h"

namespace icars::home {

// SpeechEvent and UserLocation, the composites' events, are typed PLANET events declared in
// idl/home.idl (docs/events.md), so behaviors see them like any sensor's.

class SpeechSensor final : public service::Service {
 public:
  SpeechSensor(std::shared_ptr<SoundSensor> sound, std::shared_ptr<SpeechRecognizerService> recognizer);
  ~SpeechSensor() override;

  // `fn` runs for every SpeechEvent; a callable that also takes an UnrecognizedSpeech (a
  // behavior's generic listener) gets those too. Returns an id for unsubscribe.
  template <class F>
  std::uint64_t subscribe(F fn) {
    if constexpr (std::is_invocable_v<F&, const UnrecognizedSpeech&>) {
      return add_subscription(fn, fn);
    } else {
      return add_subscription(std::move(fn), nullptr);
    }
  }
  void unsubscribe(std::uint64_t id);

  // The phrases `listener` acts on (a voice-control behavior, while it runs): the recognizer
  // decodes against the union of every listener's phrases, so it hears what the running policy
  // can act on and reports anything else as UnrecognizedSpeech. With none, free speech.
  void want_phrases(const void* listener, std::vector<std::string> phrases);
  void drop_phrases(const void* listener);
  // want_phrases, and the call that drops them again (harmless once this sensor is gone): what a
  // behavior hands to on_release.
  std::function<void()> hold_phrases(const void* listener, std::vector<std::string> phrases);
  std::vector<std::string> phrases() const;  // the union, sorted

  std::uint64_t recognized() const { return recognized_.load(); }
  std::uint64_t rejected() const { return rejected_.load(); }
  std::uint64_t retried() const { return retried_.load(); }
  std::size_t waiting() const;  // sounds waiting for the recognizer to be reachable again

  // Speech is delivered in the order it was heard. Sounds whose recognition failed because the
  // recognizer could not be reached (its link dropped, a call timed out, it was overloaded) are
  // kept, at most kMaxWaiting for at most kMaxWait, and recognized again when it is reachable
  // again, or every kRetryAfter while it stays connected; what was heard after them waits for
  // them. Past those bounds a sound is rejected: listeners get an UnrecognizedSpeech saying why,
  // so no sound is lost without a word.
  static constexpr std::size_t kMaxWaiting = 64;
  static constexpr std::chrono::seconds kMaxWait{120};
  static constexpr std::chrono::seconds kRetryAfter{2};

 private:
  struct Heard {
    std::uint64_t seq = 0;  // in the order the sounds came
    planet::Binary audio;
    int sample_rate = 0;
    int channels = 0;
    SpeechEvent speech;
    std::chrono::steady_clock::time_point at;
    bool retried_at_once = false;
    std::string last_error;  // why the recognizer could not be reached, last time
  };
  struct Outcome {
    std::optional<SpeechEvent> speech;
    std::optional<UnrecognizedSpeech> unrecognized;
  };
  std::uint64_t add_subscription(std::function<void(const SpeechEvent&)> speech,
                                 std::function<void(const UnrecognizedSpeech&)> unrecognized);
  void on_sound(const home::SoundEvent& e);
  void recognize(Heard h);
  // Keeps `h` for the recognizer's return; false when it is too old or too many wait.
  bool wait_for_recognizer(Heard h);
  void retry_waiting();
  // Retries the waiting sounds after kRetryAfter unless a retry is due already.
  void retry_later();
  // Rejects `h`: an UnrecognizedSpeech saying why (`why` and the last error).
  void give_up(Heard h, const std::string& why);
  // Records the outcome of sound `seq` (neither: rejected, nothing to tell) and delivers what
  // is in order.
  void settle(std::uint64_t seq, Outcome outcome);
  void update_availability();

  std::shared_ptr<SoundSensor> sound_;
  std::shared_ptr<SpeechRecognizerService> recognizer_;
  std::uint64_t sound_subscription_ = 0;
  std::uint64_t sound_watch_ = 0;
  std::uint64_t recognizer_watch_ = 0;
  service::Listeners<SpeechEvent> events_;
  service::Listeners<UnrecognizedSpeech> unrecognized_;
  std::atomic<std::uint64_t> recognized_{0};
  std::atomic<std::uint64_t> rejected_{0};
  std::atomic<std::uint64_t> retried_{0};
  mutable std::mutex mutex_;
  std::uint64_t next_seq_ = 0;     // the next sound's
  std::uint64_t deliver_seq_ = 0;  // the next to deliver
  std::map<std::uint64_t, Outcome> settled_;  // out of order so far
  std::deque<Heard> waiting_;
  std::shared_ptr<asio::steady_timer> retry_timer_;  // armed: a retry of waiting_ is due
  std::map<const void*, std::vector<std::string>> wanted_;
  std::uint64_t next_subscription_ = 0;
  std::map<std::uint64_t, std::pair<std::uint64_t, std::uint64_t>> subscriptions_;
  std::mutex deliver_mutex_;  // one deliverer at a time, so listeners see the order
};

// Where sounds come from: for a SoundSensor on a microphone array, the direction of each sound
// estimated from the delays between its channels (GCC-PHAT, include/icars/audio/direction.h),
// published as a SoundDirection (bearing from the array's front) from the localizer's own
// thread, in the order the sounds came. Sounds of a one-channel microphone cannot be located
// and are only counted.
class SoundLocalizer final : public service::Service {
 public:
  explicit SoundLocalizer(std::shared_ptr<SoundSensor> sound);
  ~SoundLocalizer() override;

  std::uint64_t subscribe(std::function<void(const SoundDirection&)> fn) { return events_.add(std::move(fn)); }
  void unsubscribe(std::uint64_t id) { events_.remove(id); }
  std::uint64_t located() const { return located_.load(); }
  std::uint64_t unlocated() const { return unlocated_.load(); }

 private:
  void on_sound(const SoundEvent& e);
  std::shared_ptr<SoundSensor> sound_;
  std::uint64_t subscription_ = 0;
  std::uint64_t watch_ = 0;
  service::Listeners<SoundDirection> events_;
  std::atomic<std::uint64_t> located_{0};
  std::atomic<std::uint64_t> unlocated_{0};
  asio::thread_pool worker_{1};  // where the correlations run; joined before the rest goes
};

// A shared camera: `capture` completes with the newest image no older than max_age, taking a
// new one (one remote call for all waiting users) when needed.
class CameraFactory final : public service::Service {
 public:
  using Capture = std::function<void(std::exception_ptr, const home::Image&)>;
  CameraFactory(std::shared_ptr<CameraService> camera, std::chrono::milliseconds max_age);
  ~CameraFactory() override;

  void capture(Capture done);
  std::uint64_t remote_captures() const { return remote_captures_.load(); }

 private:
  std::shared_ptr<CameraService> camera_;
  std::chrono::milliseconds max_age_;
  std::uint64_t watch_ = 0;
  std::mutex mutex_;
  bool capturing_ = false;
  std::vector<Capture> waiting_;
  std::chrono::steady_clock::time_point taken_at_{};
  std::optional<home::Image> latest_;
  std::atomic<std::uint64_t> remote_captures_{0};
};

class UserLocator final : public service::Service {
 public:
  UserLocator(std::shared_ptr<CameraFactory> camera, std::shared_ptr<FaceRecognizerService> faces);
  ~UserLocator() override;

  // Looks once: captures (shared), recognizes, publishes one UserLocation per face found and
  // completes with them.
  void locate(std::function<void(std::exception_ptr, const std::vector<UserLocation>&)> done);
  std::uint64_t subscribe(std::function<void(const UserLocation&)> fn) { return events_.add(std::move(fn)); }
  void unsubscribe(std::uint64_t id) { events_.remove(id); }

 private:
  void update_availability();
  std::shared_ptr<CameraFactory> camera_;
  std::shared_ptr<FaceRecognizerService> faces_;
  std::uint64_t camera_watch_ = 0;
  std::uint64_t faces_watch_ = 0;
  service::Listeners<UserLocation> events_;
};

// Builds the adaptive services of the house as their parts appear in the container:
// a SpeechSensor per SoundSensor (with the first SpeechRecognizer), a CameraFactory per Camera,
// and a UserLocator per CameraFactory (with the first FaceRecognizer).
class CompositeFactory final : public service::Composer {
 public:
  // camera_max_age is wall-clock time: with a simulated house running at 1000x, 200 ms are minutes
  // of simulated time and a robot that moved meanwhile would be shown an old room. By default
  // only a capture in flight is shared.
  explicit CompositeFactory(service::ServiceContainer& container,
                            std::chrono::milliseconds camera_max_age = std::chrono::milliseconds(0));
  ~CompositeFactory() override;
  CompositeFactory(const CompositeFactory&) = delete;
  CompositeFactory& operator=(const CompositeFactory&) = delete;

 private:
  void compose();
  service::ServiceContainer& container_;
  std::chrono::milliseconds camera_max_age_;
  std::uint64_t watch_ = 0;
  std::recursive_mutex mutex_;
};

// A CompositeFactory for every ServiceFramework made with it (ServerOptions::composers).
service::MakeComposer composer(std::chrono::milliseconds camera_max_age = std::chrono::milliseconds(0));

}  // namespace icars::home
