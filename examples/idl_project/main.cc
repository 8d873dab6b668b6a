// A lamp and a microphone served over PLANET from their generated IDL, and a client that uses
// them through the generated stubs: a typed call, a typed exception, a listener passed by
// reference that the microphone calls back, and an audio stream pulled to its end.
#include <asio/use_future.hpp>
#include <atomic>
#include <cstdio>
#include <future>
#include <thread>

#include "home_devices.planet.h"
#include "icars/planet/communicator.h"
#include "icars/planet/publisher.h"
#include "icars/planet/stream.h"

namespace p = icars::planet;

class Lamp final : public home::LampServant {
 public:
  void set_intensity(std::int32_t percent, const p::Current&) override {
    if (percent < 0 || percent > 100) throw home::OutOfRange(percent, 100, "intensity is 0..100");
    intensity_ = percent;
  }
  std::int32_t intensity(const p::Current&) override { return intensity_; }

 private:
  std::atomic<std::int32_t> intensity_{0};
};

class Microphone final : public home::MicrophoneServant {
 public:
  explicit Microphone(p::Communicator& communicator) : communicator_(communicator) {}

  void subscribe(home::SoundListenerPrx listener, const p::Current&) override {
    sounds_.subscribe(listener);
  }
  p::StreamRef record(std::int32_t milliseconds, const p::Current&) override {
    auto out = p::OutputStream::create(communicator_);
    // 16 kHz, 16-bit mono: 32 bytes per millisecond, written by a recording thread.
    recorder_ = std::jthread([out, bytes = 32 * milliseconds] {
      std::vector<std::byte> block(3200);
      for (std::int32_t at = 0; at < bytes; at += 3200) {
        for (std::size_t i = 0; i < block.size(); ++i) block[i] = std::byte(i & 0xFF);
        out->write(std::span(block).first(static_cast<std::size_t>(std::min(3200, bytes - at))));
      }
      out->close();
    });
    return out->ref();
  }

  void hear(double direction, double level) {
    sounds_.publish(home::SoundEvent{direction, level, home::Room::living_room});
  }

 private:
  p::Communicator& communicator_;
  p::Publisher<home::SoundEvent> sounds_{home::SoundListener::on_sound};
  std::jthread recorder_;
};

class Listener final : public home::SoundListenerServant {
 public:
  void on_sound(const home::SoundEvent& sound, const p::Current&) override {
    std::printf("heard a sound from %.0f degrees at %.0f dB\n", sound.direction, sound.level);
    if (++heard_ == 3) all_heard_.set_value();
  }
  std::future<void> all_heard() { return all_heard_.get_future(); }

 private:
  int heard_ = 0;
  std::promise<void> all_heard_;
};

int main() {
  // The device side: a device manager hosting the two devices.
  p::Communicator devices;
  auto lamp = std::make_shared<Lamp>();
  auto mic = std::make_shared<Microphone>(devices);
  devices.adapter().add("/living/lamp", lamp);
  devices.adapter().add("/living/mic", mic);
  const auto port = devices.listen("127.0.0.1", 0);

  // The client side: stubs generated from the same IDL.
  p::Communicator client;
  auto peer = client.connect("127.0.0.1", port);
  if (!peer->wait_connected(std::chrono::seconds(10))) return 1;
  home::LampPrx lamp_prx(client, peer, "/living/lamp");
  home::MicrophonePrx mic_prx(client, peer, "/living/mic");

  lamp_prx.set_intensity(70);
  std::printf("lamp intensity %d\n", lamp_prx.intensity());
  try {
    lamp_prx.set_intensity(150);
  } catch (const home::OutOfRange& e) {
    std::printf("refused: %d is above %d\n", e.requested(), e.limit());
  }
  auto later = lamp_prx.intensity_async(asio::use_future);
  std::printf("lamp intensity (async) %d\n", later.get());

  auto listener = std::make_shared<Listener>();
  client.adapter().add("/me/listener", listener);
  auto heard = listener->all_heard();
  mic_prx.subscribe(client.reference<home::SoundListener>("/me/listener"));
  for (int i = 0; i < 3; ++i) mic->hear(30.0 * i, 60.0 + i);
  if (heard.wait_for(std::chrono::seconds(10)) != std::future_status::ready) return 1;

  auto audio = mic_prx.record(500);
  std::size_t bytes = 0;
  for (auto chunk = audio->read(); !chunk.empty(); chunk = audio->read()) bytes += chunk.size();
  std::printf("recorded %zu bytes of audio\n", bytes);
  if (bytes != 32 * 500) return 1;
  std::printf("example ok\n");
  return 0;
}
