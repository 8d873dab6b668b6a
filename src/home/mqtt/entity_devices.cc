#include "icars/home/mqtt/entity_devices.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <asio/post.hpp>
#include <asio/redirect_error.hpp>
#include <asio/steady_timer.hpp>
#include <asio/this_coro.hpp>
#include <asio/use_awaitable.hpp>
#include <atomic>
#include <cctype>
#include <charconv>
#include <cmath>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <shared_mutex>
#include <stdexcept>

#include "home.planet.h"
#include "icars/bridge/mqtt/discovery.h"
#include "icars/planet/publisher.h"

namespace icars::home::mqtt {

namespace bm = icars::bridge::mqtt;
namespace p = icars::planet;
using nlohmann::json;

std::string name_of(std::string_view text) {
  std::string name(text);
  for (char& c : name) {
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '_' && c != '-') c = '_';
  }
  return name;
}

namespace {

enum class Kind { light, on_off_switch, occupancy, motion, measurement, cover, fan, climate };

std::string_view type_of(Kind k) {
  switch (k) {
    case Kind::light:
      return "Light";
    case Kind::on_off_switch:
      return "Switch";
    case Kind::occupancy:
      return "Occupancy";
    case Kind::motion:
      return "MotionSensor";
    case Kind::measurement:
      return "MeasurementSensor";
    case Kind::cover:
      return "Cover";
    case Kind::fan:
      return "Fan";
    case Kind::climate:
      return "Climate";
  }
  return "";
}

std::string_view capability_of(Kind k) {
  switch (k) {
    case Kind::light:
      return "light";
    case Kind::on_off_switch:
      return "switch";
    case Kind::occupancy:
      return "occupancy";
    case Kind::motion:
      return "motion";
    case Kind::measurement:
      return "measurement";
    case Kind::cover:
      return "cover";
    case Kind::fan:
      return "fan";
    case Kind::climate:
      return "climate";
  }
  return "";
}

// The device classes of `sensor` entities whose state is a number: the quantity of their
// MeasurementEvents is the device class.
constexpr std::string_view kMeasuredQuantities[] = {"temperature",
                                                    "humidity",
                                                    "illuminance",
                                                    "pressure",
                                                    "atmospheric_pressure",
                                                    "carbon_dioxide",
                                                    "carbon_monoxide",
                                                    "pm1",
                                                    "pm25",
                                                    "pm10",
                                                    "volatile_organic_compounds",
                                                    "power",
                                                    "energy",
                                                    "voltage",
                                                    "current",
                                                    "sound_pressure",
                                                    "battery"};

// The device kind of an entity, or why it has none.
std::optional<Kind> kind_of(const bm::Entity& e, std::string& why) {
  const auto& c = e.where.component;
  if (c == "light") return Kind::light;
  if (c == "switch") return Kind::on_off_switch;
  if (c == "fan") return Kind::fan;
  if (c == "cover") return Kind::cover;
  if (c == "binary_sensor") {
    if (e.device_class == "occupancy" || e.device_class == "presence") return Kind::occupancy;
    if (e.device_class == "motion") return Kind::motion;
    why = fmt::format(
        "a binary_sensor of device_class '{}' has no ICARS interface (occupancy, presence and "
        "motion have); not registered",
        e.device_class);
    return std::nullopt;
  }
  if (c == "sensor") {
    const auto& q = kMeasuredQuantities;
    if (std::find(std::begin(q), std::end(q), e.device_class) != std::end(q)) {
      return Kind::measurement;
    }
    why = fmt::format(
        "a sensor of device_class '{}' has no ICARS interface (these have: {}); not registered",
        e.device_class, fmt::join(std::begin(q), std::end(q), ", "));
    return std::nullopt;
  }
  if (c == "climate") {
    const auto& m = e.modes;
    const bool can_be_off = std::find(m.begin(), m.end(), "off") != m.end();
    const bool can_be_on =
        std::any_of(m.begin(), m.end(), [](const auto& x) { return x != "off"; });
    if (can_be_off && can_be_on) return Kind::climate;
    why = fmt::format(
        "a climate whose modes ({}) lack 'off' or another mode cannot be switched on and off; "
        "not registered",
        fmt::join(m, ", "));
    return std::nullopt;
  }
  why = fmt::format(
      "component '{}' has no ICARS device type yet (light, switch, binary_sensor, sensor, cover, "
      "fan and climate have); not registered",
      c);
  return std::nullopt;
}

// "Living Room" → "living_room".
std::string room_of(std::string_view area) {
  std::string room;
  for (const char c : area)
    room += c == ' ' ? '_' : static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return room;
}

std::optional<int> parse_int(std::string_view s) {
  while (!s.empty() && s.front() == ' ') s.remove_prefix(1);
  while (!s.empty() && s.back() == ' ') s.remove_suffix(1);
  int v = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || end != s.data() + s.size()) return std::nullopt;
  return v;
}

