// An MQTT client for the bridges to real homes: a connection to a broker kept up
// in the background — reconnected with exponential backoff after a broker restart or a network
// cut, with every subscription made again on each connection — over libmosquitto (Debian's
// Eclipse Mosquitto client library; MQTT itself is not written here).
//
//   mqtt::ClientOptions o;
//   o.host = "127.0.0.1"; o.port = 1883; o.client_id = "icars-bridge";
//   mqtt::Client client(o);
//   client.on_message([](const mqtt::Message& m) { ... });   // on the client's network thread
//   client.subscribe("homeassistant/+/+/config");
//   client.start();
//   client.wait_connected(std::chrono::seconds(10));
//   client.publish("zigbee2mqtt/lamp/set", R"({"state":"ON"})");
//
// A broker that refuses the client (wrong password, unknown client) is not retried: the refusal
// is last_error() and the connection callback's reason.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>

struct mosquitto;
struct mosquitto_message;

namespace icars::bridge::mqtt {

// A publish, subscribe or connect that cannot be done now, with the reason.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct Will {
  std::string topic;
  std::string payload;
  bool retain = true;
};

struct ClientOptions {
  std::string host = "127.0.0.1";
  int port = 1883;
  std::string client_id;  // empty: the broker makes one (then a clean session)
  std::string username;   // empty: none
  std::string password;
  std::string ca_file;    // set: TLS, the broker's certificate checked against this CA
  std::chrono::seconds keepalive{30};
  std::chrono::seconds reconnect_min{1};   // first delay after a lost connection...
  std::chrono::seconds reconnect_max{30};  // ... doubling up to this
  std::optional<Will> will;                // published by the broker if this client dies
  std::size_t max_payload = 1 << 20;       // larger incoming messages are dropped (logged)

  void validate() const;  // throws std::invalid_argument naming the bad option
};

// A broker's address as users write it: "mqtt://HOST[:PORT]" (1883) or "mqtts://HOST[:PORT]"
// (8883, TLS).
struct BrokerUri {
  std::string host;
  int port = 1883;
  bool tls = false;
};
// Throws std::invalid_argument naming the URI and what is wrong with it.
BrokerUri parse_broker_uri(const std::string& uri);

struct Message {
  std::string topic;
  std::string payload;
  bool retained = false;
};

class Client {
 public:
  // Checks the options (std::invalid_argument) and prepares the connection; nothing connects
  // before start(). A CA file that cannot be used throws Error.
  explicit Client(ClientOptions options);
  ~Client();  // stops
  Client(const Client&) = delete;
  Client& operator=(const Client&) = delete;

  // Callbacks run on the client's network thread; set them before start().
  void on_message(std::function<void(const Message&)> fn);
  // (connected, reason): every connection made or lost, and each new reason a connection could
  // not be made (a broker not there, a certificate its CA did not sign); the reason says why it
  // was lost or refused ("" when connected).
  void on_connection(std::function<void(bool, const std::string&)> fn);
  // Told once per problem with incoming data (a message too large), with the topic.
  void on_problem(std::function<void(const std::string&)> fn);

  // Connects in the background and keeps the connection up until stop().
  void start();
  // Disconnects cleanly (no last will) and stops the network thread. Idempotent.
  void stop();

  // Subscribes now if connected, and again on every later connection. `filter` may have MQTT
  // wildcards. Throws Error for a filter the MQTT rules refuse.
  void subscribe(const std::string& filter, int qos = 1);
  void unsubscribe(const std::string& filter);
  // Publishes (QoS 0-2, retained or not). Throws Error when not connected, or for a topic with
  // wildcards or one the MQTT rules refuse.
  void publish(const std::string& topic, std::string_view payload, bool retain = false, int qos = 1);

  // Waits until everything published so far has reached the broker (for QoS 0: was written;
  // for QoS 1 and 2: was acknowledged). False after `timeout`: the broker went away meanwhile.
  bool drain(std::chrono::milliseconds timeout) const;

  bool connected() const;
  bool wait_connected(std::chrono::milliseconds timeout) const;
  std::uint64_t connections() const;  // how many times a connection was made
  std::string last_error() const;     // why the last connection was lost or refused
  bool refused() const;               // the broker refused the client: it does not retry

 private:
  static void handle_connect(struct ::mosquitto*, void* self, int rc);
  static void handle_disconnect(struct ::mosquitto*, void* self, int rc);
  static void handle_message(struct ::mosquitto*, void* self, const struct ::mosquitto_message* m);
  static void handle_publish(struct ::mosquitto*, void* self, int mid);
  static void handle_log(struct ::mosquitto*, void* self, int level, const char* text);

  ClientOptions options_;
  struct ::mosquitto* mosq_ = nullptr;
  mutable std::mutex mutex_;
  mutable std::condition_variable changed_;
  bool started_ = false;
  bool connected_ = false;
  bool refused_ = false;
  std::uint64_t connections_ = 0;
  std::uint64_t sent_ = 0;       // publishes handed to libmosquitto
  std::uint64_t delivered_ = 0;  // ... and done with (written, or acknowledged)
  std::string last_error_;
  std::string log_error_;         // libmosquitto's last error log line since the last connection
  std::string reported_failure_;  // the failure to connect last told to on_connection
  std::map<std::string, int> subscriptions_;  // filter -> QoS, made again on each connection
  std::function<void(const Message&)> on_message_;
  std::function<void(bool, const std::string&)> on_connection_;
  std::function<void(const std::string&)> on_problem_;
};

}  // namespace icars::bridge::mqtt
