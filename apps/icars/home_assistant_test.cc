// `icars run --publish-to-home-assistant` as Home Assistant sees it: a real mosquitto, the
// mediator as a child process, and a client subscribed to `homeassistant/#` like Home
// Assistant's MQTT integration. The configs follow the discovery schema, every topic they name
// exists, the buttons and the select drive the policy, and the entities leave with the mediator.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <chrono>
#include <condition_variable>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include "announcement.h"
#include "broker.h"
#include "child_process.h"
#include "icars/bridge/mqtt/client.h"
#include "program_run.h"

using nlohmann::json;
using namespace std::chrono_literals;
namespace bm = icars::bridge::mqtt;

namespace {

const std::string kIcars = ICARS_BINARY;
const std::string kSource = ICARS_SOURCE_DIR;

// What Home Assistant would have heard: every topic's last message, and each state topic's
// history.
class HomeAssistantListener {
 public:
  explicit HomeAssistantListener(int port) : client_(options(port)) {
    client_.on_message([this](const bm::Message& m) {
      std::lock_guard lock(mutex_);
      last_[m.topic] = m.payload;
      history_[m.topic].push_back(m.payload);
      changed_.notify_all();
    });
    client_.subscribe("homeassistant/#");
    client_.subscribe("icars/#");
    client_.start();
    if (!client_.wait_connected(20s)) throw std::runtime_error("the listener cannot reach the broker");
  }

  // Waits (up to 60 s) until `pred` holds for what was heard.
  bool wait(const std::function<bool(const std::map<std::string, std::string>&)>& pred) {
    std::unique_lock lock(mutex_);
    return changed_.wait_for(lock, 60s, [&] { return pred(last_); });
  }
  bool heard(const std::string& topic, const std::string& payload) {
    return wait([&](const auto&) {
      const auto it = history_.find(topic);
      return it != history_.end() && std::find(it->second.begin(), it->second.end(), payload) != it->second.end();
    });
  }
  std::map<std::string, std::string> last() {
    std::lock_guard lock(mutex_);
    return last_;
  }
  void press(const std::string& topic, const std::string& payload) { client_.publish(topic, payload); }

 private:
  static bm::ClientOptions options(int port) {
    bm::ClientOptions o;
    o.port = port;
    o.client_id = "home-assistant-test";
    return o;
  }
  bm::Client client_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::map<std::string, std::string> last_;
  std::map<std::string, std::vector<std::string>> history_;
};

std::map<std::string, json> configs(const std::map<std::string, std::string>& last) {
  std::map<std::string, json> out;
  for (const auto& [topic, payload] : last) {
    if (topic.starts_with("homeassistant/") && topic.ends_with("/config") && !payload.empty()) {
      out[topic] = json::parse(payload, nullptr, false);
    }
  }
  return out;
}

}  // namespace

