// The MQTT client against a real Mosquitto broker started by the test: publish and subscribe,
// retained messages, a broker that comes later or restarts (reconnect, subscriptions made
// again), a wrong password refused with the broker's reason, and bad topics and oversized
// messages as clear errors.
#include "icars/bridge/mqtt/client.h"

#include <gtest/gtest.h>

#include <atomic>
#include <mutex>
#include <string>
#include <vector>

#include "broker.h"
#include "child_process.h"

namespace icars::bridge::mqtt {
namespace {

using namespace std::chrono_literals;

ClientOptions to(const bridge_test::Broker& broker, const std::string& id) {
  ClientOptions o;
  o.port = broker.port();
  o.client_id = id;
  return o;
}

// What a client received, safe to read from the test's thread.
struct Inbox {
  std::mutex mutex;
  std::vector<Message> messages;
  void add(const Message& m) {
    std::lock_guard lock(mutex);
    messages.push_back(m);
  }
  std::function<void(const Message&)> sink() {
    return [this](const Message& m) { add(m); };
  }
  bool has(const std::string& topic, const std::string& payload, bool retained) {
    std::lock_guard lock(mutex);
    for (const auto& m : messages) {
      if (m.topic == topic && m.payload == payload && m.retained == retained) return true;
    }
    return false;
  }
};

TEST(MqttClient, PublishesAndReceivesRetainedAndLiveMessages) {
  bridge_test::Broker broker;
  Inbox live;
  Client listener(to(broker, "listener"));
  listener.on_message(live.sink());
  listener.subscribe("home/#");
  listener.start();
  ASSERT_TRUE(listener.wait_connected(20s)) << listener.last_error();

  Client lamp(to(broker, "lamp"));
  lamp.start();
  ASSERT_TRUE(lamp.wait_connected(20s)) << lamp.last_error();
  lamp.publish("home/lamp/state", "ON", /*retain=*/true);
  // A subscription takes effect asynchronously: publish until the listener hears it.
  ASSERT_TRUE(planet_test::wait_until([&] {
    lamp.publish("home/lamp/brightness", "128");
    return live.has("home/lamp/brightness", "128", false);
  }));
  EXPECT_TRUE(planet_test::wait_until([&] { return live.has("home/lamp/state", "ON", false); }));

  // A client that subscribes later gets the retained state, marked retained.
  Inbox late;
  Client newcomer(to(broker, "newcomer"));
  newcomer.on_message(late.sink());
  newcomer.subscribe("home/+/state");
  newcomer.start();
  EXPECT_TRUE(planet_test::wait_until([&] { return late.has("home/lamp/state", "ON", true); }));
  EXPECT_EQ(listener.connections(), 1u);
}

TEST(MqttClient, ReconnectsAndSubscribesAgainWhenTheBrokerRestarts) {
  bridge_test::Broker broker;
  Inbox inbox;
  std::mutex reasons_mutex;
  std::vector<std::string> reasons;  // of every connection lost or not made
  Client listener(to(broker, "listener"));
  listener.on_message(inbox.sink());
  listener.on_connection([&](bool up, const std::string& why) {
    if (up) return;
    std::lock_guard lock(reasons_mutex);
    reasons.push_back(why);
  });
  listener.subscribe("sensors/#");
  listener.start();
  ASSERT_TRUE(listener.wait_connected(20s)) << listener.last_error();

  broker.kill();
  ASSERT_TRUE(planet_test::wait_until([&] { return !listener.connected(); }, 30s));
  // The loss is told once; a reason it cannot connect again, if any, once each.
  ASSERT_TRUE(planet_test::wait_until([&] {
    std::lock_guard lock(reasons_mutex);
    return !reasons.empty();
  }, 30s));
  {
    std::lock_guard lock(reasons_mutex);
    EXPECT_NE(reasons[0].find("lost the connection to the broker at 127.0.0.1:" + std::to_string(broker.port())),
              std::string::npos)
        << reasons[0];
    for (std::size_t i = 1; i < reasons.size(); ++i) {
      EXPECT_NE(reasons[i], reasons[i - 1]) << "told twice";
      EXPECT_NE(reasons[i].find("cannot connect to the broker"), std::string::npos) << reasons[i];
    }
  }
  broker.restart();
  ASSERT_TRUE(planet_test::wait_until([&] { return listener.connections() == 2; }, 60s)) << listener.last_error();

  Client sensor(to(broker, "sensor"));
  sensor.start();
  ASSERT_TRUE(sensor.wait_connected(20s)) << sensor.last_error();
  ASSERT_TRUE(planet_test::wait_until([&] {
    sensor.publish("sensors/motion", "1");
    return inbox.has("sensors/motion", "1", false);
  })) << "the subscription was not made again on the new connection";
}

TEST(MqttClient, ConnectsToABrokerThatStartsLater) {
  bridge_test::Broker broker;
  broker.kill();
  Client client(to(broker, "early"));
  client.start();
  EXPECT_FALSE(client.connected());
  EXPECT_THROW(client.publish("a/b", "x"), Error);
  broker.restart();
  EXPECT_TRUE(planet_test::wait_until([&] { return client.connected(); }, 60s)) << client.last_error();
}

TEST(MqttClient, AWrongPasswordIsRefusedWithTheBrokersReason) {
  bridge_test::Broker broker({.username = "icars", .password = "s3cret"});
  auto wrong = to(broker, "intruder");
  wrong.username = "icars";
  wrong.password = "guess";
  Client intruder(wrong);
  std::atomic<int> refusals{0};
  intruder.on_connection([&](bool up, const std::string&) { refusals += up ? 0 : 1; });
  intruder.start();
  EXPECT_FALSE(intruder.wait_connected(20s));
  const auto error = intruder.last_error();
  EXPECT_NE(error.find("the broker at 127.0.0.1:" + std::to_string(broker.port()) + " refused the connection"),
            std::string::npos)
      << error;
  EXPECT_NE(error.find("not authori"), std::string::npos) << error;
  intruder.stop();

  auto right = to(broker, "bridge");
  right.username = "icars";
  right.password = "s3cret";
  Client bridge(right);
  bridge.start();
  EXPECT_TRUE(bridge.wait_connected(20s)) << bridge.last_error();
}

TEST(MqttClient, BadTopicsAndOptionsAreClearErrors) {
  bridge_test::Broker broker;
  Client client(to(broker, "careful"));
  client.start();
  ASSERT_TRUE(client.wait_connected(20s));
  try {
    client.publish("home/+/set", "ON");
    ADD_FAILURE() << "published to a wildcard";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("cannot publish to 'home/+/set'"), std::string::npos) << e.what();
  }
  EXPECT_THROW(client.publish("", "x"), Error);
  try {
    client.subscribe("home/#/state");
    ADD_FAILURE() << "subscribed to a malformed filter";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("'home/#/state' is not a topic filter"), std::string::npos) << e.what();
  }
  EXPECT_THROW(client.publish("a/b", "x", false, 3), Error);