// A reading: a finite number, with spaces around it allowed.
std::optional<double> parse_number(std::string_view s) {
  while (!s.empty() && s.front() == ' ') s.remove_prefix(1);
  while (!s.empty() && s.back() == ' ') s.remove_suffix(1);
  double v = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || end != s.data() + s.size() || !std::isfinite(v)) return std::nullopt;
  return v;
}

// The value a JSON path picks, as text (strings as they are, numbers and booleans as JSON
// writes them, as discovery reads payload_on/payload_off); nullopt with `error` set otherwise.
std::optional<std::string> pick(const json& j, const std::vector<std::string>& path,
                                std::string& error) {
  const json* at = &j;
  for (const auto& key : path) {
    if (!at->is_object() || !at->contains(key)) {
      error = fmt::format("the state has no '{}' (the entity reads value_json.{})", key,
                          fmt::join(path, "."));
      return std::nullopt;
    }
    at = &(*at)[key];
  }
  if (at->is_object() || at->is_array() || at->is_null()) {
    error = fmt::format("value_json.{} is {}, not a value", fmt::join(path, "."), at->type_name());
    return std::nullopt;
  }
  return at->is_string() ? at->get<std::string>() : at->dump();
}

// A sensor capability's value and its listeners; an event for every change.
class OccupancyCapability final : public home::OccupancySensorServant {
 public:
  OccupancyCapability(std::string device, std::string furniture, std::function<std::int64_t()> now)
      : device_(std::move(device)), furniture_(std::move(furniture)), now_(std::move(now)) {}
  bool occupied(const p::Current&) override { return occupied_.load(); }
  std::string furniture(const p::Current&) override { return furniture_; }
  void subscribe(home::OccupancyListenerPrx l, const p::Current&) override { events_.subscribe(l); }
  void unsubscribe(home::OccupancyListenerPrx l, const p::Current&) override {
    events_.unsubscribe(l);
  }
  void update(bool occupied) {
    if (occupied_.exchange(occupied) == occupied) return;
    events_.publish(home::OccupancyEvent{device_, furniture_, occupied, now_()});
  }

 private:
  std::string device_;
  std::string furniture_;
  std::function<std::int64_t()> now_;
  std::atomic<bool> occupied_{false};
  p::Publisher<home::OccupancyEvent> events_{home::OccupancyListener::on_occupancy};
};

class MotionCapability final : public home::MotionSensorServant {
 public:
  MotionCapability(std::string device, std::string room, std::function<std::int64_t()> now)
      : device_(std::move(device)), room_(std::move(room)), now_(std::move(now)) {}
  bool motion(const p::Current&) override { return motion_.load(); }
  void subscribe(home::MotionListenerPrx l, const p::Current&) override { events_.subscribe(l); }
  void unsubscribe(home::MotionListenerPrx l, const p::Current&) override {
    events_.unsubscribe(l);
  }
  void update(bool motion) {
    if (motion_.exchange(motion) == motion) return;
    events_.publish(home::MotionEvent{device_, room_, motion, now_()});
  }

 private:
  std::string device_;
  std::string room_;
  std::function<std::int64_t()> now_;
  std::atomic<bool> motion_{false};
  p::Publisher<home::MotionEvent> events_{home::MotionListener::on_motion};
};

class MeasurementCapability final : public home::MeasurementSensorServant {
 public:
  // `no_reading`: the message value() fails with before the first reading.
  MeasurementCapability(std::string device, std::string quantity, std::string unit,
                        std::string room, std::string no_reading, std::function<std::int64_t()> now)
      : device_(std::move(device)),
        quantity_(std::move(quantity)),
        unit_(std::move(unit)),
        room_(std::move(room)),
        no_reading_(std::move(no_reading)),
        now_(std::move(now)) {}
  double value(const p::Current&) override {
    std::lock_guard lock(mutex_);
    if (!value_) throw p::Error(p::ErrorKind::failed, no_reading_);
    return *value_;
  }
  std::string quantity(const p::Current&) override { return quantity_; }
  std::string unit(const p::Current&) override { return unit_; }
  void subscribe(home::MeasurementListenerPrx l, const p::Current&) override {
    events_.subscribe(l);
  }
  void unsubscribe(home::MeasurementListenerPrx l, const p::Current&) override {
    events_.unsubscribe(l);
  }
  void update(double value) {
    {
      std::lock_guard lock(mutex_);
      if (value_ == value) return;
      value_ = value;
    }
    events_.publish(home::MeasurementEvent{device_, quantity_, value, unit_, room_, now_()});
  }

 private:
  std::string device_;
  std::string quantity_;
  std::string unit_;
  std::string room_;
  std::string no_reading_;
  std::function<std::int64_t()> now_;
  std::mutex mutex_;
  std::optional<double> value_;
  p::Publisher<home::MeasurementEvent> events_{home::MeasurementListener::on_measurement};
};

enum class CoverCommand { open, close, stop };

// The state a command asks for.
struct Wanted {
  bool on = false;                    // a light, switch, fan or climate
  std::optional<int> brightness;      // on the entity's brightness scale
  std::optional<CoverCommand> cover;  // a cover's command (`on` means nothing then)
};

