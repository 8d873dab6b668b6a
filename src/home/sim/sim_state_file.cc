#include "icars/home/sim/sim_state_file.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <stdexcept>
#include <system_error>

#include "icars/clock/time.h"

namespace icars::home {

namespace {

using nlohmann::json;
constexpr std::string_view kFormat = "icars-sim-state";
constexpr int kVersion = 1;

// What is wrong with a state file; becomes the warning.
struct Invalid : std::runtime_error {
  using std::runtime_error::runtime_error;
};

[[noreturn]] void system_failure(const std::string& what, const std::filesystem::path& path) {
  throw std::system_error(errno, std::generic_category(),
                          fmt::format("{} {}", what, path.string()));
}

// Writes `text` to `path` so that a crash at any instant leaves the old file or the new one:
// a temporary file beside it, fsync, rename over it, fsync of the directory (the rename).
void write_atomically(const std::filesystem::path& path, const std::string& text) {
  const auto tmp = std::filesystem::path(path.string() + ".tmp");
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) system_failure("cannot create", tmp);
  std::size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      const int saved = errno;
      ::close(fd);
      errno = saved;
      system_failure("cannot write", tmp);
    }
    done += static_cast<std::size_t>(n);
  }
  if (::fsync(fd) != 0) {
    const int saved = errno;
    ::close(fd);
    errno = saved;
    system_failure("cannot fsync", tmp);
  }
  if (::close(fd) != 0) system_failure("cannot close", tmp);
  if (::rename(tmp.c_str(), path.c_str()) != 0) system_failure("cannot rename onto", path);
  const auto dir = path.has_parent_path() ? path.parent_path() : std::filesystem::path(".");
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd < 0) system_failure("cannot open the directory", dir);
  const int synced = ::fsync(dfd);
  ::close(dfd);
  if (synced != 0) system_failure("cannot fsync the directory", dir);
}

// A member of `object` as T, or Invalid naming `where` and the key.
template <class T>
T field(const json& object, const char* key, const std::string& where) {
  const auto it = object.find(key);
  if (it == object.end()) throw Invalid(fmt::format("{} has no \"{}\"", where, key));
  try {
    return it->get<T>();
  } catch (const json::exception&) {
    throw Invalid(fmt::format("{}: \"{}\" is {}, expected {}", where, key, it->dump(),
                              std::is_same_v<T, bool>          ? "true or false"
                              : std::is_same_v<T, std::string> ? "a string"
                              : std::is_integral_v<T>          ? "a whole number"
                                                               : "a number"));
  }
}

std::int32_t ranged(const json& object, const char* key, const std::string& where, std::int32_t lo,
                    std::int32_t hi) {
  const auto v = field<std::int64_t>(object, key, where);
  if (v < lo || v > hi) {
    throw Invalid(fmt::format("{}: \"{}\" is {}, expected {} to {}", where, key, v, lo, hi));
  }
  return static_cast<std::int32_t>(v);
}

double number(const json& object, const char* key, const std::string& where) {
  const auto it = object.find(key);
  if (it == object.end() || !it->is_number()) {
    throw Invalid(fmt::format("{}: \"{}\" is {}, expected a number", where, key,
                              it == object.end() ? std::string("missing") : it->dump()));
  }
  return it->get<double>();
}

const json& object_member(const json& object, const char* key, const std::string& where) {
  const auto it = object.find(key);
  if (it == object.end() || !it->is_object()) {
    throw Invalid(fmt::format("{}: \"{}\" is {}, expected an object", where, key,
                              it == object.end() ? std::string("missing") : it->dump()));
  }
  return *it;
}

bool is_kept(const std::string& type) {
  return type == "TV" || type == "Light" || type == "Speaker";
}

}  // namespace

SimStateFile::SimStateFile(std::filesystem::path path, sim::World& world,
                           std::vector<std::string> devices, std::shared_ptr<spdlog::logger> logger,
                           std::chrono::milliseconds min_interval)
    : path_(std::move(path)),
      world_(world),
      devices_(std::move(devices)),
      log_(logger ? std::move(logger)
                  : std::make_shared<spdlog::logger>(
                        "state", std::make_shared<spdlog::sinks::stderr_color_sink_mt>())),
      min_interval_(min_interval) {
  std::sort(devices_.begin(), devices_.end());
  devices_.erase(std::unique(devices_.begin(), devices_.end()), devices_.end());
  for (const auto& id : devices_) {
    const auto* spec = world_.house().device(id);
    if (spec == nullptr) {
      throw std::invalid_argument(fmt::format("state file {}: device \"{}\" is not in house \"{}\"",
                                              path_.string(), id, world_.house().name));
    }
    if (spec->type == "TV") tvs_[id] = {};
    if (spec->type == "Light") lights_[id] = {};
    if (spec->type == "Speaker") speakers_[id] = {};
  }
  load();
  writer_ = std::thread([this] { write_loop(); });
}

