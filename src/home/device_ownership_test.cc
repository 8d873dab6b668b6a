// Devices belong to the principal that registered them, and their state survives outages: over
// real PLANET connections on loopback, an authenticated intruder with its own valid token cannot
// take over, unregister or speak for another principal's device, cannot flood the registry, and
// what a vanished manager registered is forgotten; a device that comes back with another state
// than the last acknowledged one is told to behaviors (DeviceRestored) and re-applied, and a
// sensor that changed while away is re-read.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <asio/steady_timer.hpp>
#include <asio/this_coro.hpp>
#include <asio/use_awaitable.hpp>
#include <atomic>
#include <functional>
#include <mutex>

#include "child_process.h"
#include "scoped_subscription.h"
#include "icars/device/device_manager.h"
#include "icars/home/adaptors.h"
#include "icars/home/services.h"
#include "icars/planet/publisher.h"
#include "icars/service/device_registry.h"
#include "icars/service/service_framework.h"

namespace icars::home {
namespace {

using namespace icars::service;
using namespace std::chrono_literals;
namespace p = icars::planet;

class FakeTV final : public home::TVControlServant {
 public:
  void set_power(bool on, const p::Current&) override { with([&] { state_.on = on; }); }
  void set_channel(std::int32_t channel, const p::Current&) override { with([&] { state_.channel = channel; }); }
  void set_volume(std::int32_t volume, const p::Current&) override { with([&] { state_.volume = volume; }); }
  home::TVState state(const p::Current&) override { return now(); }
  home::TVState now() const {
    std::lock_guard lock(mutex_);
    return state_;
  }

 private:
  void with(const std::function<void()>& change) {
    std::lock_guard lock(mutex_);
    change();
  }
  mutable std::mutex mutex_;
  home::TVState state_;
};

class FakeSofa final : public home::OccupancySensorServant {
 public:
  // `hold_readings`: occupied() takes its reading, then answers only after release_reading()
  // (asynchronously: a servant never blocks its communicator's io thread, which also sends the
  // sensor's events).
  FakeSofa(bool occupied, bool hold_readings) : occupied_(occupied), holding_(hold_readings) {
    if (!hold_readings) return;
    implement(home::OccupancySensor::occupied, [this]() -> asio::awaitable<bool> {
      const bool reading = occupied_;
      reading_taken_ = true;
      asio::steady_timer poll(co_await asio::this_coro::executor);
      while (holding_) {
        poll.expires_after(2ms);
        co_await poll.async_wait(asio::use_awaitable);
      }
      co_return reading;
    });
  }
  bool occupied(const p::Current&) override { return occupied_; }
  bool reading_taken() const { return reading_taken_; }
  void release_reading() { holding_ = false; }
  std::string furniture(const p::Current&) override { return "sofa"; }
  void subscribe(home::OccupancyListenerPrx l, const p::Current&) override { events_.subscribe(l); }
  void unsubscribe(home::OccupancyListenerPrx l, const p::Current&) override { events_.unsubscribe(l); }
  void sit(bool occupied) {
    occupied_ = occupied;
    events_.publish(home::OccupancyEvent{"sofa_sensor", "sofa", occupied, 1000});
  }
  std::size_t subscribers() const { return events_.size(); }

 private:
  std::atomic<bool> occupied_;
  std::atomic<bool> holding_;
  std::atomic<bool> reading_taken_{false};
  p::Publisher<home::OccupancyEvent> events_{home::OccupancyListener::on_occupancy};
};

// A device manager process's side: its own communicator, token and devices.
struct Manager {
  p::Communicator communicator;
  device::DeviceManager manager{communicator};
  std::shared_ptr<FakeTV> tv = std::make_shared<FakeTV>();
  std::shared_ptr<FakeSofa> sofa;

