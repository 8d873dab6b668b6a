// Distance fields shared by the agents of one host through a directory.
//
// A robot's bid reads the distance fields of the places it would drive to (MapPlanner), and
// each field costs milliseconds of Dijkstra over the whole map (about 10 ms on the office floor)
// where reading one costs microseconds. Robots on separate computers each compute their own in
// parallel; N robot processes on one host (icars-coros run) would compute the same field N times
// on the same cores, so an auction of 50 robots waited a second for bids. With a FieldCache the
// first agent to need a field computes it and writes it to the directory while the others wait
// for it, then read it.
#pragma once

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <memory>

#include "icars/sim/planner.h"

namespace spdlog {
class logger;
}

namespace icars::coros {

class FieldCache {
 public:
  // Fields of `grid` (kept alive by the caller, as the fields refer to it) in `directory`,
  // created when missing; throws CorosError naming the directory when it cannot be.
  FieldCache(std::filesystem::path directory, const sim::OccupancyGrid& grid);
  ~FieldCache();
  FieldCache(const FieldCache&) = delete;
  FieldCache& operator=(const FieldCache&) = delete;

  // The field of `goal` (free on the grid: std::invalid_argument otherwise): read from the
  // directory when an agent stored it, else computed and stored. While one agent computes a
  // field, the others asking for it wait (an advisory lock per field), then read it. A file that
  // cannot be written is reported once on stderr and the field returned all the same.
  // Thread-safe.
  std::shared_ptr<const sim::DistanceField> field(sim::Point goal) const;

  // The file that holds the field of `goal`: named by the grid's fingerprint (its size,
  // resolution, origin, inflation and free cells) and the goal, so maps never share a file.
  std::filesystem::path file_of(sim::Point goal) const;
  const std::filesystem::path& directory() const { return directory_; }
  // Fields this object computed itself rather than read (for tests and benchmarks).
  std::size_t computed() const { return computed_.load(); }

 private:
  std::shared_ptr<const sim::DistanceField> read(const std::filesystem::path& file,
                                                 sim::Point goal) const;
  void write(const std::filesystem::path& file, const sim::DistanceField& field) const;

  std::filesystem::path directory_;
  const sim::OccupancyGrid& grid_;
  std::uint64_t fingerprint_;
  std::shared_ptr<spdlog::logger> log_;
  mutable std::atomic<std::size_t> computed_{0};
  mutable std::atomic<bool> write_failed_{false};  // reported once
};

}  // namespace icars::coros
