// The service container and the listener lists services are built on: discovery by type and
// attributes, change notifications, and callbacks that never run after their removal returned.
#include <gtest/gtest.h>

#include <atomic>
#include <future>
#include <thread>

#include "icars/service/service_container.h"

namespace icars::service {
namespace {

class TestService final : public Service {
 public:
  TestService(std::string id, std::string type, ServiceAttributes a)
      : Service(std::move(id), std::move(type), std::move(a)) {}
  using Service::set_available;
};

std::shared_ptr<TestService> make(std::string id, std::string type, std::string room,
                                  std::string carrier = {}) {
  return std::make_shared<TestService>(std::move(id), std::move(type),
                                       ServiceAttributes{"dev", "cap", std::move(room), std::move(carrier)});
}

TEST(ServiceContainer, FindsByTypeAndAttributesAndReportsChanges) {
  ServiceContainer c;
  std::vector<std::pair<std::string, ServiceChange>> changes;
  c.watch([&](const std::shared_ptr<Service>& s, const ServiceChange& change) {
    changes.emplace_back(s->id(), change);
  });
  auto bedroom_light = make("bedroom_light.light", "LightControl", "bedroom");
  auto living_light = make("living_light.light", "LightControl", "living_room");
  auto mic = make("mic.sound", "SoundSensor", "", "robot1");
  c.add(bedroom_light);
  c.add(living_light);
  c.add(mic);
  EXPECT_THROW(c.add(make("mic.sound", "SoundSensor", "")), std::invalid_argument);

  EXPECT_EQ(c.find(ServiceQuery::of_type("LightControl")).size(), 2u);
  EXPECT_EQ(c.find(ServiceQuery::of_type("LightControl").in_room("bedroom")).front(), bedroom_light);
  EXPECT_EQ(c.find(ServiceQuery().carried_by("robot1")).front(), mic);
  EXPECT_TRUE(c.find(ServiceQuery::of_type("LightControl").available()).empty());
  living_light->set_available(true);
  EXPECT_EQ(c.find(ServiceQuery::of_type("LightControl").available()).front(), living_light);
  EXPECT_EQ(c.find_first<TestService>(ServiceQuery::of_type("SoundSensor")), mic);
  EXPECT_EQ(c.find_first<TestService>(ServiceQuery::of_type("Nothing")), nullptr);

  EXPECT_TRUE(c.remove("mic.sound"));
  EXPECT_FALSE(c.remove("mic.sound"));
  mic->set_available(true);  // no longer in the container: no notification
  const std::vector<std::pair<std::string, ServiceChange>> expected = {
      {"bedroom_light.light", ServiceChange::added},
      {"living_light.light", ServiceChange::added},
      {"mic.sound", ServiceChange::added},
      {"living_light.light", ServiceChange::available},
      {"mic.sound", ServiceChange::removed},
  };
  EXPECT_EQ(changes, expected);
}

TEST(Listeners, RemoveWaitsForACallInProgressOnAnotherThread) {
  Listeners<int> listeners;
  std::promise<void> entered;
  std::promise<void> release;
  auto release_future = release.get_future().share();
  std::atomic<bool> finished{false};
  const auto id = listeners.add([&](const int&) {
    entered.set_value();
    release_future.wait();
    finished = true;
  });
  std::thread notifier([&] { listeners.notify(1); });
  entered.get_future().wait();
  auto removal = std::async(std::launch::async, [&] { return listeners.remove(id); });
  EXPECT_EQ(removal.wait_for(std::chrono::milliseconds(50)), std::future_status::timeout)
      << "remove() returned while the callback was still running";
  release.set_value();
  EXPECT_TRUE(removal.get());
  EXPECT_TRUE(finished.load());
  notifier.join();
  listeners.notify(2);  // removed: not called again (it would set the promise twice)
}

TEST(Listeners, ACallbackMayRemoveItself) {
  Listeners<int> listeners;
  int calls = 0;
  std::uint64_t id = 0;
  id = listeners.add([&](const int&) {
    ++calls;
    listeners.remove(id);
  });
  listeners.notify(1);
  listeners.notify(2);
  EXPECT_EQ(calls, 1);
  EXPECT_EQ(listeners.size(), 0u);
}

}  // namespace
}  // namespace icars::service