  Manager(std::uint16_t port, const std::string& token, bool sofa_occupied = false,
          bool hold_sofa_readings = false)
      : communicator(options(token)), sofa(std::make_shared<FakeSofa>(sofa_occupied, hold_sofa_readings)) {
    auto tv_device = std::make_shared<device::Device>("tv", "TV", "living_room");
    tv_device->add("tv_control", tv);
    auto sofa_device = std::make_shared<device::Device>("sofa_sensor", "OccupancySensor", "living_room");
    sofa_device->add("occupancy", sofa);
    manager.add(tv_device);
    manager.add(sofa_device);
    manager.connect("127.0.0.1", port);
  }
  ~Manager() { sofa->release_reading(); }  // never leaves a reading waiting
  Manager(const Manager&) = delete;
  Manager& operator=(const Manager&) = delete;
  static p::CommunicatorOptions options(const std::string& token) {
    p::CommunicatorOptions o;
    o.token = token;
    return o;
  }
};

// A client with a valid token of its own: it speaks PLANET directly to the registry.
struct Client {
  p::Communicator communicator;
  std::shared_ptr<p::Peer> peer;
  df::DeviceRegistryPrx registry;

  Client(std::uint16_t port, const std::string& token)
      : communicator(Manager::options(token)), peer(communicator.connect("127.0.0.1", port)) {
    EXPECT_TRUE(peer->wait_connected(20s)) << peer->last_error();
    registry = df::DeviceRegistryPrx(communicator, peer, std::string(device::kRegistryPath));
  }
  static df::DeviceInfo device(const std::string& id, const std::string& path = "/devices/x/tv_control") {
    return df::DeviceInfo{id, "TV", "living_room", "", {df::CapabilityInfo{"tv_control", "icars::home::TVControl", path}}};
  }
};

std::shared_ptr<const p::AccessPolicy> home_access() {
  auto access = std::make_shared<p::AccessPolicy>();
  const std::vector<std::string> dm_paths{std::string(device::kRegistryPath), "/sf/listeners/*"};
  access->add({"living-room", p::sha256_hex("living-room-token"), "", dm_paths, {"tv", "sofa_*"}, 8});
  access->add({"intruder", p::sha256_hex("intruder-token"), "", dm_paths, {"*"}, 16});
  access->add({"guest", p::sha256_hex("guest-token"), "", dm_paths, {"guest_*"}, 4});
  return access;
}

p::CommunicatorOptions server_options(std::shared_ptr<const p::AccessPolicy> access) {
  p::CommunicatorOptions o;
  o.access = std::move(access);
  return o;
}

class Ownership : public ::testing::Test {
 protected:
  // Devices gone for `forget_after` are forgotten: soon, for the tests of forgetting.
  explicit Ownership(std::chrono::milliseconds forget_after = 500ms)
      : server_(server_options(home_access())), sf_(server_, adaptors(), registry_options(forget_after), {composer()}) {
    port_ = server_.listen("127.0.0.1", 0);
    devices_ = sf_.container().watch_devices([this](const p::Event& e) {
      std::lock_guard lock(mutex_);
      events_.push_back(e);
    });
  }
  ~Ownership() override { sf_.container().remove_device_watcher(devices_); }
  static RegistryOptions registry_options(std::chrono::milliseconds forget_after) {
    RegistryOptions o;
    o.forget_after = forget_after;
    return o;
  }
  std::vector<p::Event> events(const std::string& type) {
    std::lock_guard lock(mutex_);
    std::vector<p::Event> out;
    for (const auto& e : events_) {
      if (e.type() == type) out.push_back(e);
    }
    return out;
  }
  std::shared_ptr<TVControlService> tv() {
    return sf_.container().find_first<TVControlService>(ServiceQuery::of_type("TVControl"));
  }

