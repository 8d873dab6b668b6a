#include "icars/home/services.h"

#include <asio/post.hpp>
#include <fmt/format.h>

#include <set>

namespace icars::home {

// --- SpeechSensor ----------------------------------------------------------------------------

SpeechSensor::SpeechSensor(std::shared_ptr<SoundSensor> sound,
                           std::shared_ptr<SpeechRecognizerService> recognizer)
    : service::Service(sound->attributes().device + ".speech_sensor", "SpeechSensor", sound->attributes()),
      sound_(std::move(sound)),
      recognizer_(std::move(recognizer)) {
  sound_subscription_ = sound_->subscribe([this](const home::SoundEvent& e) { on_sound(e); });
  sound_watch_ = sound_->watch([this](const bool&) { update_availability(); });
  recognizer_watch_ = recognizer_->watch([this](const bool&) { update_availability(); });
  update_availability();
}

SpeechSensor::~SpeechSensor() {
  sound_->unsubscribe(sound_subscription_);
  sound_->remove_watcher(sound_watch_);
  recognizer_->remove_watcher(recognizer_watch_);
}

void SpeechSensor::update_availability() {
  set_available(sound_->available() && recognizer_->available());
  if (recognizer_->available()) retry_waiting();
}

void SpeechSensor::on_sound(const home::SoundEvent& e) {
  if (e.audio.bytes.empty()) return;
  retry_waiting();  // what waited goes first
  Heard h;
  h.audio = e.audio;
  h.sample_rate = e.sample_rate;
  h.channels = e.channels;
  h.speech.room = e.room;
  h.speech.device = e.device;
  h.speech.time_ms = e.time_ms;
  h.speech.end_ms = e.end_ms;
  h.at = std::chrono::steady_clock::now();
  {
    std::lock_guard lock(mutex_);
    h.seq = next_seq_++;
  }
  recognize(std::move(h));
}

void SpeechSensor::want_phrases(const void* listener, std::vector<std::string> phrases) {
  std::lock_guard lock(mutex_);
  wanted_[listener] = std::move(phrases);
}

void SpeechSensor::drop_phrases(const void* listener) {
  std::lock_guard lock(mutex_);
  wanted_.erase(listener);
}

std::function<void()> SpeechSensor::hold_phrases(const void* listener, std::vector<std::string> phrases) {
  want_phrases(listener, std::move(phrases));
  return [weak = std::weak_ptr<SpeechSensor>(std::static_pointer_cast<SpeechSensor>(shared_from_this())), listener] {
    if (auto s = weak.lock()) s->drop_phrases(listener);
  };
}

std::vector<std::string> SpeechSensor::phrases() const {
  std::lock_guard lock(mutex_);
  std::set<std::string> all;
  for (const auto& [listener, phrases] : wanted_) all.insert(phrases.begin(), phrases.end());
  return {all.begin(), all.end()};
}

void SpeechSensor::recognize(Heard h) {
  auto audio = h.audio;
  const int rate = h.sample_rate;
  const int channels = h.channels;
  // Decoding takes time in proportion to the sound (two decodes of up to 10 s of audio on a
  // busy machine): the call may take longer than a command. A recognizer that is gone is told
  // by its link, not by this deadline.
  auto proxy = recognizer_->proxy();
  const double seconds = rate > 0 && channels > 0
                             ? static_cast<double>(audio.bytes.size()) / (2.0 * rate * channels)
                             : 0.0;
  const auto deadline = std::chrono::milliseconds(10000 + static_cast<std::int64_t>(seconds * 4000));
  if (deadline > proxy.timeout()) proxy.set_timeout(deadline);
  proxy.recognize_async(
      audio, rate, channels, phrases(),
      [weak = weak_from_this(), h = std::move(h)](std::exception_ptr error, home::Recognition result) mutable {
        auto self = std::static_pointer_cast<SpeechSensor>(weak.lock());
        if (!self) return;
        const auto latency = std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() - h.at);
        if (error) {
          // Not speech (NotRecognized) is an answer; a recognizer out of reach is not.
          bool unreachable = false;
          UnrecognizedSpeech unrecognized{"", "", h.speech.room, h.speech.device, h.speech.time_ms};
          try {
            std::rethrow_exception(error);
          } catch (const home::NotRecognized& e) {
            unrecognized.reason = e.reason();
          } catch (const home::BadAudio& e) {
            unrecognized.reason = "bad audio: " + e.reason();
          } catch (const planet::Error& e) {
            unreachable = e.kind() == planet::ErrorKind::disconnected ||
                          e.kind() == planet::ErrorKind::timeout ||
                          e.kind() == planet::ErrorKind::overloaded;
            unrecognized.reason = e.what();
          } catch (const std::exception& e) {
            unrecognized.reason = e.what();
          }
          if (!unreachable) {
            ++self->rejected_;
            self->settle(h.seq, Outcome{std::nullopt, std::move(unrecognized)});
            return;
          }
          h.last_error = unrecognized.reason;
          self->wait_for_recognizer(std::move(h));
          return;
        }
        h.speech.text = std::move(result.text);
        h.speech.confidence = result.confidence;
        h.speech.latency_ms = latency.count();
        ++self->recognized_;
        self->settle(h.seq, Outcome{std::move(h.speech), std::nullopt});
        self->retry_waiting();  // it is reachable: what waited for it need not wait longer
      });
}

