// Commands through the MQTT bridge: the latency of one command from an ICARS call to its
// acknowledgment, and commands per second, next to the same round trip made by a plain MQTT
// client and by the mosquitto_pub / mosquitto_sub programs (a plain program printing medians).
//
//   mqtt_bridge [--runs 5] [--commands 200] [--window 16] [--process-commands 50] [--nodelay]
//               [--mosquitto /usr/sbin/mosquitto]
//
// Everything runs on loopback against Debian's `mosquitto` broker, started by this program on a
// free port and killed when it exits (also when it fails or is killed: the broker gets SIGKILL
// when this process dies).
// TCP: by default as Debian's broker sets it up, with Nagle's algorithm on its side of every
// connection, so when it writes twice in a row (an acknowledgment, then a message) the second
// waits for the client's delayed ACK (40 ms on Linux): about 40 ms of every round trip here.
// --nodelay takes those delays out: the broker with `set_tcp_nodelay true` and mosquitto_pub/sub
// with --nodelay (icars::bridge::mqtt::Client, on both sides here, always sets TCP_NODELAY).
//   the lamps          --window zigbee2mqtt-like lamps on an MQTT client of their own: each
//                      publishes a retained Home Assistant discovery config (light, json schema),
//                      its availability and its state, and answers every command on its command
//                      topic by publishing its new state (retained) at once;
//   icars call         a MediatingServer (home adaptors) and, as icars-mqtt-bridge has them, a
//                      DeviceManager with MqttDevices on a client of their own, registered with
//                      the server over loopback PLANET. A call is LightPrx::set_power on the
//                      server's LightControl service of a lamp: server → device manager → the
//                      bridge publishes the command → broker → lamp → state → broker → bridge
//                      (the state confirms the command) → reply → server → caller;
//   mqtt client        a client of its own publishes the command the bridge would publish and
//                      waits for the lamp's state message that confirms it (libmosquitto through
//                      bridge::mqtt::Client, as the bridge; QoS 1 everywhere, as the bridge);
//   processes          per command, `mosquitto_sub -q 1 -C 2 -t STATE` (its first message is
//                      the retained state: the subscription is in place) and then
//                      `mosquitto_pub -q 1 -t COMMAND -m ...`, timed from starting mosquitto_sub
//                      until it printed the new state: two process starts and two connections
//                      per command, what a shell script pays.
// Measured in each run: latency, one command at a time on one lamp, each command the opposite
// of the last (--commands; --process-commands for the processes), after 20 untimed ones; and
// throughput, --commands commands with --window of them in flight, one per lamp (on a lamp the
// next command starts when its last one was confirmed). Every row checks that the lamps
// received exactly the commands it counted as confirmed. The processes row has no window: its
// commands/s is 1 / its median latency. Prints, over --runs runs, the median of each run's
// median, p99 and commands/s, and each row's ratio to the mqtt client's.
#include <fcntl.h>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <netinet/in.h>
#include <poll.h>
#include <pwd.h>
#include <signal.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <semaphore>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "bench_util.h"
#include "icars/bridge/mqtt/client.h"
#include "icars/device/device_manager.h"
#include "icars/home/adaptors.h"
#include "icars/home/mqtt/entity_devices.h"
#include "icars/server/mediating_server.h"