// A command waiting on the io thread for its entity's state topic to confirm it.
struct Waiter {
  explicit Waiter(const asio::any_io_executor& executor) : timer(executor) {}
  asio::steady_timer timer;  // cancelled (on its executor) when the waiter is settled
  Wanted wanted;
  // Under Core::mutex_:
  bool settled = false;
  bool confirmed = false;
  std::string failure;  // set: why the command failed before its confirmation came
};

struct Publish {
  std::string topic;
  std::string payload;
};

}  // namespace

class MqttDevices::Core : public std::enable_shared_from_this<Core> {
 public:
  Core(bm::Client& client, device::DeviceManager& manager, MqttDevicesOptions options)
      : client_(client), manager_(manager), options_(std::move(options)) {
    if (!options_.now_ms) {
      options_.now_ms = [] {
        return static_cast<std::int64_t>(std::chrono::duration_cast<std::chrono::milliseconds>(
                                             std::chrono::system_clock::now().time_since_epoch())
                                             .count());
      };
    }
    log_ = options_.logger
               ? options_.logger
               : std::make_shared<spdlog::logger>(
                     "mqtt-devices", std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
    if (options_.command_timeout <= std::chrono::milliseconds::zero()) {
      throw std::invalid_argument("mqtt devices: command_timeout must be positive");
    }
  }

  void start() {
    client_.on_message([self = shared_from_this()](const bm::Message& m) { self->on_message(m); });
    client_.subscribe(options_.discovery_prefix + "/+/+/config");
    client_.subscribe(options_.discovery_prefix + "/+/+/+/config");
  }

  // After it, no message is handled and every command fails; waiting commands fail now.
  void close() {
    std::unique_lock alive(alive_mutex_);
    closed_ = true;
    std::lock_guard lock(mutex_);
    for (auto& [id, record] : entities_) fail_waiters(record, "the MQTT bridge is closed");
  }

  std::vector<EntityDevice> devices() const {
    std::lock_guard lock(mutex_);
    std::vector<EntityDevice> out;
    for (const auto& [id, r] : entities_) {
      out.push_back(EntityDevice{id, r.device_id, std::string(type_of(r.kind)), r.room,
                                 r.entity.config_topic, r.online});
    }
    return out;
  }

  std::vector<std::string> problems() const {
    std::lock_guard lock(problems_mutex_);
    return problems_;
  }

  // --- The capabilities' operations ----------------------------------------------------------

  static asio::awaitable<void> command(std::shared_ptr<Core> self, std::string unique_id,
                                       Wanted wanted, std::string what);

  home::LightState light_state(const std::string& unique_id) const {
    std::lock_guard lock(mutex_);
    const auto& r = entities_.at(unique_id);
    const bool on = r.on.value_or(false);
    if (dimmable(r) && r.brightness) {
      return home::LightState{on, static_cast<std::int32_t>(std::lround(
                                      *r.brightness * 100.0 / r.entity.brightness_scale))};
    }
    return home::LightState{on, on ? 100 : 0};
  }

  home::CoverState cover_state(const std::string& unique_id) const {
    std::lock_guard lock(mutex_);
    return home::CoverState{entities_.at(unique_id).position};
  }

  bool power_on(const std::string& unique_id) const {
    std::lock_guard lock(mutex_);
    return entities_.at(unique_id).on.value_or(false);
  }

  // What set_intensity(percent) asks for, or OutOfRange.
  Wanted intensity(const std::string& unique_id, std::int32_t percent) const {
    std::lock_guard lock(mutex_);
    const auto& r = entities_.at(unique_id);
    if (percent < 0 || percent > 100) {
      throw home::OutOfRange("intensity", percent, 0, 100,
                             fmt::format("{}: intensity {} is outside 0..100", label(r), percent));
    }
    if (!dimmable(r)) {
      if (percent != 0 && percent != 100) {
        throw home::OutOfRange(
            "intensity", percent, 0, 100,
            fmt::format("{}: intensity {} cannot be set: it is on/off only (0 turns it off, 100 "
                        "on)",
                        label(r), percent));
      }
      return Wanted{percent == 100, std::nullopt, std::nullopt};
    }
    if (percent == 0) return Wanted{false, std::nullopt, std::nullopt};
    const int scale = r.entity.brightness_scale;
    return Wanted{true, std::max(1, static_cast<int>(std::lround(percent * scale / 100.0))),
                  std::nullopt};
  }

 private:
  struct Record {
    bm::Entity entity;
    std::string config;  // the config's payload: a repeat changes nothing
    Kind kind = Kind::light;
    std::string device_id;
    std::string room;
    bool removed = false;  // its config was removed
    std::optional<bool> on;
    std::optional<int> brightness;
    std::string position = "unknown";  // a cover's, as CoverState says it
    std::string on_mode;               // the non-off mode a climate last reported
    std::map<std::string, std::string> availability_said;  // topic → last payload
    std::string latest_availability;                       // the topic heard last
    bool online = false;                                   // as told to the device manager
    std::vector<std::shared_ptr<Waiter>> waiters;
    std::shared_ptr<OccupancyCapability> occupancy;
    std::shared_ptr<MotionCapability> motion;
    std::shared_ptr<MeasurementCapability> measurement;
  };

  static std::string label(const Record& r) {
    return fmt::format("{} '{}' ({})", r.entity.where.component, r.entity.name, r.entity.unique_id);
  }
  static bool dimmable(const Record& r) {
    return r.kind == Kind::light && r.entity.brightness &&
           (r.entity.schema == "json" || !r.entity.brightness_command_topic.empty());
  }
  static bool reports_brightness(const Record& r) {
    return dimmable(r) && (r.entity.schema == "json" || !r.entity.brightness_state_topic.empty());
  }

  // Logs a problem once. Bounded: a device that keeps sending new kinds of nonsense cannot
  // grow the bridge's memory; past kMaxProblems, problems are counted and logged every 1000th.
  void problem(const std::string& what) {
    std::uint64_t dropped = 0;
    {
      std::lock_guard lock(problems_mutex_);
      if (problems_seen_.contains(what)) return;
      if (problems_seen_.size() >= kMaxProblems) {
        dropped = ++problems_dropped_;
      } else {
        problems_seen_.insert(what);
        problems_.push_back(what);
      }
    }
    if (dropped == 0) {
      log_->warn("{}", what);
    } else if (dropped % 1000 == 1) {
      log_->warn("{} (and {} more problems after the first {}, not kept)", what, dropped - 1,
                 kMaxProblems);
    }
  }

  void on_message(const bm::Message& m) {
    {
      std::shared_lock alive(alive_mutex_);
      if (!closed_) {
        try {
          if (bm::parse_discovery_topic(m.topic, options_.discovery_prefix)) {
            on_config(m);
          } else {
            on_state(m);
          }
        } catch (const std::exception& e) {
          // Never lost silently; the bridge goes on with the next message.
          problem(fmt::format("{}: {}", m.topic, e.what()));
        }
      }
    }
    if (options_.handled) options_.handled(m);
  }

  // --- Discovery -----------------------------------------------------------------------------

  void on_config(const bm::Message& m) {
    const auto result = bm::read_discovery(m.topic, m.payload, options_.discovery_prefix);
    if (result.removed) {
      remove(m.topic);
      return;
    }
    if (!result.error.empty()) {
      problem(result.error + "; not registered");
      return;
    }
    const bm::Entity& e = *result.entity;
    std::string why;
    const auto kind = kind_of(e, why);
    if (!kind) {
      problem(fmt::format("{}: {}", m.topic, why));
      return;
    }
    std::vector<std::pair<std::string, bool>> changes;
    {
      std::lock_guard lock(mutex_);
      const auto it = entities_.find(e.unique_id);
      if (it != entities_.end()) {
        Record& r = it->second;
        if (r.kind != *kind) {
          problem(fmt::format("{}: {} is now a {}; it stays a {} device until the bridge restarts",
                              m.topic, label(r), type_of(*kind), type_of(r.kind)));
          return;
        }
        if (r.config != m.payload) {
          r.entity = e;
          r.config = m.payload;
          apply_cached(r, changes);
        }
        r.removed = false;
        update_online(r, changes);
      }
    }
    if (entities_contains(e.unique_id)) {
      tell_manager(changes);
      subscribe_topics(e);
      return;
    }
    add(m, e, *kind);
  }

  bool entities_contains(const std::string& unique_id) const {
    std::lock_guard lock(mutex_);
    return entities_.contains(unique_id);
  }

  void add(const bm::Message& m, const bm::Entity& e, Kind kind) {
    Record r;
    r.entity = e;
    r.config = m.payload;
    r.kind = kind;
    std::string furniture;
    if (const auto place = options_.placements.find(e.unique_id);
        place != options_.placements.end()) {
      r.device_id =
          place->second.device_id.empty() ? name_of(e.unique_id) : place->second.device_id;
      r.room = place->second.room.empty() ? room_of(e.area) : place->second.room;
      furniture = place->second.furniture;
    } else {
      r.device_id = name_of(e.unique_id);
      r.room = room_of(e.area);
    }
    std::shared_ptr<device::Device> device;
    try {
      device = std::make_shared<device::Device>(r.device_id, std::string(type_of(kind)), r.room);
      device->add(std::string(capability_of(kind)), make_capability(r, furniture));
    } catch (const std::invalid_argument& error) {
      problem(fmt::format("{}: {}; not registered", m.topic, error.what()));
      return;
    }
    bool online = false;
    {
      std::lock_guard lock(mutex_);
      for (const auto& [id, other] : entities_) {
        if (other.device_id == r.device_id) {
          problem(fmt::format("{}: device id '{}' is taken by {}; not registered", m.topic,
                              r.device_id, label(other)));
          return;
        }
      }
      Record& added = entities_.emplace(e.unique_id, std::move(r)).first->second;
      std::vector<std::pair<std::string, bool>> ignored;
      apply_cached(added, ignored);
      added.online = available(added, nullptr);
      online = added.online;
    }
    try {
      manager_.add(device, online);
    } catch (const std::invalid_argument& error) {
      std::lock_guard lock(mutex_);
      entities_.erase(e.unique_id);
      problem(fmt::format("{}: {}; not registered", m.topic, error.what()));
      return;
    }
    log_->info("{}: {} '{}' as device {} ({}) in room '{}'{}", m.topic, e.where.component, e.name,
               device->id(), device->type(), device->room(), online ? "" : ", offline for now");
    subscribe_topics(e);
  }

  std::shared_ptr<p::Servant> make_capability(Record& r, const std::string& furniture) {
    switch (r.kind) {
      case Kind::occupancy: {
        auto c = std::make_shared<OccupancyCapability>(r.device_id, furniture, options_.now_ms);
        r.occupancy = c;
        return c;
      }
      case Kind::motion: {
        auto c = std::make_shared<MotionCapability>(r.device_id, r.room, options_.now_ms);
        r.motion = c;
        return c;
      }
      case Kind::measurement: {
        auto c = std::make_shared<MeasurementCapability>(
            r.device_id, r.entity.device_class, r.entity.unit, r.room,
            fmt::format("{}: no reading yet on '{}'", label(r), r.entity.state_topic),
            options_.now_ms);
        r.measurement = c;
        return c;
      }
      case Kind::cover:
        return make_cover(r);
      case Kind::fan:
      case Kind::climate:
        return make_power_switch(r);
      case Kind::light:
      case Kind::on_off_switch:
        break;
    }
    auto servant = std::make_shared<p::Servant>(std::string(home::Light::type_id));
    const std::weak_ptr<Core> weak = weak_from_this();
    const std::string id = r.entity.unique_id;
    servant->implement(home::Light::set_power, [weak, id](bool on) {
      return command(alive(weak), id, Wanted{on, std::nullopt, std::nullopt},
                     on ? "turn it on" : "turn it off");
    });
    servant->implement(home::Light::set_intensity, [weak, id](std::int32_t percent) {
      auto self = alive(weak);
      const Wanted wanted = self->intensity(id, percent);
      return command(std::move(self), id, wanted, fmt::format("set its intensity to {}%", percent));
    });
    servant->implement(home::Light::state, [weak, id]() { return alive(weak)->light_state(id); });
    return servant;
  }

  std::shared_ptr<p::Servant> make_cover(const Record& r) {
    auto servant = std::make_shared<p::Servant>(std::string(home::Cover::type_id));
    const std::weak_ptr<Core> weak = weak_from_this();
    const std::string id = r.entity.unique_id;
    const auto send = [weak, id](CoverCommand c, std::string what) {
      return command(alive(weak), id, Wanted{false, std::nullopt, c}, std::move(what));
    };
    servant->implement(home::Cover::open, [send]() { return send(CoverCommand::open, "open it"); });
    servant->implement(home::Cover::close,
                       [send]() { return send(CoverCommand::close, "close it"); });
    servant->implement(home::Cover::stop, [send]() { return send(CoverCommand::stop, "stop it"); });
    servant->implement(home::Cover::state, [weak, id]() { return alive(weak)->cover_state(id); });
    return servant;
  }

  std::shared_ptr<p::Servant> make_power_switch(const Record& r) {
    auto servant = std::make_shared<p::Servant>(std::string(home::PowerSwitch::type_id));
    const std::weak_ptr<Core> weak = weak_from_this();
    const std::string id = r.entity.unique_id;
    servant->implement(home::PowerSwitch::set_power, [weak, id](bool on) {
      return command(alive(weak), id, Wanted{on, std::nullopt, std::nullopt},
                     on ? "turn it on" : "turn it off");
    });
    servant->implement(home::PowerSwitch::on, [weak, id]() { return alive(weak)->power_on(id); });
    return servant;
  }

  static std::shared_ptr<Core> alive(const std::weak_ptr<Core>& weak) {
    auto self = weak.lock();
    if (!self) throw p::Error(p::ErrorKind::failed, "the MQTT bridge is closed");
    return self;
  }

  void subscribe_topics(const bm::Entity& e) {
    std::vector<std::string> topics{e.state_topic, e.brightness_state_topic};
    for (const auto& a : e.availability) topics.push_back(a.topic);
    for (const auto& t : topics) {
      if (t.empty()) continue;
      {
        std::lock_guard lock(mutex_);
        if (!subscribed_.insert(t).second) continue;
      }
      client_.subscribe(t);
    }
  }

  // An empty config: the entity is gone, so its device leaves the server.
  void remove(const std::string& config_topic) {
    std::vector<std::pair<std::string, bool>> changes;
    {
      std::lock_guard lock(mutex_);
      for (auto& [id, r] : entities_) {
        if (r.entity.config_topic != config_topic || r.removed) continue;
        r.removed = true;
        r.config.clear();
        update_online(r, changes);
      }
    }
    tell_manager(changes);
  }

  // --- State and availability ----------------------------------------------------------------

  void on_state(const bm::Message& m) {
    std::vector<std::pair<std::string, bool>> changes;
    {
      std::lock_guard lock(mutex_);
      last_payload_[m.topic] = m.payload;
      for (auto& [id, r] : entities_) apply(r, m.topic, m.payload, changes);
    }
    tell_manager(changes);
  }

  void tell_manager(const std::vector<std::pair<std::string, bool>>& changes) {
    for (const auto& [device_id, online] : changes) manager_.set_online(device_id, online);
  }

  // Applies what the topics of a new or changed entity said before it was known to this bridge.
  void apply_cached(Record& r, std::vector<std::pair<std::string, bool>>& changes) {
    std::vector<std::string> topics{r.entity.state_topic, r.entity.brightness_state_topic};
    for (const auto& a : r.entity.availability) topics.push_back(a.topic);
    for (const auto& t : topics) {
      if (t.empty()) continue;
      if (const auto it = last_payload_.find(t); it != last_payload_.end())
        apply(r, t, it->second, changes);
    }
  }

  // Under mutex_.
  void apply(Record& r, const std::string& topic, const std::string& payload,
             std::vector<std::pair<std::string, bool>>& changes) {
    const auto& e = r.entity;
    bool state_changed = false;
    if (topic == e.state_topic) state_changed |= read_state(r, topic, payload);
    if (topic == e.brightness_state_topic) {
      const auto b = parse_int(payload);
      if (!b || *b < 0 || *b > e.brightness_scale) {
        problem(fmt::format("{}: brightness '{}' of {} is not a whole number in 0..{}; ignored",
                            topic, payload, label(r), e.brightness_scale));
      } else {
        r.brightness = *b;
        state_changed = true;
      }
    }
    bool availability_heard = false;
    for (const auto& a : e.availability) {
      if (a.topic != topic) continue;
      std::string value = payload;
      if (!a.value_template.empty()) {
        const auto path = bm::value_template_path(a.value_template);
        std::string error;
        std::optional<std::string> picked;
        if (path && !path->empty()) {
          const json j = json::parse(payload, nullptr, false);
          if (j.is_discarded()) {
            error = "the availability is not JSON";
          } else {
            picked = pick(j, *path, error);
          }
        } else if (path) {
          picked = payload;
        } else {
          error = fmt::format("value_template '{}' is not one ICARS follows", a.value_template);
        }
        if (!picked) {
          problem(fmt::format("{}: availability of {}: {}; ignored", topic, label(r), error));
          continue;
        }
        value = *picked;
      }
      if (value != a.payload_available && value != a.payload_not_available) {
        problem(fmt::format("{}: availability '{}' of {} is neither '{}' nor '{}'; ignored", topic,
                            value, label(r), a.payload_available, a.payload_not_available));
        continue;
      }
      r.availability_said[topic] = value;
      r.latest_availability = topic;
      availability_heard = true;
    }
    if (state_changed) settle(r);
    if (availability_heard) update_online(r, changes);
  }

  // Reads a state topic's payload; false (and logged once) when it contradicts the schema.
  bool read_state(Record& r, const std::string& topic, const std::string& payload) {
    const auto& e = r.entity;
    std::string error;
    std::optional<std::string> value;
    std::optional<int> brightness;
    if (e.value_path.empty()) {
      value = payload;
    } else {
      const json j = json::parse(payload, nullptr, false);
      if (j.is_discarded()) {
        error = fmt::format("the state is not JSON (the entity reads value_json.{})",
                            fmt::join(e.value_path, "."));
      } else {
        value = pick(j, e.value_path, error);
        if (value && r.kind == Kind::light && e.schema == "json" && e.brightness) {
          if (const auto b = j.find("brightness"); b != j.end() && !b->is_null()) {
            if (!b->is_number() || b->get<double>() < 0 || b->get<double>() > e.brightness_scale) {
              error = fmt::format("brightness {} is not a number in 0..{}", b->dump(),
                                  e.brightness_scale);
              value.reset();
            } else {
              brightness = static_cast<int>(std::lround(b->get<double>()));
            }
          }
        }
      }
    }
    if (value) {
      error = take(r, *value, brightness);
      if (!error.empty()) value.reset();
    }
    if (!value) {
      problem(fmt::format("{}: state of {} ignored: {}", topic, label(r), error));
      return false;
    }
    return true;
  }

  // Under mutex_: the entity takes the state its state topic reported; or, when the state
  // contradicts its config, nothing changes and the reason is returned.
  static std::string take(Record& r, const std::string& value, std::optional<int> brightness) {
    const auto& e = r.entity;
    switch (r.kind) {
      case Kind::measurement: {
        const auto v = parse_number(value);
        if (!v) return fmt::format("'{}' is not a number", value);
        r.measurement->update(*v);
        return "";
      }
      case Kind::cover: {
        const std::pair<const std::string&, const char*> positions[] = {
            {e.state_open, "open"},
            {e.state_closed, "closed"},
            {e.state_opening, "opening"},
            {e.state_closing, "closing"},
            {e.state_stopped, "stopped"}};
        for (const auto& [said, position] : positions) {
          if (value == said) {
            r.position = position;
            return "";
          }
        }
        return fmt::format(
            "'{}' is none of '{}' (open), '{}' (closed), '{}' (opening), '{}' "
            "(closing) and '{}' (stopped)",
            value, e.state_open, e.state_closed, e.state_opening, e.state_closing, e.state_stopped);
      }
      case Kind::climate:
        if (value == "off") {
          r.on = false;
        } else if (std::find(e.modes.begin(), e.modes.end(), value) != e.modes.end()) {
          r.on = true;
          r.on_mode = value;
        } else {
          return fmt::format("mode '{}' is none of its modes ({})", value,
                             fmt::join(e.modes, ", "));
        }
        return "";
      case Kind::light:
      case Kind::on_off_switch:
      case Kind::occupancy:
      case Kind::motion:
      case Kind::fan:
        break;
    }
    bool on = false;
    if (value == e.state_on) {
      on = true;
    } else if (value != e.state_off) {
      return fmt::format("'{}' is neither '{}' (on) nor '{}' (off)", value, e.state_on,
                         e.state_off);
    }
    r.on = on;
    if (brightness) r.brightness = brightness;
    if (r.occupancy) r.occupancy->update(on);
    if (r.motion) r.motion->update(on);
    return "";
  }

  // Under mutex_: the mode a climate is switched on in: the one it last ran in, or else the
  // first of its modes other than "off" (kind_of made sure there is one).
  static std::string on_mode(const Record& r) {
    if (!r.on_mode.empty()) return r.on_mode;
    for (const auto& m : r.entity.modes) {
      if (m != "off") return m;
    }
    return "";
  }

  // Under mutex_: whether the entity may be used, and if not, why.
  static bool available(const Record& r, std::string* why) {
    const auto said = [&](const bm::Availability& a) -> std::string {
      const auto it = r.availability_said.find(a.topic);
      return it == r.availability_said.end()
                 ? fmt::format("nothing heard yet on availability topic '{}'", a.topic)
                 : fmt::format("availability topic '{}' says '{}'", a.topic, it->second);
    };
    const auto is_online = [&](const bm::Availability& a) {
      const auto it = r.availability_said.find(a.topic);
      return it != r.availability_said.end() && it->second == a.payload_available;
    };
    const auto& list = r.entity.availability;
    if (r.removed) {
      if (why) *why = "its discovery config was removed";
      return false;
    }
    if (list.empty()) return true;
    const std::string& mode = r.entity.availability_mode;
    if (mode == "all") {
      for (const auto& a : list) {
        if (!is_online(a)) {
          if (why) *why = said(a);
          return false;
        }
      }
      return true;
    }
    if (mode == "any") {
      if (std::any_of(list.begin(), list.end(), is_online)) return true;
      if (why) *why = said(list.front());
      return false;
    }
    for (const auto& a : list) {  // latest
      if (a.topic == r.latest_availability) {
        if (!is_online(a) && why) *why = said(a);
        return is_online(a);
      }
    }
    if (why) *why = said(list.front());
    return false;
  }

  // Under mutex_: tells the manager (through `changes`) when the entity came or went.
  void update_online(Record& r, std::vector<std::pair<std::string, bool>>& changes) {
    std::string why;
    const bool now = available(r, &why);
    if (now == r.online) return;
    r.online = now;
    changes.emplace_back(r.device_id, now);
    if (now) {
      log_->info("{} is online: device {} registered", label(r), r.device_id);
    } else {
      log_->warn("{} is offline ({}): device {} unregistered", label(r), why, r.device_id);
      fail_waiters(r, fmt::format("it went offline ({})", why));
    }
  }

  static bool satisfied(const Record& r, const Wanted& w) {
    if (w.cover) {
      // Open and close are done once the cover moves that way; a stop once it does not move.
      switch (*w.cover) {
        case CoverCommand::open:
          return r.position == "open" || r.position == "opening";
        case CoverCommand::close:
          return r.position == "closed" || r.position == "closing";
        case CoverCommand::stop:
          return r.position == "open" || r.position == "closed" || r.position == "stopped";
      }
    }
    if (r.on != w.on) return false;
    if (!w.brightness || !reports_brightness(r)) return true;
    if (!r.brightness) return false;
    const int tolerance = std::max(1, r.entity.brightness_scale / 100);
    return std::abs(*r.brightness - *w.brightness) <= tolerance;
  }

  static void wake(const std::shared_ptr<Waiter>& w) {
    asio::post(w->timer.get_executor(), [w] { w->timer.cancel(); });
  }

  // Under mutex_: the commands the entity's state now confirms.
  static void settle(Record& r) {
    for (const auto& w : r.waiters) {
      if (w->settled || !satisfied(r, w->wanted)) continue;
      w->settled = w->confirmed = true;
      wake(w);
    }
  }

  static void fail_waiters(Record& r, const std::string& why) {
    for (const auto& w : r.waiters) {
      if (w->settled) continue;
      w->settled = true;
      w->failure = why;
      wake(w);
    }
  }

  bm::Client& client_;
  device::DeviceManager& manager_;
  MqttDevicesOptions options_;
  std::shared_ptr<spdlog::logger> log_;

  std::shared_mutex alive_mutex_;  // held shared while a message is handled
  bool closed_ = false;

  mutable std::mutex mutex_;
  std::map<std::string, Record> entities_;           // by unique id
  std::map<std::string, std::string> last_payload_;  // state and availability topics
  std::set<std::string> subscribed_;

  static constexpr std::size_t kMaxProblems = 1024;
  mutable std::mutex problems_mutex_;
  std::set<std::string> problems_seen_;
  std::vector<std::string> problems_;
  std::uint64_t problems_dropped_ = 0;
};

asio::awaitable<void> MqttDevices::Core::command(std::shared_ptr<Core> self, std::string unique_id,
                                                 Wanted wanted, std::string what) {
  // In lock-step, the simulated clock waits while the device confirms (on the wall clock).
  const Activity::Hold busy(self->options_.activity.get());
  const auto executor = co_await asio::this_coro::executor;
  auto waiter = std::make_shared<Waiter>(executor);
  waiter->wanted = wanted;
  std::vector<Publish> messages;
  std::string label;
  std::string state_topic;
  std::string command_topic;
  {
    std::shared_lock alive(self->alive_mutex_);
    if (self->closed_) throw p::Error(p::ErrorKind::failed, "the MQTT bridge is closed");
    std::lock_guard lock(self->mutex_);
    Record& r = self->entities_.at(unique_id);
    const auto& e = r.entity;
    label = Core::label(r);
    state_topic = e.state_topic;
    command_topic = e.command_topic;
    if (!r.online) {
      std::string why;
      available(r, &why);
      throw p::Error(p::ErrorKind::failed,
                     fmt::format("{}: cannot {}: it is offline ({}); nothing sent to '{}'", label,
                                 what, why, command_topic));
    }
    if (wanted.cover) {
      const auto c = *wanted.cover;
      messages.push_back({command_topic, c == CoverCommand::open    ? e.payload_open
                                         : c == CoverCommand::close ? e.payload_close
                                                                    : e.payload_stop});
    } else if (r.kind == Kind::climate) {
      messages.push_back({command_topic, wanted.on ? on_mode(r) : std::string("off")});
    } else if (e.schema == "json") {
      json command = {{"state", wanted.on ? "ON" : "OFF"}};
      if (wanted.brightness) command["brightness"] = *wanted.brightness;
      messages.push_back({command_topic, command.dump()});
    } else {
      if (wanted.brightness)
        messages.push_back({e.brightness_command_topic, std::to_string(*wanted.brightness)});
      messages.push_back({command_topic, wanted.on ? e.payload_on : e.payload_off});
    }
    if (!state_topic.empty()) r.waiters.push_back(waiter);
  }
  const auto forget = [&] {
    std::lock_guard lock(self->mutex_);
    if (const auto it = self->entities_.find(unique_id); it != self->entities_.end()) {
      std::erase(it->second.waiters, waiter);
    }
  };
  for (const auto& m : messages) {
    try {
      self->client_.publish(m.topic, m.payload);
    } catch (const bm::Error& error) {
      forget();
      throw p::Error(p::ErrorKind::failed,
                     fmt::format("{}: cannot {}: {}", label, what, error.what()));
    }
  }
  if (state_topic.empty()) co_return;  // optimistic: nothing can confirm it

  const auto timeout = self->options_.command_timeout;
  waiter->timer.expires_after(timeout);
  bool settled = false;
  {
    std::lock_guard lock(self->mutex_);
    settled = waiter->settled;
  }
  if (!settled) {
    // Ends at the timeout, or earlier when the state topic confirms (or the entity goes offline).
    std::error_code ignored;
    co_await waiter->timer.async_wait(asio::redirect_error(asio::use_awaitable, ignored));
  }
  forget();
  std::lock_guard lock(self->mutex_);
  if (waiter->confirmed) co_return;
  if (!waiter->failure.empty()) {
    throw p::Error(p::ErrorKind::failed,
                   fmt::format("{}: {} was sent to '{}' but {} before '{}' confirmed it", label,
                               what, command_topic, waiter->failure, state_topic));
  }
  const auto message = fmt::format(
      "{}: no confirmation on '{}' within {} ms of the command to '{}' ({}); the "
      "device may be unreachable or refused it",
      label, state_topic, timeout.count(), command_topic, what);
  self->log_->warn("{}", message);
  throw p::Error(p::ErrorKind::timeout, message);
}

MqttDevices::MqttDevices(bm::Client& client, device::DeviceManager& manager,
                         MqttDevicesOptions options)
    : core_(std::make_shared<Core>(client, manager, std::move(options))) {
  core_->start();
}

MqttDevices::~MqttDevices() { core_->close(); }

std::vector<EntityDevice> MqttDevices::devices() const { return core_->devices(); }

std::vector<std::string> MqttDevices::problems() const { return core_->problems(); }

}  // namespace icars::home::mqtt