  ClientOptions bad;
  bad.port = 0;
  EXPECT_THROW(Client{bad}, std::invalid_argument);
  bad = ClientOptions{};
  bad.password = "p";
  EXPECT_THROW(Client{bad}, std::invalid_argument);
  bad = ClientOptions{};
  bad.ca_file = "/nonexistent/ca.pem";
  try {
    Client tls(bad);
    ADD_FAILURE() << "a missing CA file was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("cannot read the CA file /nonexistent/ca.pem"), std::string::npos) << e.what();
  }
}

TEST(MqttClient, AnOversizedMessageIsDroppedAndReportedAndTheNextOneArrives) {
  bridge_test::Broker broker;
  auto small = to(broker, "small");
  small.max_payload = 100;
  Inbox inbox;
  std::mutex problems_mutex;
  std::vector<std::string> problems;
  Client client(small);
  client.on_message(inbox.sink());
  client.on_problem([&](const std::string& p) {
    std::lock_guard lock(problems_mutex);
    problems.push_back(p);
  });
  client.subscribe("big/#");
  client.start();
  ASSERT_TRUE(client.wait_connected(20s));
  Client sender(to(broker, "sender"));
  sender.start();
  ASSERT_TRUE(sender.wait_connected(20s));
  ASSERT_TRUE(planet_test::wait_until([&] {
    sender.publish("big/ping", "x");
    return inbox.has("big/ping", "x", false);
  }));
  sender.publish("big/blob", std::string(1000, 'a'));
  sender.publish("big/after", "ok");
  ASSERT_TRUE(planet_test::wait_until([&] { return inbox.has("big/after", "ok", false); }));
  std::lock_guard lock(problems_mutex);
  ASSERT_EQ(problems.size(), 1u);
  EXPECT_EQ(problems[0], "big/blob: a message of 1000 bytes dropped (more than 100)");
}

// Everything published before drain() returned true is at the broker: a subscriber gets all of
// it even when the publisher stops at once.
TEST(MqttClient, DrainWaitsUntilTheBrokerHasEverythingPublished) {
  bridge_test::Broker broker;
  Inbox inbox;
  Client receiver(to(broker, "receiver"));
  receiver.on_message(inbox.sink());
  receiver.subscribe("drain/#");
  receiver.start();
  ASSERT_TRUE(receiver.wait_connected(20s));
  {
    Client sender(to(broker, "sender"));
    sender.start();
    ASSERT_TRUE(sender.wait_connected(20s));
    for (int i = 0; i < 200; ++i) sender.publish("drain/" + std::to_string(i), std::string(1000, 'x'), true);
    EXPECT_TRUE(sender.drain(20s));
    sender.stop();
  }
  ASSERT_TRUE(planet_test::wait_until([&] { return inbox.has("drain/199", std::string(1000, 'x'), false); }));
}

TEST(BrokerUri, ReadsHostPortAndTlsAndRefusesTheRest) {
  const auto plain = parse_broker_uri("mqtt://broker.lan");
  EXPECT_EQ(plain.host, "broker.lan");
  EXPECT_EQ(plain.port, 1883);
  EXPECT_FALSE(plain.tls);
  const auto tls = parse_broker_uri("mqtts://10.0.0.2:8884");
  EXPECT_EQ(tls.host, "10.0.0.2");
  EXPECT_EQ(tls.port, 8884);
  EXPECT_TRUE(tls.tls);
  EXPECT_EQ(parse_broker_uri("mqtts://h").port, 8883);
  for (const auto* bad : {"broker.lan:1883", "http://h", "mqtt://", "mqtt://h:0", "mqtt://h:99999", "mqtt://h:x",
                          "mqtt://h/path"}) {
    EXPECT_THROW(parse_broker_uri(bad), std::invalid_argument) << bad;
  }
}

}  // namespace
}  // namespace icars::bridge::mqtt
