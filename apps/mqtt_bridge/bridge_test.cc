// icars-mqtt-bridge as its users run it: a real Mosquitto broker, a zigbee2mqtt/Tasmota-like
// fleet, the program as a child process and a mediating server (PLANET + Service Framework) in
// this process. The placement file names and places the devices; a light obeys through the
// server; a broker restart mid-run is survived; a wrong password ends the bridge with the
// broker's reason; a broken placement file ends it with the file and line.
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "broker.h"
#include "tls_files.h"
#include "child_process.h"
#include "fleet.h"
#include "icars/home/adaptors.h"
#include "icars/home/services.h"
#include "icars/service/service_framework.h"

namespace {

using namespace icars::service;
using namespace std::chrono_literals;
namespace home = icars::home;
namespace p = icars::planet;
namespace fs = std::filesystem;

const std::string kBridge = ICARS_MQTT_BRIDGE_BINARY;

fs::path write_file(const std::string& name, const std::string& text) {
  const auto path = fs::temp_directory_path() / ("icars_mqtt_bridge_" + std::to_string(::getpid()) + "_" + name);
  std::ofstream(path) << text;
  return path;
}

// Reads the bridge's lines until one starts with `prefix` (and contains `part`); "" on EOF or
// after the timeout. Every line read is kept in `seen`.
std::string read_until(planet_test::ChildProcess& bridge, const std::string& prefix, std::vector<std::string>& seen,
                       const std::string& part = "", std::chrono::seconds timeout = 60s) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    const auto line = bridge.read_line(std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now()));
    if (!line) return "";
    seen.push_back(*line);
    if (line->starts_with(prefix) && line->find(part) != std::string::npos) return *line;
  }
  return "";
}

std::string joined(const std::vector<std::string>& lines) {
  std::string out;
  for (const auto& l : lines) out += l + "\n";
  return out;
}

class MqttBridge : public ::testing::Test {
 protected:
  void SetUp() override { server_port_ = server_.listen("127.0.0.1", 0); }
  void TearDown() override {
    for (const auto& f : files_) fs::remove(f);
  }

  // The bridge on `broker` (or on the broker URI `uri`) and this test's server.
  std::unique_ptr<planet_test::ChildProcess> launch(const bridge_test::Broker& broker, std::vector<std::string> extra,
                                                    std::string uri = "") {
    if (uri.empty()) uri = "mqtt://127.0.0.1:" + std::to_string(broker.port());
    std::vector<std::string> argv{kBridge, "--broker", uri, "--server", "127.0.0.1:" + std::to_string(server_port_)};
    argv.insert(argv.end(), extra.begin(), extra.end());
    return std::make_unique<planet_test::ChildProcess>(argv);
  }
  fs::path file(const std::string& name, const std::string& text) {
    files_.push_back(write_file(name, text));
    return files_.back();
  }

  p::Communicator server_;
  ServiceFramework sf_{server_, home::adaptors(), {}, {home::composer()}};
  std::uint16_t server_port_ = 0;
  std::vector<fs::path> files_;
};

TEST_F(MqttBridge, PlacedDevicesRegisterAndALightObeysThroughTheServerAcrossABrokerRestart) {
  bridge_test::Broker broker;
  mqtt_test::Fleet fleet(broker.port());
  fleet.start();
  const auto placements = file("placements.xml", "<placements>\n"
      "  <entity unique_id=\"" + mqtt_test::Fleet::unique_id("living_lamp") + "\" device=\"living_light\" room=\"living_room\"/>\n"
      "  <entity unique_id=\"" + mqtt_test::Fleet::unique_id("bed_sensor") + "\" device=\"bed_sensor\" room=\"bedroom\" furniture=\"bed\"/>\n"
      "</placements>\n");
  auto bridge = launch(broker, {"--placements", placements.string(), "--command-timeout", "5000"});
  std::vector<std::string> seen;
  const auto device = read_until(*bridge, "DEVICE living_light ", seen, " living_room online");
  ASSERT_NE(device, "") << joined(seen);

  auto& c = sf_.container();
  ASSERT_TRUE(planet_test::wait_until([&] {
    return c.find_first<home::LightService>(ServiceQuery::of_type("LightControl").on_device("living_light").available()) &&
           c.find_first<home::OccupancyService>(ServiceQuery::of_type("OccupancySensor").in_room("bedroom").available());
  }, 60s));
  auto light = c.find_first<home::LightService>(ServiceQuery::of_type("LightControl").on_device("living_light"));
  light->proxy().set_power(true);  // acknowledged once the lamp's state topic says ON
  EXPECT_EQ(fleet.on("living_lamp"), true);

  // The broker goes away and comes back: the bridge reconnects and the light obeys again.
  broker.kill();
  ASSERT_NE(read_until(*bridge, "BROKER DOWN", seen), "") << joined(seen);
  broker.restart();
  ASSERT_NE(read_until(*bridge, "BROKER CONNECTED", seen), "") << joined(seen);
  ASSERT_TRUE(planet_test::wait_until([&] {
    try {
      light->proxy().set_power(false);
      return true;
    } catch (const p::Error&) {
      return false;  // the fleet may not be back on the broker yet
    }
  }, 60s));
  EXPECT_EQ(fleet.on("living_lamp"), false);

  bridge->signal(SIGTERM);
  const auto status = bridge->wait_for(30s);
  ASSERT_TRUE(status) << "the bridge ignored SIGTERM";
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 0) << *status;
}