  p::Communicator server_;
  ServiceFramework sf_;
  std::uint16_t port_ = 0;
  std::uint64_t devices_ = 0;
  std::mutex mutex_;
  std::vector<p::Event> events_;
};

template <class F>
std::string refusal(F&& register_call) {
  try {
    register_call();
  } catch (const df::RegistrationRefused& e) {
    return e.reason();
  } catch (const p::Error& e) {
    return e.what();
  }
  return "(accepted)";
}

TEST_F(Ownership, AnotherPrincipalCannotTakeOverARegisteredDevice) {
  Manager living_room(port_, "living-room-token");
  ASSERT_TRUE(living_room.manager.wait_registered(1, 20s)) << living_room.manager.last_error();
  EXPECT_EQ(sf_.registry().holder("tv"), "living-room");

  Client intruder(port_, "intruder-token");
  const auto reason = refusal([&] { intruder.registry.register_device(Client::device("tv")); });
  EXPECT_EQ(reason, "device 'tv' is held by principal 'living-room'; principal 'intruder' may not take it over");
  // The TV service still reaches the living room's TV, not the intruder.
  auto service = tv();
  ASSERT_TRUE(service && service->available());
  service->proxy().set_power(true);
  EXPECT_TRUE(living_room.tv->now().on);

  // Whatever the id: every device the living room registered is its own.
  EXPECT_EQ(refusal([&] { intruder.registry.register_device(Client::device("sofa_sensor")); }),
            "device 'sofa_sensor' is held by principal 'living-room'; principal 'intruder' may not take it over");
}

TEST_F(Ownership, ADeviceOutsideThePrincipalsAccessEntryIsRefused) {
  Client guest(port_, "guest-token");
  EXPECT_EQ(refusal([&] { guest.registry.register_device(Client::device("tv")); }),
            "principal 'guest' may not register device 'tv': its access entry's \"devices\" do not list it");
  EXPECT_EQ(refusal([&] { guest.registry.register_device(Client::device("simulation")); }),
            "principal 'guest' may not register device 'simulation': its access entry's \"devices\" do not list it");
  guest.registry.register_device(Client::device("guest_lamp"));
  EXPECT_EQ(sf_.registry().holder("guest_lamp"), "guest");
}

TEST_F(Ownership, OnlyTheHolderMayUnregister) {
  Manager living_room(port_, "living-room-token");
  ASSERT_TRUE(living_room.manager.wait_registered(1, 20s));
  Client intruder(port_, "intruder-token");
  try {
    intruder.registry.unregister_device("tv");
    FAIL() << "the intruder unregistered the TV";
  } catch (const p::Error& e) {
    EXPECT_EQ(e.kind(), p::ErrorKind::denied);
    EXPECT_NE(std::string(e.what()).find("principal 'intruder' may not unregister device 'tv': it is held by "
                                         "principal 'living-room'"),
              std::string::npos)
        << e.what();
  }
  EXPECT_TRUE(tv() && tv()->available());
}

TEST_F(Ownership, EventsAreAcceptedOnlyFromTheDevicesOwnLink) {
  Manager living_room(port_, "living-room-token");
  ASSERT_TRUE(living_room.manager.wait_registered(1, 20s));
  auto sofa = sf_.container().find_first<OccupancyService>(ServiceQuery::of_type("OccupancySensor"));
  ASSERT_TRUE(sofa);
  std::atomic<int> occupied{0}, left{0};
  const auto subscription = planet_test::subscribe_scoped(*sofa, [&](const home::OccupancyEvent& e) { ++(e.occupied ? occupied : left); });
  ASSERT_TRUE(planet_test::wait_until([&] { return living_room.sofa->subscribers() == 1; }));

  // The intruder forges "the user left the sofa", then asks the registry something: requests
  // over one link are handled in order, so the forgery was handled when the answer comes.
  Client intruder(port_, "intruder-token");
  home::OccupancyListenerPrx listener(intruder.communicator, intruder.peer, "/sf/listeners/sofa_sensor.occupancy");
  for (int i = 0; i < 20; ++i) listener.on_occupancy(home::OccupancyEvent{"sofa_sensor", "sofa", false, 5000});
  EXPECT_FALSE(intruder.registry.devices().empty());
  EXPECT_EQ(left.load(), 0) << "a forged event reached the service's listeners";
  EXPECT_EQ(sofa->events_received(), 0u);

  living_room.sofa->sit(true);  // the real sensor still gets through
  EXPECT_TRUE(planet_test::wait_until([&] { return occupied.load() == 1; }));
}

TEST_F(Ownership, APrincipalHoldsAtMostItsMaxDevices) {
  Client intruder(port_, "intruder-token");
  int accepted = 0;
  std::string last;
  for (int i = 0; i < 100; ++i) {
    last = refusal([&] { intruder.registry.register_device(Client::device(fmt::format("fake_{}", i))); });
    if (last == "(accepted)") ++accepted;
  }
  EXPECT_EQ(accepted, 16);
  EXPECT_EQ(last, "principal 'intruder' holds 16 devices, its limit (max_devices in its access entry)");
  EXPECT_EQ(sf_.registry().registered_devices(), 16u);
}

TEST_F(Ownership, WhatAVanishedPrincipalRegisteredIsForgotten) {
  {
    Client intruder(port_, "intruder-token");
    for (int i = 0; i < 10; ++i) intruder.registry.register_device(Client::device(fmt::format("fake_{}", i)));
    EXPECT_EQ(sf_.container().all().size(), 10u);
  }  // its link closes
  // The registry drops its records, removes the services, then tells its watchers: once they
  // have heard, all three are done.
  ASSERT_TRUE(planet_test::wait_until([&] { return events("DeviceForgotten").size() >= 10; }, 20s));
  EXPECT_EQ(sf_.registry().registered_devices(), 0u);
  EXPECT_TRUE(sf_.container().all().empty());
  EXPECT_EQ(events("DeviceLost").size(), 10u);
  EXPECT_EQ(events("DeviceForgotten").size(), 10u);
  // Forgotten ids are free again, for a principal whose entry lists them.
  Client guest(port_, "guest-token");
  EXPECT_EQ(refusal([&] { guest.registry.register_device(Client::device("guest_fake_0")); }), "(accepted)");
}

TEST_F(Ownership, ARemovedPrincipalsDevicesCanBeForgottenAtOnce) {
  Manager living_room(port_, "living-room-token");
  ASSERT_TRUE(living_room.manager.wait_registered(1, 20s));
  EXPECT_EQ(sf_.registry().forget_holder("living-room"), 2u);
  EXPECT_FALSE(sf_.registry().holder("tv"));
  EXPECT_EQ(events("DeviceForgotten").size(), 2u);
}

TEST_F(Ownership, AForgottenSensorRegistersAgainWhileItsOldServiceIsStillHeld) {
  auto living_room = std::make_unique<Manager>(port_, "living-room-token");
  ASSERT_TRUE(living_room->manager.wait_registered(1, 20s));
  // A behavior still holds the sofa's service when its manager vanishes for good.
  const auto held = sf_.container().find_first<OccupancyService>(ServiceQuery::of_type("OccupancySensor"));
  ASSERT_TRUE(planet_test::wait_until([&] { return living_room->sofa->subscribers() == 1; }));
  living_room.reset();
  ASSERT_TRUE(planet_test::wait_until([&] { return events("DeviceForgotten").size() == 2; }, 20s));

  living_room = std::make_unique<Manager>(port_, "living-room-token");
  ASSERT_TRUE(living_room->manager.wait_registered(1, 20s));
  EXPECT_EQ(living_room->manager.last_error(), "");
  const auto sofa = sf_.container().find_first<OccupancyService>(ServiceQuery::of_type("OccupancySensor"));
  ASSERT_NE(sofa, nullptr);
  EXPECT_NE(sofa, held);
  std::atomic<int> heard{0};
  const auto subscription = planet_test::subscribe_scoped(*sofa, [&](const home::OccupancyEvent&) { ++heard; });
  ASSERT_TRUE(planet_test::wait_until([&] { return living_room->sofa->subscribers() == 1; }));
  living_room->sofa->sit(true);
  ASSERT_TRUE(planet_test::wait_until([&] { return heard == 1; }));
  EXPECT_EQ(held->events_received(), 0u);
}

TEST(AnonymousRegistry, IsBoundedWithoutAnAccessPolicy) {
  p::Communicator server;
  RegistryOptions options;
  options.max_anonymous_devices = 5;
  ServiceFramework sf(server, adaptors(), options, {composer()});
  Client client(server.listen("127.0.0.1", 0), "");
  for (int i = 0; i < 5; ++i) client.registry.register_device(Client::device(fmt::format("d{}", i)));
  EXPECT_EQ(refusal([&] { client.registry.register_device(Client::device("d5")); }),
            "an unauthenticated client holds 5 devices, its limit (max_anonymous_devices)");
}

// --- State across outages ------------------------------------------------------------------------

// Devices away for a moment, never long enough to be forgotten however slow the machine.
class Restore : public Ownership {
 protected:
  Restore() : Ownership(std::chrono::minutes(10)) {}
};

TEST_F(Restore, ADeviceThatLostItsStateIsToldAndReapplied) {
  auto living_room = std::make_unique<Manager>(port_, "living-room-token");
  ASSERT_TRUE(living_room->manager.wait_registered(1, 20s));
  auto service = tv();
  service->proxy().set_power(true);
  service->proxy().set_channel(5);
  service->proxy().set_volume(25);
  ASSERT_TRUE(planet_test::wait_until([&] {
    const auto s = service->acknowledged_state();
    return s.has("volume") && s.get<std::int32_t>("volume") == 25;
  }));

  living_room.reset();  // killed: its TV comes back off, channel 0, volume 0
  ASSERT_TRUE(planet_test::wait_until([&] { return !service->available(); }));
  living_room = std::make_unique<Manager>(port_, "living-room-token");
  ASSERT_TRUE(living_room->manager.wait_registered(1, 20s));

  ASSERT_TRUE(planet_test::wait_until([&] { return events("DeviceRestored").size() == 1; }, 20s));
  const auto restored = events("DeviceRestored").front();
  EXPECT_EQ(restored.get<std::string>("device"), "tv");
  EXPECT_EQ(restored.get<std::string>("differences"), "on true -> false, channel 5 -> 0, volume 25 -> 0");
  EXPECT_TRUE(restored.get<bool>("reapplied"));
  EXPECT_EQ(restored.get<std::int32_t>("channel"), 5);
  EXPECT_EQ(restored.get<std::int32_t>("found_channel"), 0);
  EXPECT_EQ(restored.get<std::string>("error"), "");
  EXPECT_EQ(events("DeviceBack").size(), 2u);  // the TV and the sofa
  const auto now = living_room->tv->now();
  EXPECT_TRUE(now.on);
  EXPECT_EQ(now.channel, 5);
  EXPECT_EQ(now.volume, 25);
}

TEST_F(Restore, ADeviceThatKeptItsStateRaisesNothing) {
  auto living_room = std::make_unique<Manager>(port_, "living-room-token");
  ASSERT_TRUE(living_room->manager.wait_registered(1, 20s));
  auto service = tv();
  service->proxy().set_channel(3);
  ASSERT_TRUE(planet_test::wait_until([&] { return service->acknowledged_state().has("channel"); }));
  // The link drops and comes back (the same manager, its TV untouched).
  for (const auto& c : server_.connections().connections()) c->close("test: link cut");
  ASSERT_TRUE(living_room->manager.wait_registered(2, 20s));
  ASSERT_TRUE(planet_test::wait_until([&] { return events("DeviceBack").size() == 2; }, 20s));
  // A restore that found no difference emits nothing; a round trip after it proves it ran.
  EXPECT_EQ(service->proxy().state().channel, 3);
  EXPECT_TRUE(events("DeviceRestored").empty());
}

TEST_F(Restore, AManagerRestartedBeforeItsOldLinkClosedIsCheckedToo) {
  // A manager killed and started again faster than the heartbeat timeout registers its devices
  // over a new link while the old one still looks open: its TV lost its state all the same.
  auto old_manager = std::make_unique<Manager>(port_, "living-room-token");
  ASSERT_TRUE(old_manager->manager.wait_registered(1, 20s));
  auto service = tv();
  service->proxy().set_channel(7);
  ASSERT_TRUE(planet_test::wait_until([&] { return service->acknowledged_state().has("channel"); }));
  auto new_manager = std::make_unique<Manager>(port_, "living-room-token");  // the old link still open
  ASSERT_TRUE(new_manager->manager.wait_registered(1, 20s));
  ASSERT_TRUE(planet_test::wait_until([&] { return events("DeviceRestored").size() == 1; }, 20s));
  EXPECT_EQ(events("DeviceRestored").front().get<std::string>("differences"), "channel 7 -> 0");
  ASSERT_TRUE(planet_test::wait_until([&] { return new_manager->tv->now().channel == 7; }, 20s));
  EXPECT_EQ(old_manager->tv->now().channel, 7);
  // The old link closing now loses nothing: the devices live on the new one.
  old_manager.reset();
  EXPECT_EQ(service->proxy().state().channel, 7);
  EXPECT_TRUE(service->available());
  EXPECT_TRUE(events("DeviceLost").empty());
}

TEST(RestoreReportOnly, TellsWithoutReapplying) {
  p::Communicator server;
  RegistryOptions options;
  options.reapply_state = false;
  ServiceFramework sf(server, adaptors(), options, {composer()});
  const auto port = server.listen("127.0.0.1", 0);
  std::mutex mutex;
  std::vector<p::Event> restored;
  const auto watch = planet_test::watch_devices_scoped(sf.container(), [&](const p::Event& e) {
    std::lock_guard lock(mutex);
    if (e.type() == "DeviceRestored") restored.push_back(e);
  });
  auto manager = std::make_unique<Manager>(port, "");
  ASSERT_TRUE(manager->manager.wait_registered(1, 20s));
  auto service = sf.container().find_first<TVControlService>(ServiceQuery::of_type("TVControl"));
  service->proxy().set_power(true);
  ASSERT_TRUE(planet_test::wait_until([&] { return service->acknowledged_state().has("on"); }));
  manager.reset();
  ASSERT_TRUE(planet_test::wait_until([&] { return !service->available(); }));
  manager = std::make_unique<Manager>(port, "");
  ASSERT_TRUE(manager->manager.wait_registered(1, 20s));
  ASSERT_TRUE(planet_test::wait_until([&] {
    std::lock_guard lock(mutex);
    return restored.size() == 1;
  }, 20s));
  std::lock_guard lock(mutex);
  EXPECT_FALSE(restored.front().get<bool>("reapplied"));
  EXPECT_EQ(restored.front().get<std::string>("differences"), "on true -> false");
  EXPECT_FALSE(manager->tv->now().on);
}

TEST_F(Restore, ASensorThatChangedWhileAwayIsReread) {
  auto living_room = std::make_unique<Manager>(port_, "living-room-token");
  ASSERT_TRUE(living_room->manager.wait_registered(1, 20s));
  auto sofa = sf_.container().find_first<OccupancyService>(ServiceQuery::of_type("OccupancySensor"));
  std::mutex mutex;
  std::vector<bool> seen;
  const auto subscription = planet_test::subscribe_scoped(*sofa, [&](const home::OccupancyEvent& e) {
    std::lock_guard lock(mutex);
    seen.push_back(e.occupied);
  });
  ASSERT_TRUE(planet_test::wait_until([&] { return living_room->sofa->subscribers() == 1; }));
  living_room->sofa->sit(true);
  ASSERT_TRUE(planet_test::wait_until([&] { return sofa->events_received() == 1; }));

  living_room.reset();  // the user gets up while the sensor's manager is down
  ASSERT_TRUE(planet_test::wait_until([&] { return !sofa->available(); }));
  living_room = std::make_unique<Manager>(port_, "living-room-token", /*sofa_occupied=*/false);
  ASSERT_TRUE(planet_test::wait_until([&] {
    std::lock_guard lock(mutex);
    return seen.size() == 2;
  }, 20s));
  std::lock_guard lock(mutex);
  EXPECT_EQ(seen, (std::vector<bool>{true, false}));
}

// The server asks a sensor for its reading when it binds it; an event published after the reading
// was taken may reach the server before the reading's reply. The older reading must not undo it.
TEST_F(Restore, AnEventThatOvertakesTheReadingIsNotUndone) {
  Manager living_room(port_, "living-room-token", false, /*hold_sofa_readings=*/true);
  ASSERT_TRUE(living_room.manager.wait_registered(1, 20s));
  const auto sofa = sf_.container().find_first<OccupancyService>(ServiceQuery::of_type("OccupancySensor"));
  ASSERT_NE(sofa, nullptr);
  std::mutex heard_mutex;
  std::vector<bool> heard;
  const auto subscription = planet_test::subscribe_scoped(*sofa, [&](const home::OccupancyEvent& e) {
    std::lock_guard lock(heard_mutex);
    heard.push_back(e.occupied);
  });
  const auto heard_now = [&] {
    std::lock_guard lock(heard_mutex);
    return heard;
  };
  ASSERT_TRUE(planet_test::wait_until([&] { return living_room.sofa->reading_taken(); }));
  living_room.sofa->sit(true);  // after the reading (unoccupied) was taken, before its reply
  ASSERT_TRUE(planet_test::wait_until([&] { return heard_now().size() == 1; }));
  living_room.sofa->release_reading();
  sofa->proxy().furniture();  // answered after the reading: the reading's reply is in
  living_room.sofa->sit(false);
  living_room.sofa->sit(true);
  ASSERT_TRUE(planet_test::wait_until([&] {
    const auto h = heard_now();
    return h.size() >= 3 && h.back();
  }));
  EXPECT_EQ(heard_now(), (std::vector<bool>{true, false, true}));
}

}  // namespace
}  // namespace icars::home