bool SpeechSensor::wait_for_recognizer(Heard h) {
  if (std::chrono::steady_clock::now() - h.at > kMaxWait) {
    give_up(std::move(h), fmt::format("the recognizer could not be reached for {} s", kMaxWait.count()));
    return false;
  }
  // The recognizer may be back already (its watcher fired before this failure came): once.
  if (!h.retried_at_once && recognizer_->available()) {
    h.retried_at_once = true;
    ++retried_;
    recognize(std::move(h));
    return true;
  }
  bool kept = false;
  {
    std::lock_guard lock(mutex_);
    if (waiting_.size() < kMaxWaiting) {
      waiting_.push_back(std::move(h));
      kept = true;
    }
  }
  if (!kept) {
    give_up(std::move(h), fmt::format("{} sounds already wait for the recognizer", kMaxWaiting));
    return false;
  }
  // Still connected (a call that timed out, an engine overloaded): nothing else may come to
  // retry it (no new sound, no reconnection), so a timer does.
  if (recognizer_->available()) retry_later();
  return true;
}

void SpeechSensor::give_up(Heard h, const std::string& why) {
  ++rejected_;
  UnrecognizedSpeech unrecognized{"", "", h.speech.room, h.speech.device, h.speech.time_ms};
  unrecognized.reason = h.last_error.empty() ? why : why + ": " + h.last_error;
  settle(h.seq, Outcome{std::nullopt, std::move(unrecognized)});
}

void SpeechSensor::retry_later() {
  std::shared_ptr<asio::steady_timer> timer;
  try {
    std::lock_guard lock(mutex_);
    if (retry_timer_ || waiting_.empty()) return;
    retry_timer_ = std::make_shared<asio::steady_timer>(recognizer_->proxy().communicator().io(), kRetryAfter);
    timer = retry_timer_;
  } catch (const planet::Error&) {
    return;  // unbound after all: its return retries (update_availability)
  }
  timer->async_wait([weak = weak_from_this(), timer](std::error_code ec) {
    auto self = std::static_pointer_cast<SpeechSensor>(weak.lock());
    if (!self || ec) return;
    {
      std::lock_guard lock(self->mutex_);
      if (self->retry_timer_ == timer) self->retry_timer_.reset();
    }
    self->retry_waiting();
  });
}

std::size_t SpeechSensor::waiting() const {
  std::lock_guard lock(mutex_);
  return waiting_.size();
}

void SpeechSensor::retry_waiting() {
  std::deque<Heard> again;
  {
    std::lock_guard lock(mutex_);
    again.swap(waiting_);
  }
  for (auto& h : again) {
    if (std::chrono::steady_clock::now() - h.at > kMaxWait) {
      give_up(std::move(h), fmt::format("the recognizer could not be reached for {} s", kMaxWait.count()));
      continue;
    }
    ++retried_;
    recognize(std::move(h));
  }
}

void SpeechSensor::settle(std::uint64_t seq, Outcome outcome) {
  std::lock_guard deliver(deliver_mutex_);
  std::vector<Outcome> ready;
  {
    std::lock_guard lock(mutex_);
    settled_.emplace(seq, std::move(outcome));
    for (auto it = settled_.begin(); it != settled_.end() && it->first == deliver_seq_;
         it = settled_.erase(it), ++deliver_seq_) {
      ready.push_back(std::move(it->second));
    }
  }
  for (const auto& o : ready) {
    if (o.speech) events_.notify(*o.speech);
    if (o.unrecognized) unrecognized_.notify(*o.unrecognized);
  }
}