SimStateFile::~SimStateFile() {
  commands_.join();  // the commands in progress end (their commits need the writer)
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  writer_.join();
  done_.notify_all();
}

void SimStateFile::load() {
  std::error_code ec;
  if (!std::filesystem::exists(path_, ec)) {
    log_->info("state file {} does not exist yet: the devices start as the house file says",
               path_.string());
    return;
  }
  try {
    std::ifstream in(path_, std::ios::binary);
    if (!in) throw Invalid(fmt::format("cannot be read ({})", std::strerror(errno)));
    std::stringstream text;
    text << in.rdbuf();
    json doc;
    try {
      doc = json::parse(text.str());
    } catch (const json::parse_error& e) {
      throw Invalid(fmt::format("not valid JSON ({}; a truncated or damaged file)", e.what()));
    }
    if (!doc.is_object()) throw Invalid("not a JSON object, expected an icars-sim-state object");
    if (doc.value("format", std::string()) != kFormat) {
      throw Invalid(fmt::format("\"format\" is {}, expected \"{}\"",
                                doc.contains("format") ? doc["format"].dump() : "missing",
                                kFormat));
    }
    if (const auto v = field<std::int64_t>(doc, "version", "the file"); v != kVersion) {
      throw Invalid(fmt::format("version {}, this program reads version {}", v, kVersion));
    }
    const auto house = field<std::string>(doc, "house", "the file");
    if (house != world_.house().name) {
      throw Invalid(fmt::format("written for house \"{}\", this manager runs house \"{}\"", house,
                                world_.house().name));
    }
    const Time at{field<std::int64_t>(doc, "time_ms", "the file")};

    // The devices: exactly the hosted ones, of the same types, with their kept state.
    const json& devices = object_member(doc, "devices", "the file");
    std::vector<std::string> ids;
    for (const auto& [id, value] : devices.items()) ids.push_back(id);
    std::sort(ids.begin(), ids.end());
    if (ids != devices_) {
      std::vector<std::string> missing, extra;
      std::set_difference(devices_.begin(), devices_.end(), ids.begin(), ids.end(),
                          std::back_inserter(missing));
      std::set_difference(ids.begin(), ids.end(), devices_.begin(), devices_.end(),
                          std::back_inserter(extra));
      throw Invalid(fmt::format(
          "written for another set of devices: it lacks [{}] and has [{}] that this manager "
          "does not host (was --devices changed?)",
          fmt::join(missing, ", "), fmt::join(extra, ", ")));
    }
    auto tvs = tvs_;
    auto lights = lights_;
    auto speakers = speakers_;
    for (const auto& id : devices_) {
      const std::string where = fmt::format("device \"{}\"", id);
      const json& d = devices.at(id);
      if (!d.is_object())
        throw Invalid(fmt::format("{} is {}, expected an object", where, d.dump()));
      const auto& type = world_.house().device(id)->type;
      if (const auto t = field<std::string>(d, "type", where); t != type) {
        throw Invalid(
            fmt::format("{} has type \"{}\" in the file, \"{}\" in the house", where, t, type));
      }
      if (type == "TV") {
        tvs[id] = SimTVState{field<bool>(d, "on", where), ranged(d, "channel", where, 1, 99),
                             ranged(d, "volume", where, 0, 100)};
      } else if (type == "Light") {
        lights[id] =
            SimLightState{field<bool>(d, "on", where), ranged(d, "intensity", where, 0, 100)};
      } else if (type == "Speaker") {
        speakers[id] = SimSpeakerState{field<std::string>(d, "playing", where),
                                       ranged(d, "volume", where, 0, 100),
                                       field<std::string>(d, "last_spoken", where)};
      }
    }

    // The robots: every robot of the house, standing or driving, where the house lets it be.
    const json& robots = object_member(doc, "robots", "the file");
    std::map<std::string, sim::RobotState> saved;
    for (const auto& [id, r] : robots.items()) {
      const std::string where = fmt::format("robot \"{}\"", id);
      if (world_.house().robot(id) == nullptr) {
        throw Invalid(fmt::format("{} is not in house \"{}\"", where, world_.house().name));
      }
      if (!r.is_object())
        throw Invalid(fmt::format("{} is {}, expected an object", where, r.dump()));
      sim::RobotState state;
      state.robot = id;
      state.at = at;
      state.pose = {number(r, "x", where), number(r, "y", where), number(r, "heading", where)};
      if (r.contains("path")) {
        const json& path = r["path"];
        if (!path.is_array() || path.size() < 2) {
          throw Invalid(fmt::format("{}: \"path\" is {}, expected at least two [x, y] points",
                                    where, path.dump()));
        }
        for (const auto& p : path) {
          if (!p.is_array() || p.size() != 2 || !p[0].is_number() || !p[1].is_number()) {
            throw Invalid(fmt::format("{}: path point {} is not [x, y]", where, p.dump()));
          }
          state.path.push_back({p[0].get<double>(), p[1].get<double>()});
        }
        state.start = Time{field<std::int64_t>(r, "start_ms", where)};
        if (r.contains("pause_ms")) {  // waiting for a door on the way
          state.pause = Time{field<std::int64_t>(r, "pause_ms", where)};
          state.pause_at = number(r, "pause_at", where);
          if (state.pause.count() < 0 || state.pause_at < 0) {
            throw Invalid(fmt::format("{}: a negative pause ({} ms at {} m)", where, state.pause.count(), state.pause_at));
          }
        }
      }
      try {
        world_.check_robot_state(state);
      } catch (const std::invalid_argument& e) {
        throw Invalid(e.what());
      }
      saved.emplace(id, std::move(state));
    }
    for (const auto& spec : world_.house().robots) {
      if (!saved.contains(spec.id))
        throw Invalid(fmt::format("no entry for robot \"{}\"", spec.id));
    }
    tvs_ = std::move(tvs);
    lights_ = std::move(lights);
    speakers_ = std::move(speakers);
    saved_robots_ = std::move(saved);
    loaded_ = Loaded::restored;
    log_->info("state file {}: restored {} devices and {} robots as of {}", path_.string(),
               tvs_.size() + lights_.size() + speakers_.size(), saved_robots_.size(),
               format_time(at));
  } catch (const Invalid& e) {
    loaded_ = Loaded::rejected;
    rejection_ = e.what();
    const auto aside = std::filesystem::path(path_.string() + ".rejected");
    std::filesystem::rename(path_, aside, ec);
    if (ec) {
      throw std::runtime_error(
          fmt::format("state file {}: {}, and it cannot be moved aside to {}: {}", path_.string(),
                      rejection_, aside.string(), ec.message()));
    }
    log_->warn(
        "state file {}: {}; ignoring it, the devices start as the house file says (the "
        "file is kept as {})",
        path_.string(), rejection_, aside.string());
  }
}

