#include "icars/coros/field_cache.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <spdlog/logger.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <sys/file.h>
#include <unistd.h>

#include <array>
#include <bit>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#include "icars/coros/messages.h"

namespace icars::coros {

namespace fs = std::filesystem;

namespace {

constexpr std::array<char, 8> kMagic{'I', 'C', 'A', 'R', 'S', 'D', 'F', '1'};

// The file: magic, the grid's fingerprint, the goal, the number of cells, then one float per
// cell in the host's byte order (the agents sharing it run on one host).
struct Header {
  std::array<char, 8> magic = kMagic;
  std::uint64_t fingerprint = 0;
  double goal_x = 0, goal_y = 0;
  std::uint64_t cells = 0;
};

class Fnv1a {
 public:
  void add(const void* data, std::size_t n) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < n; ++i) hash_ = (hash_ ^ p[i]) * 0x100000001b3ULL;
  }
  template <class T>
  void add(const T& value) {
    add(&value, sizeof value);
  }
  std::uint64_t value() const { return hash_; }

 private:
  std::uint64_t hash_ = 0xcbf29ce484222325ULL;
};

std::uint64_t fingerprint_of(const sim::OccupancyGrid& grid) {
  Fnv1a h;
  h.add(grid.width());
  h.add(grid.height());
  h.add(grid.resolution());
  h.add(grid.origin().x);
  h.add(grid.origin().y);
  h.add(grid.inflate_radius());
  std::vector<unsigned char> row(static_cast<std::size_t>(grid.width()));
  for (int y = 0; y < grid.height(); ++y) {
    for (int x = 0; x < grid.width(); ++x) {
      row[static_cast<std::size_t>(x)] = grid.free(sim::Cell{x, y}) ? 1 : 0;
    }
    h.add(row.data(), row.size());
  }
  return h.value();
}

// An advisory lock on a file (flock), released at destruction. Without the lock file (an
// unwritable directory) every request succeeds at once and nothing is held.
class FileLock {
 public:
  explicit FileLock(const fs::path& file)
      : fd_(::open(file.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0600)) {}
  ~FileLock() {
    if (fd_ >= 0) ::close(fd_);  // releases the lock
  }
  FileLock(const FileLock&) = delete;
  FileLock& operator=(const FileLock&) = delete;

  // The exclusive lock if no one holds the file locked, without waiting.
  bool try_exclusive() { return fd_ < 0 || ::flock(fd_, LOCK_EX | LOCK_NB) == 0; }
  // Wait for a shared lock (every holder of one gets it at the same moment), or an exclusive one.
  void shared() { take(LOCK_SH); }
  void exclusive() { take(LOCK_EX); }

 private:
  void take(int how) {
    if (fd_ < 0) return;
    while (::flock(fd_, how) != 0 && errno == EINTR) {
    }
  }

  int fd_;
};

}  // namespace

FieldCache::FieldCache(fs::path directory, const sim::OccupancyGrid& grid)
    : directory_(std::move(directory)),
      grid_(grid),
      fingerprint_(fingerprint_of(grid)),
      log_(std::make_shared<spdlog::logger>(
          "coros", std::make_shared<spdlog::sinks::stderr_color_sink_mt>())) {
  std::error_code ec;
  fs::create_directories(directory_, ec);
  if (ec || !fs::is_directory(directory_)) {
    throw CorosError(fmt::format("field cache {}: cannot create the directory: {}",
                                 directory_.string(), ec ? ec.message() : "not a directory"));
  }
}

FieldCache::~FieldCache() = default;

fs::path FieldCache::file_of(sim::Point goal) const {
  Fnv1a h;
  h.add(std::bit_cast<std::uint64_t>(goal.x));
  h.add(std::bit_cast<std::uint64_t>(goal.y));
  return directory_ / fmt::format("{:016x}-{:016x}.field", fingerprint_, h.value());
}

std::shared_ptr<const sim::DistanceField> FieldCache::field(sim::Point goal) const {
  const fs::path file = file_of(goal);
  if (auto stored = read(file, goal)) return stored;
  // The agent that computes a field holds its lock exclusively; the others wait for it on a
  // shared lock, so when it is done they all read the file at once rather than one by one.
  FileLock lock(fs::path(file) += ".lock");
  if (!lock.try_exclusive()) {
    lock.shared();
    if (auto stored = read(file, goal)) return stored;
    lock.exclusive();  // the agent computing it ended without storing it: compute it here
  }
  if (auto stored = read(file, goal)) return stored;  // stored since we first looked
  auto made = std::make_shared<const sim::DistanceField>(grid_, goal);
  ++computed_;
  write(file, *made);
  return made;
}

std::shared_ptr<const sim::DistanceField> FieldCache::read(const fs::path& file,
                                                           sim::Point goal) const {
  std::ifstream in(file, std::ios::binary);
  if (!in) return nullptr;
  Header h;
  if (!in.read(reinterpret_cast<char*>(&h), sizeof h)) return nullptr;
  const std::size_t cells =
      static_cast<std::size_t>(grid_.width()) * static_cast<std::size_t>(grid_.height());
  // Anything else than this grid's field of this goal (another map's, a file cut short) is
  // computed again and replaced.
  if (h.magic != kMagic || h.fingerprint != fingerprint_ || h.goal_x != goal.x ||
      h.goal_y != goal.y || h.cells != cells) {
    return nullptr;
  }
  std::vector<float> distances(cells);
  if (!in.read(reinterpret_cast<char*>(distances.data()),
               static_cast<std::streamsize>(cells * sizeof(float)))) {
    return nullptr;
  }
  return std::make_shared<const sim::DistanceField>(grid_, goal, std::move(distances));
}

void FieldCache::write(const fs::path& file, const sim::DistanceField& field) const {
  // Written aside and renamed into place, so a reader never sees half a field.
  const fs::path part = fs::path(file) += fmt::format(".{}.part", ::getpid());
  const auto& d = field.distances();
  Header h;
  h.fingerprint = fingerprint_;
  h.goal_x = field.goal().x;
  h.goal_y = field.goal().y;
  h.cells = d.size();
  std::string problem;
  {
    std::ofstream out(part, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(&h), sizeof h);
    out.write(reinterpret_cast<const char*>(d.data()),
              static_cast<std::streamsize>(d.size() * sizeof(float)));
    out.close();
    if (!out) problem = fmt::format("cannot write {}", part.string());
  }
  std::error_code ec;
  if (problem.empty()) {
    fs::rename(part, file, ec);
    if (ec) {
      problem =
          fmt::format("cannot rename {} to {}: {}", part.string(), file.string(), ec.message());
    }
  }
  if (problem.empty()) return;
  fs::remove(part, ec);
  if (!write_failed_.exchange(true)) {
    log_->warn(
        "field cache: {}; this agent computes the fields it needs itself (check the space "
        "and permissions of {})",
        problem, directory_.string());
  }
}

}  // namespace icars::coros
