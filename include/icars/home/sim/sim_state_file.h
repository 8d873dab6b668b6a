// The state file of a device manager's simulated devices: what a real device keeps through a
// software restart — a TV's power, channel and volume, a light's power and intensity, a
// speaker's track, volume and last words, every robot's pose or the motion it is driving — so
// that `icars-device-manager --state FILE`, killed and restarted, brings its house back as it
// was (docs/house.md, "State file"). Sensors are not kept: they follow the simulated users,
// whose schedule runs on the clock (--epoch).
//
// Writes are atomic (a temporary file beside it, fsync, rename, fsync of the directory), so a
// crash at any instant leaves the old or the new file, never a torn one. A command's state is
// on disk before commit() returns, which the devices call before they reply; concurrent
// commits share one write. Changes nobody waits for (a robot arriving) are written at most
// every `min_interval` of wall time.
#pragma once

#include <asio/any_io_executor.hpp>
#include <asio/strand.hpp>
#include <asio/thread_pool.hpp>

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "icars/sim/world.h"

namespace spdlog {
class logger;
}

namespace icars::home {

// The kept state of each kind of simulated actuator, with the state a new device starts in.
struct SimTVState {
  bool on = false;
  std::int32_t channel = 1;
  std::int32_t volume = 20;
  friend bool operator==(const SimTVState&, const SimTVState&) = default;
};
struct SimLightState {
  bool on = false;
  std::int32_t intensity = 100;
  friend bool operator==(const SimLightState&, const SimLightState&) = default;
};
struct SimSpeakerState {
  std::string playing;  // the track, or "" when stopped
  std::int32_t volume = 40;
  std::string last_spoken;
  friend bool operator==(const SimSpeakerState&, const SimSpeakerState&) = default;
};

class SimStateFile {
 public:
  // What happened to the file found at construction.
  enum class Loaded {
    none,      // no file: every device starts as the house file says
    restored,  // read and matching: the devices start from it
    rejected,  // unreadable, corrupt or for another house or device set: warned, ignored
  };

  // Reads `path` if it exists. `devices` are the ids of the house's devices this manager
  // hosts. A file that cannot be read, is not a state file, or does not match (house name,
  // hosted devices, robots, a value out of range, a robot pose not free in the house) is
  // reported as a warning naming the file and what is wrong, renamed to `path.rejected`, and
  // ignored. Throws std::runtime_error when the file exists but cannot be renamed aside.
  SimStateFile(std::filesystem::path path, sim::World& world, std::vector<std::string> devices,
               std::shared_ptr<spdlog::logger> logger,
               std::chrono::milliseconds min_interval = std::chrono::milliseconds(100));
  // Writes what changed since the last write, then stops the writer. Call while the world
  // still exists.
  ~SimStateFile();
  SimStateFile(const SimStateFile&) = delete;
  SimStateFile& operator=(const SimStateFile&) = delete;

  const std::filesystem::path& path() const { return path_; }
  Loaded loaded() const { return loaded_; }
  const std::string& rejection() const { return rejection_; }  // why, when rejected

  // A hosted device's state to start from: the file's, or the defaults. Throws
  // std::invalid_argument for a device that is not a hosted one of that type.
  SimTVState tv(const std::string& id) const;
  SimLightState light(const std::string& id) const;
  SimSpeakerState speaker(const std::string& id) const;

  // A wheels device restores its robot itself (to hear its arrival): register before start().
  using RobotRestorer = std::function<void(const sim::RobotState&)>;
  void on_restore_robot(const std::string& robot, RobotRestorer restore);
  // Puts the file's robots back (through their restorers, else World::restore_robot) at the
  // clock's current time, then writes the file once: call after the clock was set (--epoch)
  // and before it runs. Throws std::runtime_error naming the file when it cannot be written.
  void start();

  // Record a device's new state; called with the device's own lock held, so the file never
  // holds an older state than the device. They do not write: call commit() or changed().
  void set(const std::string& id, const SimTVState& state);
  void set(const std::string& id, const SimLightState& state);
  void set(const std::string& id, const SimSpeakerState& state);

  // Returns once the state as it is now (devices and robots) is on disk, or its write failed
  // (logged as an error; the command stays done). Call after a command changed something,
  // before replying.
  void commit();
  // Something changed that nobody waits for: written within min_interval.
  void changed();

  // Where the commands of a device kept in this file run (planet::Servant::run_on): a strand
  // of its own on a small pool, so that a command waiting in commit() for the disk (an fsync
  // may take a second on a busy disk) keeps neither the device manager's io thread nor the
  // other devices waiting; one device's commands still run one at a time and in order.
  asio::any_io_executor command_executor() { return asio::make_strand(commands_.get_executor()); }

  std::uint64_t writes() const;    // completed writes, for tests
  std::string last_error() const;  // the last write's error, or ""

 private:
  void load();
  void write_loop();
  std::string render() const;  // the file's text; takes world state, call without mutex_

  std::filesystem::path path_;
  sim::World& world_;
  std::vector<std::string> devices_;
  std::shared_ptr<spdlog::logger> log_;
  std::chrono::milliseconds min_interval_;
  Loaded loaded_ = Loaded::none;
  std::string rejection_;
  std::map<std::string, sim::RobotState> saved_robots_;
  std::map<std::string, RobotRestorer> restorers_;

  mutable std::mutex mutex_;
  std::condition_variable wake_;  // the writer: a change, a commit, or stop
  std::condition_variable done_;  // committers: a write completed
  std::map<std::string, SimTVState> tvs_;
  std::map<std::string, SimLightState> lights_;
  std::map<std::string, SimSpeakerState> speakers_;
  std::uint64_t version_ = 0;  // bumped by every change
  std::uint64_t urgent_ = 0;   // the newest version a committer waits for
  std::uint64_t written_ = 0;  // the newest version on disk (or failed to get there)
  std::uint64_t writes_ = 0;
  std::string error_;
  bool started_ = false;
  bool stopping_ = false;
  std::chrono::steady_clock::time_point last_write_{};
  std::thread writer_;
  asio::thread_pool commands_{2};  // joined first: its commands wait for the writer
};

}  // namespace icars::home
