#include "icars/bridge/mqtt/client.h"

#include <fmt/format.h>
#include <mosquitto.h>

#include <cerrno>
#include <cstring>
#include <fstream>
#include <mutex>
#include <utility>

namespace icars::bridge::mqtt {

namespace {

void init_library() {
  static std::once_flag once;
  std::call_once(once, [] { mosquitto_lib_init(); });
}

std::string endpoint(const ClientOptions& o) { return fmt::format("{}:{}", o.host, o.port); }

}  // namespace

void ClientOptions::validate() const {
  if (host.empty()) throw std::invalid_argument("mqtt: the broker's host is empty");
  if (port < 1 || port > 65535) throw std::invalid_argument(fmt::format("mqtt: port {} is not in 1-65535", port));
  if (client_id.size() > 65535) throw std::invalid_argument("mqtt: the client id is longer than 65535 bytes");
  if (keepalive < std::chrono::seconds(5)) throw std::invalid_argument("mqtt: keepalive must be at least 5 s");
  if (reconnect_min < std::chrono::seconds(1) || reconnect_max < reconnect_min) {
    throw std::invalid_argument("mqtt: reconnect delays must be at least 1 s, the maximum not below the minimum");
  }
  if (!password.empty() && username.empty()) throw std::invalid_argument("mqtt: a password needs a username");
  if (will && mosquitto_pub_topic_check(will->topic.c_str()) != MOSQ_ERR_SUCCESS) {
    throw std::invalid_argument(fmt::format("mqtt: the last will's topic '{}' is not a topic one can publish to",
                                            will->topic));
  }
  if (max_payload == 0) throw std::invalid_argument("mqtt: max_payload must be positive");
}

Client::Client(ClientOptions options) : options_(std::move(options)) {
  options_.validate();
  init_library();
  mosq_ = mosquitto_new(options_.client_id.empty() ? nullptr : options_.client_id.c_str(), true, this);
  if (!mosq_) throw Error("mqtt: cannot create a client (out of memory)");
  const auto check = [this](int rc, const char* what) {
    if (rc == MOSQ_ERR_SUCCESS) return;
    const std::string reason = fmt::format("mqtt: {}: {}", what, mosquitto_strerror(rc));
    mosquitto_destroy(mosq_);
    mosq_ = nullptr;
    throw Error(reason);
  };
  check(mosquitto_int_option(mosq_, MOSQ_OPT_PROTOCOL_VERSION, MQTT_PROTOCOL_V311), "protocol version");
  if (!options_.username.empty()) {
    check(mosquitto_username_pw_set(mosq_, options_.username.c_str(),
                                    options_.password.empty() ? nullptr : options_.password.c_str()),
          "username and password");
  }
  if (!options_.ca_file.empty()) {
    if (!std::ifstream(options_.ca_file)) {
      mosquitto_destroy(mosq_);
      mosq_ = nullptr;
      throw Error(fmt::format("mqtt: cannot read the CA file {}", options_.ca_file));
    }
    check(mosquitto_tls_set(mosq_, options_.ca_file.c_str(), nullptr, nullptr, nullptr, nullptr),
          fmt::format("TLS with the CA file {}", options_.ca_file).c_str());
  }
  if (options_.will) {
    check(mosquitto_will_set(mosq_, options_.will->topic.c_str(), static_cast<int>(options_.will->payload.size()),
                             options_.will->payload.data(), 1, options_.will->retain),
          "last will");
  }
  // Commands and states are small messages that want an answer: without this, a publish that
  // follows an acknowledgement waits for the broker's delayed ACK (40 ms on Linux).
  check(mosquitto_int_option(mosq_, MOSQ_OPT_TCP_NODELAY, 1), "TCP_NODELAY");
  check(mosquitto_reconnect_delay_set(mosq_, static_cast<unsigned>(options_.reconnect_min.count()),
                                      static_cast<unsigned>(options_.reconnect_max.count()), true),
        "reconnect delay");
  mosquitto_connect_callback_set(mosq_, &Client::handle_connect);
  mosquitto_disconnect_callback_set(mosq_, &Client::handle_disconnect);
  mosquitto_message_callback_set(mosq_, &Client::handle_message);
  mosquitto_publish_callback_set(mosq_, &Client::handle_publish);
  mosquitto_log_callback_set(mosq_, &Client::handle_log);
}

Client::~Client() {
  stop();
  if (mosq_) mosquitto_destroy(mosq_);
}

void Client::on_message(std::function<void(const Message&)> fn) { on_message_ = std::move(fn); }
void Client::on_connection(std::function<void(bool, const std::string&)> fn) { on_connection_ = std::move(fn); }
void Client::on_problem(std::function<void(const std::string&)> fn) { on_problem_ = std::move(fn); }

void Client::start() {
  {
    std::lock_guard lock(mutex_);
    if (started_) return;
    started_ = true;
    refused_ = false;
  }
  // The network thread first: then connect_async leaves the connecting to it, and a broker that
  // is not there yet is tried again with backoff instead of failing here.
  const int loop = mosquitto_loop_start(mosq_);
  if (loop != MOSQ_ERR_SUCCESS) {
    std::lock_guard lock(mutex_);
    started_ = false;
    throw Error(fmt::format("mqtt: cannot start the network thread: {}", mosquitto_strerror(loop)));
  }
  const int rc = mosquitto_connect_async(mosq_, options_.host.c_str(), options_.port,
                                         static_cast<int>(options_.keepalive.count()));
  if (rc != MOSQ_ERR_SUCCESS) {
    std::lock_guard lock(mutex_);
    last_error_ = fmt::format("cannot connect to the broker at {}: {}", endpoint(options_),
                              rc == MOSQ_ERR_ERRNO ? std::strerror(errno) : mosquitto_strerror(rc));
  }
}

void Client::stop() {
  {
    std::lock_guard lock(mutex_);
    if (!started_) return;
    started_ = false;
  }
  mosquitto_disconnect(mosq_);
  mosquitto_loop_stop(mosq_, false);
  std::lock_guard lock(mutex_);
  connected_ = false;
  changed_.notify_all();
}

void Client::subscribe(const std::string& filter, int qos) {
  if (mosquitto_sub_topic_check(filter.c_str()) != MOSQ_ERR_SUCCESS) {
    throw Error(fmt::format("mqtt: '{}' is not a topic filter (wildcards '+' and '#' stand alone in a level, '#' last)",
                            filter));
  }
  if (qos < 0 || qos > 2) throw Error(fmt::format("mqtt: QoS {} is not 0, 1 or 2", qos));
  bool now = false;
  {
    std::lock_guard lock(mutex_);
    subscriptions_[filter] = qos;
    now = connected_;
  }
  // If the connection is lost meanwhile, the next one subscribes again.
  if (now) mosquitto_subscribe(mosq_, nullptr, filter.c_str(), qos);
}

void Client::unsubscribe(const std::string& filter) {
  bool now = false;
  {
    std::lock_guard lock(mutex_);
    if (subscriptions_.erase(filter) == 0) return;
    now = connected_;
  }
  if (now) mosquitto_unsubscribe(mosq_, nullptr, filter.c_str());
}

void Client::publish(const std::string& topic, std::string_view payload, bool retain, int qos) {
  if (mosquitto_pub_topic_check(topic.c_str()) != MOSQ_ERR_SUCCESS) {
    throw Error(fmt::format("mqtt: cannot publish to '{}': a topic has no wildcards ('+', '#') and is not empty",
                            topic));
  }
  if (qos < 0 || qos > 2) throw Error(fmt::format("mqtt: QoS {} is not 0, 1 or 2", qos));
  // Not queued for a later connection: a command meant for now fails now, with the reason.
  const int rc = connected() ? mosquitto_publish(mosq_, nullptr, topic.c_str(), static_cast<int>(payload.size()),
                                                 payload.data(), qos, retain)
                             : MOSQ_ERR_NO_CONN;
  if (rc == MOSQ_ERR_SUCCESS) {
    std::lock_guard lock(mutex_);
    ++sent_;
    return;
  }
  if (rc == MOSQ_ERR_NO_CONN) {
    throw Error(fmt::format("mqtt: cannot publish to '{}': not connected to the broker at {}{}", topic,
                            endpoint(options_), last_error().empty() ? "" : " (" + last_error() + ")"));
  }
  throw Error(fmt::format("mqtt: cannot publish to '{}': {}", topic, mosquitto_strerror(rc)));
}

bool Client::drain(std::chrono::milliseconds timeout) const {
  std::unique_lock lock(mutex_);
  return changed_.wait_for(lock, timeout, [this] { return delivered_ >= sent_; });
}

void Client::handle_publish(struct ::mosquitto*, void* obj, int) {
  auto* self = static_cast<Client*>(obj);
  std::lock_guard lock(self->mutex_);
  ++self->delivered_;
  self->changed_.notify_all();
}

bool Client::connected() const {
  std::lock_guard lock(mutex_);
  return connected_;
}

bool Client::wait_connected(std::chrono::milliseconds timeout) const {
  std::unique_lock lock(mutex_);
  return changed_.wait_for(lock, timeout, [this] { return connected_ || refused_; }) && connected_;
}

std::uint64_t Client::connections() const {
  std::lock_guard lock(mutex_);
  return connections_;
}

std::string Client::last_error() const {
  std::lock_guard lock(mutex_);
  return last_error_;
}

bool Client::refused() const {
  std::lock_guard lock(mutex_);
  return refused_;
}

// --- libmosquitto's callbacks, on its network thread -----------------------------------------

void Client::handle_connect(struct ::mosquitto* mosq, void* obj, int rc) {
  auto* self = static_cast<Client*>(obj);
  std::string reason;
  std::map<std::string, int> subscriptions;
  {
    std::lock_guard lock(self->mutex_);
    if (rc == 0) {
      self->connected_ = true;
      ++self->connections_;
      self->log_error_.clear();
      self->reported_failure_.clear();
      subscriptions = self->subscriptions_;
    } else {
      // Refused (a wrong password, a client the broker does not want): retrying will not help.
      self->refused_ = true;
      self->last_error_ = reason = fmt::format("the broker at {} refused the connection: {}", endpoint(self->options_),
                                               mosquitto_connack_string(rc));
    }
    self->changed_.notify_all();
  }
  if (rc != 0) mosquitto_disconnect(mosq);
  for (const auto& [filter, qos] : subscriptions) mosquitto_subscribe(mosq, nullptr, filter.c_str(), qos);
  if (self->on_connection_) self->on_connection_(rc == 0, reason);
}

void Client::handle_disconnect(struct ::mosquitto*, void* obj, int rc) {
  auto* self = static_cast<Client*>(obj);
  std::string reason;
  bool report = false;
  {
    std::lock_guard lock(self->mutex_);
    const bool was_connected = self->connected_;
    self->connected_ = false;
    if (rc != 0 && !self->refused_) {
      reason = fmt::format("{} the broker at {}: {}", was_connected ? "lost the connection to" : "cannot connect to",
                           endpoint(self->options_),
                           rc == MOSQ_ERR_ERRNO ? std::strerror(errno) : mosquitto_strerror(rc));
      // What libmosquitto logged about it says more (a certificate the CA did not sign).
      if (!self->log_error_.empty()) reason += " (" + self->log_error_ + ")";
      self->last_error_ = reason;
    }
    // A connection that never came up is reported once per reason, not on every retry.
    report = was_connected || (!reason.empty() && reason != self->reported_failure_);
    if (!was_connected && !reason.empty()) self->reported_failure_ = reason;
    self->changed_.notify_all();
  }
  if (report && self->on_connection_) self->on_connection_(false, reason.empty() ? "disconnected" : reason);
}

// libmosquitto reports some failures to connect only in its log (a TLS handshake that fails
// ends the attempt without a disconnect): an error logged while not connected is one, told once
// per reason.
void Client::handle_log(struct ::mosquitto*, void* obj, int level, const char* text) {
  if ((level & MOSQ_LOG_ERR) == 0 || text == nullptr) return;
  auto* self = static_cast<Client*>(obj);
  std::string reason;
  {
    std::lock_guard lock(self->mutex_);
    self->log_error_ = text;
    if (self->connected_ || self->refused_ || !self->started_) return;
    reason = fmt::format("cannot connect to the broker at {}: {}", endpoint(self->options_), text);
    self->last_error_ = reason;
    if (reason == self->reported_failure_) return;
    self->reported_failure_ = reason;
    self->changed_.notify_all();
  }
  if (self->on_connection_) self->on_connection_(false, reason);
}

void Client::handle_message(struct ::mosquitto*, void* obj, const struct ::mosquitto_message* m) {
  auto* self = static_cast<Client*>(obj);
  if (m->payloadlen < 0 || static_cast<std::size_t>(m->payloadlen) > self->options_.max_payload) {
    if (self->on_problem_) {
      self->on_problem_(fmt::format("{}: a message of {} bytes dropped (more than {})", m->topic, m->payloadlen,
                                    self->options_.max_payload));
    }
    return;
  }
  if (!self->on_message_) return;
  Message message;
  message.topic = m->topic;
  message.payload.assign(static_cast<const char*>(m->payload), static_cast<std::size_t>(m->payloadlen));
  message.retained = m->retain;
  self->on_message_(message);
}

BrokerUri parse_broker_uri(const std::string& uri) {
  BrokerUri b;
  std::string rest;
  if (uri.starts_with("mqtt://")) {
    rest = uri.substr(7);
  } else if (uri.starts_with("mqtts://")) {
    rest = uri.substr(8);
    b.tls = true;
    b.port = 8883;
  } else {
    throw std::invalid_argument("'" + uri + "' is not mqtt://HOST[:PORT] or mqtts://HOST[:PORT]");
  }
  const auto colon = rest.rfind(':');
  if (colon != std::string::npos) {
    const auto port = rest.substr(colon + 1);
    rest = rest.substr(0, colon);
    try {
      std::size_t used = 0;
      b.port = std::stoi(port, &used);
      if (used != port.size() || b.port < 1 || b.port > 65535) throw std::invalid_argument(port);
    } catch (const std::exception&) {
      throw std::invalid_argument("'" + uri + "': the port is not a number from 1 to 65535");
    }
  }
  if (rest.empty() || rest.find('/') != std::string::npos) {
    throw std::invalid_argument("'" + uri + "': no host, or a path after it");
  }
  b.host = rest;
  return b;
}

}  // namespace icars::bridge::mqtt