SimTVState SimStateFile::tv(const std::string& id) const {
  std::lock_guard lock(mutex_);
  const auto it = tvs_.find(id);
  if (it == tvs_.end()) throw std::invalid_argument("state file: no hosted TV \"" + id + "\"");
  return it->second;
}

SimLightState SimStateFile::light(const std::string& id) const {
  std::lock_guard lock(mutex_);
  const auto it = lights_.find(id);
  if (it == lights_.end())
    throw std::invalid_argument("state file: no hosted light \"" + id + "\"");
  return it->second;
}

SimSpeakerState SimStateFile::speaker(const std::string& id) const {
  std::lock_guard lock(mutex_);
  const auto it = speakers_.find(id);
  if (it == speakers_.end())
    throw std::invalid_argument("state file: no hosted speaker \"" + id + "\"");
  return it->second;
}

void SimStateFile::on_restore_robot(const std::string& robot, RobotRestorer restore) {
  restorers_[robot] = std::move(restore);
}

void SimStateFile::start() {
  for (const auto& [id, state] : saved_robots_) {
    if (const auto it = restorers_.find(id); it != restorers_.end()) {
      it->second(state);
    } else {
      world_.restore_robot(state);
    }
  }
  restorers_.clear();
  const std::string text = render();
  write_atomically(path_, text);  // throws: an unwritable --state is found at start
  {
    std::lock_guard lock(mutex_);
    started_ = true;
    written_ = version_;
    ++writes_;
    last_write_ = std::chrono::steady_clock::now();
  }
  wake_.notify_all();
}