std::uint64_t SpeechSensor::add_subscription(std::function<void(const SpeechEvent&)> speech,
                                             std::function<void(const UnrecognizedSpeech&)> unrecognized) {
  const auto a = events_.add(std::move(speech));
  const auto b = unrecognized ? unrecognized_.add(std::move(unrecognized)) : ~std::uint64_t{0};
  std::lock_guard lock(mutex_);
  const auto id = next_subscription_++;
  subscriptions_[id] = {a, b};
  return id;
}

void SpeechSensor::unsubscribe(std::uint64_t id) {
  std::pair<std::uint64_t, std::uint64_t> ids;
  {
    std::lock_guard lock(mutex_);
    auto it = subscriptions_.find(id);
    if (it == subscriptions_.end()) return;
    ids = it->second;
    subscriptions_.erase(it);
  }
  events_.remove(ids.first);
  if (ids.second != ~std::uint64_t{0}) unrecognized_.remove(ids.second);
}

// --- SoundLocalizer --------------------------------------------------------------------------

SoundLocalizer::SoundLocalizer(std::shared_ptr<SoundSensor> sound)
    : service::Service(sound->attributes().device + ".sound_localizer", "SoundLocalizer", sound->attributes()),
      sound_(std::move(sound)) {
  subscription_ = sound_->subscribe([this](const SoundEvent& e) { on_sound(e); });
  watch_ = sound_->watch([this](const bool& available) { set_available(available); });
  set_available(sound_->available());
}

SoundLocalizer::~SoundLocalizer() {
  sound_->unsubscribe(subscription_);
  sound_->remove_watcher(watch_);
  worker_.join();
}

void SoundLocalizer::on_sound(const SoundEvent& e) {
  const auto info = sound_->info();
  if (!info || e.channels < 2) {
    ++unlocated_;
    return;
  }
  // The correlations take a while for a long sound: on the localizer's own thread, in order.
  asio::post(worker_, [this, e, info = *info, busy = sound_->hold_work()]() mutable {
    const auto found = locate_sound(e, info);
    if (!found || !found->valid) {
      ++unlocated_;
      return;
    }
    ++located_;
    events_.notify(SoundDirection{e.device, found->bearing, found->confidence, e.level_db, e.room, e.time_ms});
    busy.release();
  });
}

// --- CameraFactory ---------------------------------------------------------------------------

CameraFactory::CameraFactory(std::shared_ptr<CameraService> camera, std::chrono::milliseconds max_age)
    : service::Service(camera->attributes().device + ".camera_factory", "CameraFactory", camera->attributes()),
      camera_(std::move(camera)),
      max_age_(max_age) {
  watch_ = camera_->watch([this](const bool& available) { set_available(available); });
  set_available(camera_->available());
}

CameraFactory::~CameraFactory() { camera_->remove_watcher(watch_); }

void CameraFactory::capture(Capture done) {
  {
    std::lock_guard lock(mutex_);
    if (latest_ && std::chrono::steady_clock::now() - taken_at_ <= max_age_) {
      home::Image image = *latest_;
      done(nullptr, image);
      return;
    }
    waiting_.push_back(std::move(done));
    if (capturing_) return;  // the capture in flight serves this caller too
    capturing_ = true;
  }
  ++remote_captures_;
  camera_->proxy().capture_async([weak = weak_from_this()](std::exception_ptr error,
                                                           home::Image image) {
    auto self = std::static_pointer_cast<CameraFactory>(weak.lock());
    if (!self) return;
    std::vector<Capture> waiting;
    {
      std::lock_guard lock(self->mutex_);
      self->capturing_ = false;
      waiting.swap(self->waiting_);
      if (!error) {
        self->latest_ = image;
        self->taken_at_ = std::chrono::steady_clock::now();
      }
    }
    for (auto& w : waiting) w(error, image);
  });
}

// --- UserLocator -----------------------------------------------------------------------------