namespace {

namespace bm = icars::bridge::mqtt;
namespace fs = std::filesystem;
namespace p = icars::planet;
using nlohmann::json;
using Clock = std::chrono::steady_clock;
using Ms = std::chrono::duration<double, std::milli>;
using namespace std::chrono_literals;

constexpr auto kWait = 10s;  // the bound of every single wait: a connection, a command, a process
constexpr int kWarmUp = 20;

std::shared_ptr<spdlog::logger> quiet_logger(const std::string& name) {
  auto log = std::make_shared<spdlog::logger>(name, std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
  log->set_level(spdlog::level::warn);
  return log;
}

// Nearest-rank percentile of a non-empty sample.
double percentile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  const auto rank = static_cast<std::size_t>(std::ceil(q * static_cast<double>(v.size())));
  return v[std::min(v.size() - 1, rank == 0 ? 0 : rank - 1)];
}

// --- Processes -------------------------------------------------------------------------------

// `name` in PATH or an sbin directory, or a runtime_error saying which Debian package has it.
std::string find_program(const std::string& name, const std::string& package) {
  std::string dirs = std::getenv("PATH") ? std::getenv("PATH") : "";
  dirs += ":/usr/sbin:/usr/local/sbin:/sbin";
  std::stringstream in(dirs);
  for (std::string dir; std::getline(in, dir, ':');) {
    if (dir.empty()) continue;
    const auto path = fs::path(dir) / name;
    if (::access(path.c_str(), X_OK) == 0) return path.string();
  }
  throw std::runtime_error(fmt::format("{} not found in PATH or /usr/sbin: install Debian's {} (apt-get install {})",
                                       name, package, package));
}

std::string read_file(const fs::path& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

// A child process with its stdout piped to us and its stderr in a file. It gets SIGKILL when
// this process dies, and from the destructor when it still runs.
class Process {
 public:
  Process(const std::vector<std::string>& argv, const fs::path& stderr_file) : name_(argv.at(0)) {
    int out[2];
    if (::pipe2(out, O_CLOEXEC) != 0) icars::bench::throw_errno("pipe");
    const int err = ::open(stderr_file.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    if (err < 0) {
      ::close(out[0]);
      ::close(out[1]);
      icars::bench::throw_errno("open for a child's stderr");
    }
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    const pid_t parent = ::getpid();
    pid_ = ::fork();
    if (pid_ == 0) {  // only async-signal-safe calls from here on
      ::prctl(PR_SET_PDEATHSIG, SIGKILL);
      if (::getppid() != parent) ::_exit(126);
      ::dup2(out[1], STDOUT_FILENO);
      ::dup2(err, STDERR_FILENO);
      ::execv(args[0], args.data());
      ::_exit(127);
    }
    const int fork_errno = errno;
    ::close(out[1]);
    ::close(err);
    if (pid_ < 0) {
      ::close(out[0]);
      errno = fork_errno;
      icars::bench::throw_errno("fork");
    }
    stdout_fd_ = out[0];
  }
  ~Process() {
    if (!reaped_) {
      ::kill(pid_, SIGKILL);
      int status = 0;
      ::waitpid(pid_, &status, 0);
    }
    ::close(stdout_fd_);
  }
  Process(const Process&) = delete;
  Process& operator=(const Process&) = delete;

  // The next line of its stdout, or nullopt at its end or after the timeout.
  std::optional<std::string> read_line(std::chrono::milliseconds timeout) {
    const auto deadline = Clock::now() + timeout;
    for (;;) {
      if (const auto nl = buffer_.find('\n'); nl != std::string::npos) {
        std::string line = buffer_.substr(0, nl);
        buffer_.erase(0, nl + 1);
        return line;
      }
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count();
      if (left <= 0) return std::nullopt;
      pollfd p{stdout_fd_, POLLIN, 0};
      if (::poll(&p, 1, static_cast<int>(left)) <= 0) continue;
      char chunk[512];
      const ssize_t n = ::read(stdout_fd_, chunk, sizeof chunk);
      if (n <= 0) return std::nullopt;
      buffer_.append(chunk, static_cast<std::size_t>(n));
    }
  }

  // Its wait status once it exited within `timeout`, else nullopt.
  std::optional<int> wait_for(std::chrono::milliseconds timeout) {
    const auto deadline = Clock::now() + timeout;
    for (;;) {
      int status = 0;
      if (::waitpid(pid_, &status, WNOHANG) == pid_) {
        reaped_ = true;
        return status;
      }
      if (Clock::now() >= deadline) return std::nullopt;
      std::this_thread::sleep_for(1ms);
    }
  }

  // Waits for it to exit and throws unless it exited with 0; `err` is its stderr file.
  void expect_success(const fs::path& err) {
    const auto status = wait_for(kWait);
    if (!status) throw std::runtime_error(fmt::format("{} did not exit within {} s", name_, kWait.count()));
    if (!WIFEXITED(*status) || WEXITSTATUS(*status) != 0) {
      throw std::runtime_error(fmt::format("{} failed (wait status {}): {}", name_, *status, read_file(err)));
    }
  }

 private:
  std::string name_;
  pid_t pid_ = -1;
  int stdout_fd_ = -1;
  std::string buffer_;
  bool reaped_ = false;
};

// A directory of our own under /tmp, removed at the end.
class TempDir {
 public:
  TempDir() {
    char pattern[] = "/tmp/icars-mqtt-bench-XXXXXX";
    if (!::mkdtemp(pattern)) icars::bench::throw_errno("mkdtemp");
    path_ = pattern;
  }
  ~TempDir() {
    std::error_code ignored;
    fs::remove_all(path_, ignored);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

// A loopback port nobody listens on now (bound once and released).
int free_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof a;
  const bool ok = fd >= 0 && ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0 &&
                  ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) == 0;
  if (fd >= 0) ::close(fd);
  if (!ok) icars::bench::throw_errno("finding a free loopback port");
  return ntohs(a.sin_port);
}

bool accepts(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return false;
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  const bool ok = ::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
  ::close(fd);
  return ok;
}

// Debian's mosquitto on a free loopback port, anonymous clients allowed, no persistence.
class Broker {
 public:
  Broker(const std::string& mosquitto, const fs::path& dir, bool nodelay) : port_(free_port()) {
    const auto conf = dir / "mosquitto.conf";
    const auto* user = ::getpwuid(::geteuid());
    std::ofstream(conf) << "listener " << port_ << " 127.0.0.1\n"
                        << "allow_anonymous true\n"
                        << "persistence false\n"
                        << "set_tcp_nodelay " << (nodelay ? "true" : "false") << "\n"
                        // As root, mosquitto would become user "mosquitto", who cannot read `dir`.
                        << "user " << (user ? user->pw_name : "root") << "\n"
                        << "log_dest stderr\n"
                        << "log_type error\n";
    const auto log = dir / "mosquitto.log";
    process_ = std::make_unique<Process>(std::vector<std::string>{mosquitto, "-c", conf.string()}, log);
    const auto deadline = Clock::now() + kWait;
    while (!accepts(port_)) {
      if (process_->wait_for(0ms)) {
        throw std::runtime_error(fmt::format("mosquitto exited at start on port {}: {}", port_, read_file(log)));
      }
      if (Clock::now() > deadline) {
        throw std::runtime_error(fmt::format("mosquitto did not listen on port {} within {} s", port_, kWait.count()));
      }
      std::this_thread::sleep_for(5ms);
    }
  }
  int port() const { return port_; }

 private:
  int port_;
  std::unique_ptr<Process> process_;  // killed on destruction
};

// --- The lamps ---------------------------------------------------------------------------------

// Zigbee lamps as zigbee2mqtt presents them to Home Assistant: a retained discovery config
// (light, json schema, brightness 0..254), availability and state; a command on
// zigbee2mqtt/<name>/set is obeyed and answered with the new state at once.
class Lamps {
 public:
  Lamps(int broker_port, int count) : client_(options(broker_port)), on_(static_cast<std::size_t>(count), false) {
    for (int i = 0; i < count; ++i) by_command_topic_[command_topic(i)] = i;
    client_.on_message([this](const bm::Message& m) { on_command(m); });
  }
  ~Lamps() { client_.stop(); }
  Lamps(const Lamps&) = delete;
  Lamps& operator=(const Lamps&) = delete;

  void start() {
    client_.subscribe("zigbee2mqtt/+/set");
    client_.start();
    if (!client_.wait_connected(kWait)) {
      throw std::runtime_error("the lamps could not connect to the broker: " + client_.last_error());
    }
    for (int i = 0; i < count(); ++i) {
      client_.publish(availability_topic(i), R"({"state":"online"})", true);
      publish_state(i);
      client_.publish(config_topic(i), config(i).dump(), true);
    }
  }

  int count() const { return static_cast<int>(on_.size()); }
  bool on(int lamp) const {
    std::lock_guard lock(mutex_);
    return on_.at(static_cast<std::size_t>(lamp));
  }
  int commands() const {
    std::lock_guard lock(mutex_);
    return commands_;
  }
  // Why the last command could not be answered ("" when all were).
  std::string problem() const {
    std::lock_guard lock(mutex_);
    return problem_;
  }

  static std::string name(int lamp) { return fmt::format("bench_lamp_{}", lamp); }
  static std::string ieee(int lamp) { return fmt::format("0x00178801{:08x}", lamp + 1); }
  static std::string unique_id(int lamp) { return ieee(lamp) + "_light_zigbee2mqtt"; }
  static std::string command_topic(int lamp) { return "zigbee2mqtt/" + name(lamp) + "/set"; }
  static std::string state_topic(int lamp) { return "zigbee2mqtt/" + name(lamp); }
  static std::string command(bool on) { return on ? R"({"state":"ON"})" : R"({"state":"OFF"})"; }
  // The power a state payload reports, nullopt when it is not a lamp state.
  static std::optional<bool> power_of(const std::string& payload) {
    const auto j = json::parse(payload, nullptr, false);
    if (!j.is_object() || !j.contains("state") || !j["state"].is_string()) return std::nullopt;
    return j["state"] == "ON";
  }

 private:
  static bm::ClientOptions options(int port) {
    bm::ClientOptions o;
    o.port = port;
    o.client_id = "bench-zigbee2mqtt";
    return o;
  }
  static std::string availability_topic(int lamp) { return state_topic(lamp) + "/availability"; }
  static std::string config_topic(int lamp) { return "homeassistant/light/" + ieee(lamp) + "/light/config"; }
  static json config(int lamp) {
    return {{"name", nullptr},
            {"object_id", name(lamp)},
            {"unique_id", unique_id(lamp)},
            {"schema", "json"},
            {"brightness", true},
            {"brightness_scale", 254},
            {"state_topic", state_topic(lamp)},
            {"command_topic", command_topic(lamp)},
            {"availability", {{{"topic", availability_topic(lamp)}, {"value_template", "{{ value_json.state }}"}}}},
            {"device",
             {{"identifiers", {"zigbee2mqtt_" + ieee(lamp)}},
              {"name", name(lamp)},
              {"manufacturer", "Signify Netherlands B.V."},
              {"model", "Hue white A60 bulb E27"},
              {"suggested_area", "Bench"}}}};
  }

  void on_command(const bm::Message& m) {
    const auto it = by_command_topic_.find(m.topic);
    if (it == by_command_topic_.end()) return;
    const auto j = json::parse(m.payload, nullptr, false);
    {
      std::lock_guard lock(mutex_);
      ++commands_;
      bool on = on_[static_cast<std::size_t>(it->second)];
      if (!j.is_object() || !j.contains("state") || !j["state"].is_string()) {
        problem_ = fmt::format("'{}' on {} is not a zigbee2mqtt light command", m.payload, m.topic);
        return;
      }
      const auto state = j["state"].get<std::string>();
      on = state == "TOGGLE" ? !on : state == "ON";
      on_[static_cast<std::size_t>(it->second)] = on;
    }
    publish_state(it->second);
  }

  void publish_state(int lamp) {
    const bool on = this->on(lamp);
    try {
      client_.publish(state_topic(lamp), json{{"brightness", 254}, {"state", on ? "ON" : "OFF"}}.dump(), true);
    } catch (const bm::Error& e) {
      std::lock_guard lock(mutex_);
      problem_ = fmt::format("cannot publish the state of {}: {}", name(lamp), e.what());
    }
  }

  bm::Client client_;
  std::map<std::string, int> by_command_topic_;
  mutable std::mutex mutex_;
  std::vector<bool> on_;
  int commands_ = 0;  // commands received
  std::string problem_;
};

// --- Who sends commands ------------------------------------------------------------------------

// Called once per command with nullptr when the lamp confirmed it, or with the failure.
using Done = std::function<void(std::exception_ptr)>;

// A way of sending commands: synchronously, or starting one and hearing of it through `done`.
struct Sender {
  std::function<void(int lamp, bool on)> call;
  std::function<void(int lamp, bool on, Done done)> start;
};

// ICARS: a mediating server with the lamps registered by an MqttDevices bridge, as
// icars-mqtt-bridge runs it (its own MQTT client, device manager and PLANET link).
class IcarsHome {
 public:
  IcarsHome(int broker_port, int lamps)
      : server_(server_options()),
        manager_side_(communicator_options("bench-bridge")),
        manager_(manager_side_),
        client_(client_options(broker_port)) {
    icars::home::mqtt::MqttDevicesOptions o;
    o.logger = quiet_logger("mqtt-devices");
    for (int i = 0; i < lamps; ++i) o.placements[Lamps::unique_id(i)] = {Lamps::name(i), "bench", ""};
    devices_ = std::make_unique<icars::home::mqtt::MqttDevices>(client_, manager_, std::move(o));
    const auto port = server_.listen();
    client_.start();
    manager_.connect("127.0.0.1", port);
  }
  ~IcarsHome() {
    devices_.reset();
    client_.stop();
  }
  IcarsHome(const IcarsHome&) = delete;
  IcarsHome& operator=(const IcarsHome&) = delete;

  // Waits until the server has every lamp's LightControl service and takes their proxies.
  void await_lamps(int lamps) {
    using icars::service::ServiceQuery;
    auto& c = server_.container();
    const auto deadline = Clock::now() + 3 * kWait;
    while (c.find(ServiceQuery::of_type("LightControl").in_room("bench").available()).size() !=
           static_cast<std::size_t>(lamps)) {
      if (Clock::now() > deadline) {
        throw std::runtime_error(fmt::format(
            "the server did not get the {} lamps' LightControl services within {} s ({} did; bridge "
            "connected to the broker: {}; problems: {})",
            lamps, 3 * kWait.count(), c.find(ServiceQuery::of_type("LightControl").available()).size(),
            client_.connected(), fmt::join(devices_->problems(), "; ")));
      }
      std::this_thread::sleep_for(5ms);
    }
    for (int i = 0; i < lamps; ++i) {
      const auto light = c.find_first<icars::home::LightService>(
          ServiceQuery::of_type("LightControl").on_device(Lamps::name(i)).available());
      if (!light) throw std::runtime_error("no LightControl service for " + Lamps::name(i));
      lights_.push_back(light->proxy());
    }
  }

  Sender sender() {
    return {[this](int lamp, bool on) { lights_.at(static_cast<std::size_t>(lamp)).set_power(on); },
            [this](int lamp, bool on, Done done) {
              lights_.at(static_cast<std::size_t>(lamp)).set_power_async(on, std::move(done));
            }};
  }

 private:
  static p::CommunicatorOptions communicator_options(const std::string& name) {
    p::CommunicatorOptions o;
    o.name = name;
    o.logger = quiet_logger(name);
    return o;
  }
  static icars::server::ServerOptions server_options() {
    icars::server::ServerOptions o;
    o.planet.logger = quiet_logger("icars");
    o.planet.logger->set_level(spdlog::level::err);  // not the device manager's link closing at exit
    o.adaptors = icars::home::adaptors();
    return o;
  }
  static bm::ClientOptions client_options(int port) {
    bm::ClientOptions o;
    o.port = port;
    o.client_id = "icars-mqtt-bridge";
    return o;
  }

  icars::server::MediatingServer server_;
  p::Communicator manager_side_;
  icars::device::DeviceManager manager_;
  bm::Client client_;
  std::unique_ptr<icars::home::mqtt::MqttDevices> devices_;
  std::vector<icars::home::LightPrx> lights_;
};

// The same round trip without ICARS: an MQTT client publishes the command the bridge would and
// waits for the lamp's state message that confirms it.
class MqttPeer {
 public:
  MqttPeer(int broker_port, int lamps) : client_(options(broker_port)), pending_(static_cast<std::size_t>(lamps)) {
    for (int i = 0; i < lamps; ++i) by_state_topic_[Lamps::state_topic(i)] = i;
    client_.on_message([this](const bm::Message& m) { on_state(m); });
  }
  ~MqttPeer() { client_.stop(); }
  MqttPeer(const MqttPeer&) = delete;
  MqttPeer& operator=(const MqttPeer&) = delete;

  void start() {
    for (const auto& [topic, lamp] : by_state_topic_) client_.subscribe(topic);
    client_.start();
    if (!client_.wait_connected(kWait)) {
      throw std::runtime_error("the MQTT client could not connect to the broker: " + client_.last_error());
    }
  }

  Sender sender() {
    return {[this](int lamp, bool on) { call(lamp, on); },
            [this](int lamp, bool on, Done done) { send(lamp, on, std::move(done)); }};
  }

 private:
  struct Pending {
    bool on = false;
    Done done;
  };

  static bm::ClientOptions options(int port) {
    bm::ClientOptions o;
    o.port = port;
    o.client_id = "bench-mqtt-client";
    return o;
  }

  // `done` runs on the client's network thread once the state confirms the command, or here
  // when the publish fails.
  void send(int lamp, bool on, Done done) {
    {
      std::lock_guard lock(mutex_);
      auto& slot = pending_.at(static_cast<std::size_t>(lamp));
      if (slot) throw std::logic_error(fmt::format("{} has a command in flight already", Lamps::name(lamp)));
      slot = Pending{on, std::move(done)};
    }
    try {
      client_.publish(Lamps::command_topic(lamp), Lamps::command(on));
    } catch (const bm::Error&) {
      Done failed;
      {
        std::lock_guard lock(mutex_);
        failed = std::move(pending_.at(static_cast<std::size_t>(lamp))->done);
        pending_.at(static_cast<std::size_t>(lamp)).reset();
      }
      failed(std::current_exception());
    }
  }

  void call(int lamp, bool on) {
    struct State {
      std::binary_semaphore done{0};
      std::exception_ptr error;
    };
    auto state = std::make_shared<State>();
    send(lamp, on, [state](std::exception_ptr e) {
      state->error = e;
      state->done.release();
    });
    if (!state->done.try_acquire_for(kWait)) {
      std::lock_guard lock(mutex_);
      pending_.at(static_cast<std::size_t>(lamp)).reset();
      throw std::runtime_error(fmt::format("{} did not confirm '{}' within {} s", Lamps::name(lamp),
                                           Lamps::command(on), kWait.count()));
    }
    if (state->error) std::rethrow_exception(state->error);
  }

  void on_state(const bm::Message& m) {
    if (m.retained) return;  // what the lamp said before we subscribed
    const auto it = by_state_topic_.find(m.topic);
    const auto power = Lamps::power_of(m.payload);
    if (it == by_state_topic_.end() || !power) return;
    Done done;
    {
      std::lock_guard lock(mutex_);
      auto& slot = pending_[static_cast<std::size_t>(it->second)];
      if (!slot || slot->on != *power) return;
      done = std::move(slot->done);
      slot.reset();
    }
    done(nullptr);
  }

  bm::Client client_;
  std::map<std::string, int> by_state_topic_;
  std::mutex mutex_;
  std::vector<std::optional<Pending>> pending_;  // by lamp
};

// --- Measurements ------------------------------------------------------------------------------

// One command at a time on lamp 0, each the opposite of the last: the latency of each (ms),
// after kWarmUp untimed ones.
std::vector<double> latencies(const Sender& sender, const Lamps& lamps, int commands) {
  bool on = lamps.on(0);
  std::vector<double> ms;
  ms.reserve(static_cast<std::size_t>(commands));
  for (int i = 0; i < kWarmUp + commands; ++i) {
    on = !on;
    const auto t0 = Clock::now();
    sender.call(0, on);
    if (i >= kWarmUp) ms.push_back(Ms(Clock::now() - t0).count());
  }
  return ms;
}

// A throughput run: who sends, and how far it got.
struct WindowRun {
  Sender sender;
  std::mutex mutex;
  std::condition_variable changed;
  std::vector<char> on;  // by lamp: what its last command asked for
  int commands = 0, started = 0, finished = 0;
  std::exception_ptr error;
};

// Starts the next command on `lamp` unless all were started or one failed; its completion
// starts the one after it.
void start_next(const std::shared_ptr<WindowRun>& run, int lamp) {
  bool on = false;
  {
    std::lock_guard lock(run->mutex);
    if (run->error || run->started == run->commands) return;
    ++run->started;
    auto& last = run->on[static_cast<std::size_t>(lamp)];
    last = !last;
    on = last != 0;
  }
  run->sender.start(lamp, on, [run, lamp](std::exception_ptr e) {
    {
      std::lock_guard lock(run->mutex);
      ++run->finished;
      if (e && !run->error) run->error = e;
    }
    run->changed.notify_all();
    start_next(run, lamp);
  });
}

// `commands` commands with one in flight on each lamp: commands per second.
double throughput(const Sender& sender, const Lamps& lamps, int commands) {
  auto run = std::make_shared<WindowRun>();
  run->sender = sender;
  run->commands = commands;
  for (int i = 0; i < lamps.count(); ++i) run->on.push_back(lamps.on(i));

  const auto t0 = Clock::now();
  for (int lamp = 0; lamp < lamps.count(); ++lamp) start_next(run, lamp);
  std::unique_lock lock(run->mutex);
  while (run->finished != run->started || (run->started < run->commands && !run->error)) {
    // Bounded by progress: every command is confirmed or fails within kWait.
    const int seen = run->finished;
    if (!run->changed.wait_for(lock, kWait, [&] { return run->finished != seen; })) {
      run->error = std::make_exception_ptr(std::runtime_error(fmt::format(
          "no command was confirmed for {} s ({} of {} were)", kWait.count(), run->finished, commands)));
      break;
    }
  }
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  if (run->error) std::rethrow_exception(run->error);
  return commands / seconds;
}

// Per command, mosquitto_sub and then mosquitto_pub on lamp 0, as a shell script would run them
// (ms, from starting mosquitto_sub until it printed the new state).
std::vector<double> process_latencies(const std::string& sub, const std::string& pub, int port, bool nodelay,
                                      const Lamps& lamps, int commands, const fs::path& dir) {
  const auto sub_err = dir / "mosquitto_sub.err";
  const auto pub_err = dir / "mosquitto_pub.err";
  const auto p = std::to_string(port);
  std::vector<double> ms;
  for (int i = 0; i < commands; ++i) {
    const bool on = !lamps.on(0);
    const auto t0 = Clock::now();
    std::vector<std::string> s_args{sub, "-h", "127.0.0.1", "-p", p, "-q", "1", "-C", "2", "-t", Lamps::state_topic(0)};
    std::vector<std::string> c_args{pub, "-h", "127.0.0.1", "-p", p, "-q", "1", "-t", Lamps::command_topic(0),
                                    "-m", Lamps::command(on)};
    if (nodelay) {
      s_args.emplace_back("--nodelay");
      c_args.emplace_back("--nodelay");
    }
    Process s(s_args, sub_err);
    const auto retained = s.read_line(kWait);
    if (!retained || Lamps::power_of(*retained) != !on) {
      s.expect_success(sub_err);
      throw std::runtime_error(fmt::format("mosquitto_sub printed '{}' where the retained state of {} was expected",
                                           retained.value_or("nothing"), Lamps::name(0)));
    }
    Process c(c_args, pub_err);
    const auto state = s.read_line(kWait);
    const auto t1 = Clock::now();
    if (!state || Lamps::power_of(*state) != on) {
      c.expect_success(pub_err);
      throw std::runtime_error(fmt::format("mosquitto_sub printed '{}' where {}'s new state ({}) was expected",
                                           state.value_or("nothing"), Lamps::name(0), Lamps::command(on)));
    }
    c.expect_success(pub_err);
    s.expect_success(sub_err);
    ms.push_back(Ms(t1 - t0).count());
  }
  return ms;
}

struct Row {
  std::string name;
  std::vector<double> median_ms, p99_ms, per_second;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Commands through the MQTT bridge next to a plain MQTT client and mosquitto_pub/sub"};
  int runs = 5;
  int commands = 200;
  int window = 16;
  int process_commands = 50;
  std::string mosquitto;
  bool nodelay = false;
  app.add_option("--runs", runs, "repetitions (medians of the runs are printed)")->check(CLI::Range(1, 1000));
  app.add_option("--commands", commands, "commands per latency and per throughput measurement")
      ->check(CLI::Range(10, 10000000));
  app.add_option("--window", window, "commands in flight for throughput (one per lamp)")->check(CLI::Range(1, 256));
  app.add_option("--process-commands", process_commands,
                 "commands through mosquitto_pub/mosquitto_sub processes (at most --commands)")
      ->check(CLI::Range(1, 100000));
  app.add_option("--mosquitto", mosquitto, "the broker program (default: mosquitto in PATH or /usr/sbin)");
  app.add_flag("--nodelay", nodelay,
               "no Nagle delays: the broker with set_tcp_nodelay (Debian's default is off) and "
               "mosquitto_pub/sub with --nodelay (the program's own MQTT clients always set TCP_NODELAY)");
  CLI11_PARSE(app, argc, argv);
  process_commands = std::min(process_commands, commands);

  try {
    if (mosquitto.empty()) mosquitto = find_program("mosquitto", "mosquitto");
    if (::access(mosquitto.c_str(), X_OK) != 0) {
      throw std::runtime_error(fmt::format("--mosquitto {}: not an executable program ({})", mosquitto,
                                           std::strerror(errno)));
    }
    const auto sub = find_program("mosquitto_sub", "mosquitto-clients");
    const auto pub = find_program("mosquitto_pub", "mosquitto-clients");
    TempDir dir;
    Broker broker(mosquitto, dir.path(), nodelay);
    Lamps lamps(broker.port(), window);
    MqttPeer peer(broker.port(), window);
    IcarsHome icars(broker.port(), window);
    lamps.start();
    peer.start();
    icars.await_lamps(window);

    std::vector<Row> rows{{"icars call via bridge", {}, {}, {}},
                          {"mqtt client round trip", {}, {}, {}},
                          {"mosquitto_pub/sub processes", {}, {}, {}}};
    // Every command confirmed reached a lamp once: none was acknowledged without it.
    const auto expect_commands = [&](int before, int sent, const std::string& row) {
      if (lamps.commands() - before != sent) {
        throw std::runtime_error(fmt::format("{}: {} commands were confirmed but the lamps received {}", row, sent,
                                             lamps.commands() - before));
      }
    };
    const auto measure = [&](Row& row, const Sender& sender) {
      const int before = lamps.commands();
      const auto ms = latencies(sender, lamps, commands);
      row.median_ms.push_back(percentile(ms, 0.5));
      row.p99_ms.push_back(percentile(ms, 0.99));
      row.per_second.push_back(throughput(sender, lamps, commands));
      expect_commands(before, kWarmUp + 2 * commands, row.name);
    };
    for (int r = 0; r < runs; ++r) {
      measure(rows[0], icars.sender());
      measure(rows[1], peer.sender());
      const int before = lamps.commands();
      const auto ms = process_latencies(sub, pub, broker.port(), nodelay, lamps, process_commands, dir.path());
      rows[2].median_ms.push_back(percentile(ms, 0.5));
      rows[2].p99_ms.push_back(percentile(ms, 0.99));
      rows[2].per_second.push_back(1000 / rows[2].median_ms.back());
      expect_commands(before, process_commands, rows[2].name);
    }
    if (const auto problem = lamps.problem(); !problem.empty()) throw std::runtime_error("the lamps: " + problem);

    fmt::print("{}; ", nodelay ? "no Nagle delays (--nodelay)" : "TCP as Debian's mosquitto sets it up (this program's MQTT clients set TCP_NODELAY)");
    fmt::print("{} runs (medians of the runs); latency: {} commands one at a time ({} through processes); "
               "commands/s: {} commands, {} in flight (processes: 1 / median)\n",
               runs, commands, process_commands, commands, window);
    fmt::print("{:<30} {:>12} {:>10} {:>12} {:>16} {:>18}\n", "", "median (ms)", "p99 (ms)", "commands/s",
               "latency / mqtt", "commands/s / mqtt");
    const auto median_of = [](const std::vector<double>& v) { return icars::bench::stats(v).median; };
    const double mqtt_ms = median_of(rows[1].median_ms);
    const double mqtt_rate = median_of(rows[1].per_second);
    for (const auto& row : rows) {
      const double ms = median_of(row.median_ms);
      const double rate = median_of(row.per_second);
      fmt::print("{:<30} {:>12.3f} {:>10.3f} {:>12.0f} {:>16.2f} {:>18.2f}\n", row.name, ms, median_of(row.p99_ms),
                 rate, ms / mqtt_ms, rate / mqtt_rate);
    }
  } catch (const std::exception& e) {
    fmt::print(stderr, "mqtt_bridge: {}\n", e.what());
    return 1;
  }
  return 0;
}