void SimStateFile::set(const std::string& id, const SimTVState& state) {
  std::lock_guard lock(mutex_);
  tvs_[id] = state;
  ++version_;
}

void SimStateFile::set(const std::string& id, const SimLightState& state) {
  std::lock_guard lock(mutex_);
  lights_[id] = state;
  ++version_;
}

void SimStateFile::set(const std::string& id, const SimSpeakerState& state) {
  std::lock_guard lock(mutex_);
  speakers_[id] = state;
  ++version_;
}

void SimStateFile::commit() {
  std::unique_lock lock(mutex_);
  const auto wanted = ++version_;  // the robots' state counts as changed too
  if (!started_) return;           // start() writes everything
  urgent_ = wanted;
  wake_.notify_all();
  done_.wait(lock, [&] { return written_ >= wanted || stopping_; });
}

void SimStateFile::changed() {
  {
    std::lock_guard lock(mutex_);
    ++version_;
  }
  wake_.notify_all();
}

std::uint64_t SimStateFile::writes() const {
  std::lock_guard lock(mutex_);
  return writes_;
}

std::string SimStateFile::last_error() const {
  std::lock_guard lock(mutex_);
  return error_;
}

std::string SimStateFile::render() const {
  // Robots first, then the devices: a command changes its device's entry before it commits,
  // so the robots are at least as new as the devices in every write.
  const auto robots = world_.robot_states();
  json doc = json::object();
  doc["format"] = kFormat;
  doc["version"] = kVersion;
  doc["house"] = world_.house().name;
  const auto at = robots.empty() ? world_.clock().now() : robots.front().at;
  doc["time_ms"] = at.count();
  doc["time"] = format_time(at);
  json devices = json::object();
  {
    std::lock_guard lock(mutex_);
    for (const auto& id : devices_) {
      const auto& type = world_.house().device(id)->type;
      json d = {{"type", type}};
      if (const auto t = tvs_.find(id); t != tvs_.end()) {
        d["on"] = t->second.on;
        d["channel"] = t->second.channel;
        d["volume"] = t->second.volume;
      } else if (const auto l = lights_.find(id); l != lights_.end()) {
        d["on"] = l->second.on;
        d["intensity"] = l->second.intensity;
      } else if (const auto s = speakers_.find(id); s != speakers_.end()) {
        d["playing"] = s->second.playing;
        d["volume"] = s->second.volume;
        d["last_spoken"] = s->second.last_spoken;
      } else if (is_kept(type)) {
        throw std::logic_error("SimStateFile: no state for device " + id);
      }
      devices[id] = std::move(d);
    }
  }
  doc["devices"] = std::move(devices);
  json rs = json::object();
  for (const auto& r : robots) {
    json j = {{"x", r.pose.x}, {"y", r.pose.y}, {"heading", r.pose.theta}};
    if (r.moving()) {
      json path = json::array();
      for (const auto& p : r.path) path.push_back({p.x, p.y});
      j["path"] = std::move(path);
      j["start_ms"] = r.start.count();
      if (r.pause.count() > 0) {
        j["pause_ms"] = r.pause.count();
        j["pause_at"] = r.pause_at;
      }
    }
    rs[r.robot] = std::move(j);
  }
  doc["robots"] = std::move(rs);
  return doc.dump(2) + "\n";
}

void SimStateFile::write_loop() {
  std::unique_lock lock(mutex_);
  while (true) {
    wake_.wait(lock, [&] { return stopping_ || (started_ && version_ > written_); });
    if (!started_) return;             // stopped before start(): nothing was ever written
    if (version_ == written_) return;  // stopping, nothing left
    if (urgent_ <= written_ && !stopping_) {
      // Only changes nobody waits for: at most one write per min_interval.
      wake_.wait_until(lock, last_write_ + min_interval_,
                       [&] { return stopping_ || urgent_ > written_; });
    }
    const auto target = version_;
    lock.unlock();
    std::string error;
    try {
      write_atomically(path_, render());
    } catch (const std::exception& e) {
      error = e.what();
    }
    lock.lock();
    written_ = target;
    last_write_ = std::chrono::steady_clock::now();
    if (error.empty()) {
      ++writes_;
    } else if (error != error_) {  // each new failure once; the commands stay done in memory
      log_->error("state file {} not written: {}; the devices' state would be lost by a restart",
                  path_.string(), error);
    }
    if (error.empty() && !error_.empty()) log_->info("state file {} written again", path_.string());
    error_ = error;
    done_.notify_all();
  }
}

}  // namespace icars::home