UserLocator::UserLocator(std::shared_ptr<CameraFactory> camera,
                         std::shared_ptr<FaceRecognizerService> faces)
    : service::Service(camera->attributes().device + ".user_locator", "UserLocator", camera->attributes()),
      camera_(std::move(camera)),
      faces_(std::move(faces)) {
  camera_watch_ = camera_->watch([this](const bool&) { update_availability(); });
  faces_watch_ = faces_->watch([this](const bool&) { update_availability(); });
  update_availability();
}

UserLocator::~UserLocator() {
  camera_->remove_watcher(camera_watch_);
  faces_->remove_watcher(faces_watch_);
}

void UserLocator::update_availability() { set_available(camera_->available() && faces_->available()); }

void UserLocator::locate(std::function<void(std::exception_ptr, const std::vector<UserLocation>&)> done) {
  camera_->capture([weak = weak_from_this(), done = std::move(done)](std::exception_ptr error,
                                                                     const home::Image& image) {
    auto self = std::static_pointer_cast<UserLocator>(weak.lock());
    if (!self || error) {
      done(error ? error : std::make_exception_ptr(planet::Error(planet::ErrorKind::failed,
                                                                 "the user locator is gone")),
           {});
      return;
    }
    self->faces_->proxy().recognize_async(
        image, [weak, done, camera = self->attributes().device, time = image.time_ms](
                   std::exception_ptr e, std::vector<home::Face> faces) {
          std::vector<UserLocation> found;
          auto locator = std::static_pointer_cast<UserLocator>(weak.lock());
          if (!e) {
            for (const auto& f : faces) {
              found.push_back(UserLocation{f.person, f.x, f.y, f.confidence, camera, time});
              if (locator) locator->events_.notify(found.back());
            }
          }
          done(e, found);
        });
  });
}

// --- CompositeFactory ------------------------------------------------------------------------

CompositeFactory::CompositeFactory(service::ServiceContainer& container, std::chrono::milliseconds camera_max_age)
    : container_(container), camera_max_age_(camera_max_age) {
  watch_ = container_.watch([this](const std::shared_ptr<service::Service>&, const service::ServiceChange& change) {
    if (change == service::ServiceChange::added) compose();
  });
  compose();
}

CompositeFactory::~CompositeFactory() { container_.remove_watcher(watch_); }

void CompositeFactory::compose() {
  std::lock_guard lock(mutex_);  // recursive: adding a composite notifies this watcher again
  for (auto& s : container_.find(service::ServiceQuery::of_type("SoundSensor"))) {
    auto sound = std::dynamic_pointer_cast<SoundSensor>(s);
    if (sound && !container_.get(sound->attributes().device + ".sound_localizer")) {
      container_.add(std::make_shared<SoundLocalizer>(sound));
    }
  }
  auto recognizer = container_.find_first<SpeechRecognizerService>(service::ServiceQuery::of_type("SpeechRecognizer"));
  if (recognizer) {
    for (auto& s : container_.find(service::ServiceQuery::of_type("SoundSensor"))) {
      auto sound = std::dynamic_pointer_cast<SoundSensor>(s);
      if (sound && !container_.get(sound->attributes().device + ".speech_sensor")) {
        container_.add(std::make_shared<SpeechSensor>(sound, recognizer));
      }
    }
  }
  for (auto& s : container_.find(service::ServiceQuery::of_type("Camera"))) {
    auto camera = std::dynamic_pointer_cast<CameraService>(s);
    if (camera && !container_.get(camera->attributes().device + ".camera_factory")) {
      container_.add(std::make_shared<CameraFactory>(camera, camera_max_age_));
    }
  }
  auto faces = container_.find_first<FaceRecognizerService>(service::ServiceQuery::of_type("FaceRecognizer"));
  if (faces) {
    for (auto& s : container_.find(service::ServiceQuery::of_type("CameraFactory"))) {
      auto camera = std::dynamic_pointer_cast<CameraFactory>(s);
      if (camera && !container_.get(camera->attributes().device + ".user_locator")) {
        container_.add(std::make_shared<UserLocator>(camera, faces));
      }
    }
  }
}

service::MakeComposer composer(std::chrono::milliseconds camera_max_age) {
  return [camera_max_age](service::ServiceContainer& container) -> std::unique_ptr<service::Composer> {
    return std::make_unique<CompositeFactory>(container, camera_max_age);
  };
}

}  // namespace icars::home
