// icars-device-manager --state, as a user meets it: the real program registers with a small
// PLANET server (this test, serving the device registry), the server turns the TV on, to
// channel 5, volume 25 and sends the robot somewhere; the manager is SIGKILLed and started
// again with the same --state and --epoch, and the TV and the robot, read back over PLANET, are
// as they were. A truncated state file gets a warning naming it and a fresh start (exit code 0
// at SIGTERM); a state file that cannot be written stops the manager at start with code 2.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>

#include "child_process.h"
#include "test_directory.h"
#include "device.planet.h"
#include "home.planet.h"
#include "icars/device/device_manager.h"
#include "icars/planet/communicator.h"

namespace {

namespace fs = std::filesystem;
namespace p = icars::planet;
namespace df = icars::df;
namespace home = icars::home;
using namespace std::chrono_literals;
using planet_test::wait_until;

const std::string kDeviceManager = ICARS_DEVICE_MANAGER_BINARY;
const std::string kHouse = std::string(ICARS_SOURCE_DIR) + "/houses/paper_house.xml";

std::string read(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

// The mediating server's device registry, as small as a test needs: remembers the connection
// each device was last registered over, so the test can call the device back through it.
class Registry final : public df::DeviceRegistryServant {
 public:
  void register_device(const df::DeviceInfo& device, const p::Current& current) override {
    std::lock_guard lock(mutex_);
    links_[device.id] = current.connection;
    ++registrations_[device.id];
  }
  void unregister_device(const std::string&, const p::Current&) override {}
  std::vector<std::string> devices(const p::Current&) override {
    std::lock_guard lock(mutex_);
    std::vector<std::string> ids;
    for (const auto& [id, link] : links_) ids.push_back(id);
    return ids;
  }
  int registrations(const std::string& device) const {
    std::lock_guard lock(mutex_);
    const auto it = registrations_.find(device);
    return it == registrations_.end() ? 0 : it->second;
  }
  std::shared_ptr<p::Connection> link(const std::string& device) const {
    std::lock_guard lock(mutex_);
    return links_.at(device);
  }

 private:
  mutable std::mutex mutex_;
  std::map<std::string, std::shared_ptr<p::Connection>> links_;
  std::map<std::string, int> registrations_;
};

class DeviceManagerState : public ::testing::Test {
 protected:
  void SetUp() override {
    state_ = dir_ / "devices.state.json";
    server_.adapter().add(std::string(icars::device::kRegistryPath), registry_);
    port_ = server_.listen("127.0.0.1", 0);
    epoch_ms_ = std::chrono::duration_cast<std::chrono::milliseconds>(
                    std::chrono::system_clock::now().time_since_epoch())
                    .count();
  }

  // The manager with its stderr in `log`; its stdout read by the test.
  std::unique_ptr<planet_test::ChildProcess> start_manager(const fs::path& state,
                                                           const fs::path& log) {
    return std::make_unique<planet_test::ChildProcess>(std::vector<std::string>{
        "/bin/sh", "-c", "log=$1; shift; exec \"$@\" 2>\"$log\"", "sh", log.string(),
        kDeviceManager, "--house", kHouse, "--server", "127.0.0.1:" + std::to_string(port_),
        "--speedup", "60", "--epoch", std::to_string(epoch_ms_), "--state", state.string()});
  }
  // Reads stdout until a line starts with `prefix`; returns it ("" on timeout or exit).
  static std::string line_starting(planet_test::ChildProcess& process, const std::string& prefix) {
    const auto deadline = std::chrono::steady_clock::now() + 60s;
    while (std::chrono::steady_clock::now() < deadline) {
      const auto line = process.read_line(1s);
      if (line && line->rfind(prefix, 0) == 0) return *line;
    }
    return "";
  }
  template <class Prx>
  Prx capability(const std::string& device, const std::string& name) {
    return Prx(server_, registry_->link(device), "/devices/" + device + "/" + name);
  }

  planet_test::TestDirectory dir_{"icars_dm_state"};
  fs::path state_;
  std::shared_ptr<Registry> registry_ = std::make_shared<Registry>();
  p::Communicator server_;
  std::uint16_t port_ = 0;
  std::int64_t epoch_ms_ = 0;
};

TEST_F(DeviceManagerState, TheTvAndTheRobotAreAsTheyWereAfterASigkillAndARestart) {
  home::Pose before;
  {
    auto manager = start_manager(state_, dir_ / "first.log");
    EXPECT_EQ(line_starting(*manager, "STATE "), "STATE new " + state_.string());
    ASSERT_NE(line_starting(*manager, "REGISTERED "), "") << read(dir_ / "first.log");
    ASSERT_GE(registry_->registrations("robot1_wheels"), 1);
    auto tv = capability<home::TVControlPrx>("tv", "tv_control");
    tv.set_power(true);
    tv.set_channel(5);
    tv.set_volume(25);
    auto wheels = capability<home::WheelsPrx>("robot1_wheels", "wheels");
    wheels.go_to(home::Pose{1.58, 3.78, 0});
    // Arrived: near the target and no longer moving (60x: 30 m per wall second).
    home::Pose last = wheels.position();
    ASSERT_TRUE(wait_until([&] {
      std::this_thread::sleep_for(50ms);
      const auto now = wheels.position();
      const bool still = now.x == last.x && now.y == last.y && now.theta == last.theta;
      last = now;
      return still && std::hypot(now.x - 1.58, now.y - 3.78) < 0.3;
    }));
    before = last;
    const auto tv_state = tv.state();
    ASSERT_TRUE(tv_state.on);
    manager->signal(SIGKILL);
    const int status = manager->wait();
    ASSERT_TRUE(WIFSIGNALED(status));
  }
  const int rounds = registry_->registrations("tv");
  auto manager = start_manager(state_, dir_ / "second.log");
  EXPECT_EQ(line_starting(*manager, "STATE "), "STATE restored " + state_.string())
      << read(dir_ / "second.log");
  ASSERT_NE(line_starting(*manager, "REGISTERED "), "") << read(dir_ / "second.log");
  ASSERT_TRUE(wait_until([&] { return registry_->registrations("robot1_wheels") > rounds; }));
  const auto tv = capability<home::TVControlPrx>("tv", "tv_control").state();
  EXPECT_TRUE(tv.on);
  EXPECT_EQ(tv.channel, 5);
  EXPECT_EQ(tv.volume, 25);
  const auto after = capability<home::WheelsPrx>("robot1_wheels", "wheels").position();
  EXPECT_EQ(after.x, before.x);
  EXPECT_EQ(after.y, before.y);
  EXPECT_EQ(after.theta, before.theta);
  EXPECT_EQ(capability<home::WheelsPrx>("robot1_wheels", "wheels").room(), "living_room");
  manager->signal(SIGTERM);
  const int status = manager->wait();
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << status;
}

TEST_F(DeviceManagerState, ATruncatedStateFileIsWarnedAboutAndTheHouseStartsFresh) {
  std::ofstream(state_) << "{\n  \"format\": \"icars-sim-state\",\n  \"version\": 1,\n  \"hou";
  auto manager = start_manager(state_, dir_ / "manager.log");
  EXPECT_EQ(line_starting(*manager, "STATE "), "STATE rejected " + state_.string());
  ASSERT_NE(line_starting(*manager, "REGISTERED "), "") << read(dir_ / "manager.log");
  const auto log = read(dir_ / "manager.log");
  EXPECT_NE(log.find("state file " + state_.string() + ": not valid JSON"), std::string::npos)
      << log;
  EXPECT_NE(log.find("kept as " + state_.string() + ".rejected"), std::string::npos) << log;
  const auto tv = capability<home::TVControlPrx>("tv", "tv_control").state();
  EXPECT_FALSE(tv.on);
  EXPECT_EQ(tv.channel, 1);
  EXPECT_EQ(tv.volume, 20);
  // A whole new file replaced it at start.
  EXPECT_TRUE(nlohmann::json::accept(read(state_)));
  manager->signal(SIGTERM);
  const int status = manager->wait();
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << status;
}

TEST_F(DeviceManagerState, AStateFileThatCannotBeWrittenStopsTheManagerAtStart) {
  const auto unwritable = dir_ / "no_such_directory" / "devices.state.json";
  auto manager = start_manager(unwritable, dir_ / "manager.log");
  const auto status = manager->wait_for(60s);
  ASSERT_TRUE(status.has_value());
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 2) << *status;
  const auto log = read(dir_ / "manager.log");
  EXPECT_NE(log.find(unwritable.string()), std::string::npos) << log;
}

}  // namespace