TEST(HomeAssistant, TheMediatorIsPublishedDrivenFromHomeAssistantAndRemovedWhenItStops) {
  bridge_test::Broker broker;
  HomeAssistantListener ha(broker.port());
  // A repository with the paper policy and a broken one, to choose from Home Assistant.
  const auto dir = icars_test::temp_path("home_assistant", "policies");
  std::filesystem::create_directories(dir);
  std::filesystem::copy_file(kSource + "/examples/smart_home/paper_home.xml", dir + "/paper_home.xml",
                             std::filesystem::copy_options::overwrite_existing);
  std::filesystem::copy_file(kSource + "/src/control/testdata/unknown_behavior.xml", dir + "/broken.xml",
                             std::filesystem::copy_options::overwrite_existing);

  planet_test::ChildProcess mediator({kIcars, "run", "paper_home", "--policies", dir, "--world",
                                      kSource + "/houses/paper_house.xml", "--speed", "5", "--until", "20:00",
                                      "--quiet", "--mqtt", "mqtt://127.0.0.1:" + std::to_string(broker.port()),
                                      "--publish-to-home-assistant"});
  const std::string base = "icars/icars_paper_house/";
  const std::string prefix = "homeassistant/";
  ASSERT_TRUE(ha.wait([&](const auto& last) {
    const auto c = configs(last);
    return c.contains(prefix + "select/icars_paper_house/policy/config") &&
           c.contains(prefix + "button/icars_paper_house/event_TimeToSleep/config") &&
           last.contains(base + "policy/state") && last.at(base + "policy/state") == "Observation";
  })) << "the mediator's entities did not appear";

  // --- The discovery schema: what Home Assistant needs of each component. -----------------------
  // Every entity is published before the states, so wait for the states every config names.
  std::set<std::string> state_topics;
  for (const auto& [topic, config] : configs(ha.last())) {
    SCOPED_TRACE(topic);
    ASSERT_TRUE(config.is_object());
    const auto component = topic.substr(prefix.size(), topic.find('/', prefix.size()) - prefix.size());
    for (const auto* key : {"unique_id", "name", "availability_topic", "device"}) {
      EXPECT_TRUE(config.contains(key)) << key;
    }
    EXPECT_EQ(config.value("availability_topic", ""), base + "availability");
    EXPECT_TRUE(config["device"]["identifiers"].is_array());
    if (component == "sensor" || component == "select") {
      ASSERT_TRUE(config.contains("state_topic"));
      state_topics.insert(config["state_topic"].get<std::string>());
    }
    if (component == "select") {
      EXPECT_TRUE(config.contains("command_topic"));
      ASSERT_TRUE(config["options"].is_array());
      EXPECT_FALSE(config["options"].empty());
    }
    if (component == "button") {
      EXPECT_TRUE(config.contains("command_topic"));
    }
    EXPECT_TRUE(component == "sensor" || component == "select" || component == "button") << component;
  }
  ASSERT_TRUE(ha.wait([&](const auto& last) {
    for (const auto& t : state_topics) {
      if (!last.contains(t)) return false;
    }
    return last.contains(base + "availability") && last.at(base + "availability") == "online";
  })) << "a config names a state topic that nothing publishes";
  std::set<std::string> unique_ids;
  for (const auto& [topic, config] : configs(ha.last())) {
    EXPECT_TRUE(unique_ids.insert(config.value("unique_id", "")).second) << "unique_id twice: " << topic;
  }
  const auto all = configs(ha.last());
  const auto select = all.at(prefix + "select/icars_paper_house/policy/config");
  EXPECT_EQ(select["options"], json::array({"broken", "paper_home"}));
  // One button per event the policy's transitions wait for, and the robot and devices.
  for (const auto* button : {"event_TimeToRest", "event_TimeToSleep", "event_UserLeft"}) {
    EXPECT_TRUE(all.contains(prefix + "button/icars_paper_house/" + button + "/config")) << button;
  }
  EXPECT_EQ(all.at(prefix + "button/icars_paper_house/event_TimeToSleep/config").value("name", ""), "Time to sleep");
  EXPECT_TRUE(all.contains(prefix + "sensor/icars_paper_house/robot1_room/config"));
  EXPECT_TRUE(all.contains(prefix + "sensor/icars_paper_house/device_tv/config"));
  const auto robot = json::parse(ha.last().at(base + "robot/robot1"));
  EXPECT_EQ(robot.value("room", ""), "living_room") << robot.dump();

  // --- Pressing a button raises its event in the policy. ----------------------------------------
  ha.press(base + "event/TimeToSleep", "PRESS");
  EXPECT_TRUE(ha.heard(base + "policy/state", "SleepMode")) << "the button did not move the policy";

  // --- The select: a broken policy is refused at its line, the running one keeps running. ------
  ha.press(base + "policy/set", "broken");
  ASSERT_TRUE(ha.wait([&](const auto& last) {
    return last.contains(base + "policy/error") && last.at(base + "policy/error") != "none";
  }));
  const auto error = ha.last().at(base + "policy/error");
  EXPECT_NE(error.find("broken.xml:4: error: unknown behavior type 'Wiat'"), std::string::npos) << error;
  EXPECT_NE(error.find("paper_home keeps running"), std::string::npos) << error;
  EXPECT_EQ(ha.last().at(base + "policy/name"), "paper_home");
  // ... and a good one runs from its start.
  ha.press(base + "policy/set", "paper_home");
  EXPECT_TRUE(ha.heard(base + "policy/error", "none"));
  EXPECT_TRUE(ha.wait([&](const auto& last) { return last.at(base + "policy/state") == "Observation"; }));
  // An event no transition waits for changes nothing and is reported.
  ha.press(base + "event/Nonsense", "PRESS");

  // --- The mediator stops: Home Assistant forgets its entities. ---------------------------------
  mediator.signal(SIGTERM);
  const auto status = mediator.wait_for(60s);
  ASSERT_TRUE(status.has_value()) << "the mediator did not stop";
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 0) << *status;
  EXPECT_TRUE(ha.wait([&](const auto& last) { return configs(last).empty(); }))
      << configs(ha.last()).size() << " configs left behind";
  EXPECT_EQ(ha.last().at(base + "availability"), "offline");
  std::filesystem::remove_all(dir);
}

TEST(HomeAssistant, WithoutABrokerTheOptionIsRefused) {
  const auto r = icars_test::run_program(kIcars, "run " + kSource + "/examples/smart_home/paper_home.xml --world " +
                                                     kSource + "/houses/paper_house.xml --publish-to-home-assistant");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("--publish-to-home-assistant needs --mqtt"), std::string::npos) << r.output;
}