TEST_F(MqttBridge, AWrongPasswordEndsTheBridgeWithTheBrokersReason) {
  bridge_test::Broker broker({.username = "icars", .password = "right"});
  const auto password = file("password", "wrong\n");
  auto bridge = launch(broker, {"--username", "icars", "--password-file", password.string()});
  std::vector<std::string> seen;
  const auto refused = read_until(*bridge, "BROKER REFUSED", seen);
  ASSERT_NE(refused, "") << joined(seen);
  EXPECT_NE(refused.find("refused"), std::string::npos) << refused;
  const auto status = bridge->wait_for(30s);
  ASSERT_TRUE(status);
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 3) << *status;
}

// A broker as a home secures it: TLS with the home's own authority and a password. The bridge
// checks the broker's certificate: against another authority it does not connect and says why.
TEST_F(MqttBridge, ConnectsOverTlsWithAPasswordAndRefusesABrokerItCannotTrust) {
  const auto certs = fs::temp_directory_path() / ("icars-mqtt-tls-" + std::to_string(::getpid()));
  const auto other = certs / "other";
  planet_test::make_certificates(certs);
  planet_test::make_certificates(other);
  bridge_test::Broker broker({.username = "icars", .password = "secret", .tls_dir = certs.string()});
  const auto uri = "mqtts://127.0.0.1:" + std::to_string(broker.port());
  const auto password = file("password", "secret\n");
  std::vector<std::string> seen;
  {
    auto bridge = launch(broker, {"--username", "icars", "--password-file", password.string(), "--ca-file",
                                  (certs / "ca.pem").string()},
                         uri);
    EXPECT_NE(read_until(*bridge, "BROKER CONNECTED", seen), "") << joined(seen);
    bridge->signal(SIGTERM);
    EXPECT_TRUE(bridge->wait_for(30s));
  }
  {
    seen.clear();
    auto bridge = launch(broker, {"--username", "icars", "--password-file", password.string(), "--ca-file",
                                  (other / "ca.pem").string()},
                         uri);
    const auto down = read_until(*bridge, "BROKER DOWN", seen);
    EXPECT_NE(down.find("certificate verify failed"), std::string::npos) << joined(seen);
    EXPECT_EQ(std::count_if(seen.begin(), seen.end(), [](const std::string& l) { return l == "BROKER CONNECTED"; }), 0)
        << joined(seen);
    bridge->signal(SIGTERM);
    EXPECT_TRUE(bridge->wait_for(30s));
  }
  fs::remove_all(certs);
}

TEST_F(MqttBridge, ABrokenPlacementFileOrBrokerAddressStopsItBeforeItConnects) {
  bridge_test::Broker broker;
  const auto bad = file("bad.xml", "<placements>\n  <entity unique_id=\"x\" device=\"a b\"/>\n</placements>\n");
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"--placements", bad.string()}, ""},
      {{}, "http://127.0.0.1:1883"},
      {{}, "mqtts://127.0.0.1"},  // TLS without --ca-file
      {{}, "mqtt://127.0.0.1:99999"}};
  for (const auto& [args, uri] : cases) {
    auto bridge = launch(broker, args, uri);
    const auto status = bridge->wait_for(30s);
    ASSERT_TRUE(status) << uri;
    EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 2) << uri << ": " << *status;
  }
}

}  // namespace
