#include "buffer_pool.h"

#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <map>
#include <mutex>

namespace icars::planet::detail {
namespace {

struct Pooled {
  std::vector<std::byte> buffer;
  std::chrono::steady_clock::time_point since;
};

struct Pool {
  std::mutex mutex;
  std::multimap<std::size_t, Pooled> buffers;  // by capacity
  std::size_t bytes = 0;
};

Pool& pool() {
  static auto* p = new Pool;  // never destroyed: buffers may be given back during exit
  return *p;
}

}  // namespace

std::vector<std::byte> take_buffer(std::size_t capacity) {
  if (capacity >= kPooledBufferBytes) {
    Pool& p = pool();
    std::lock_guard lock(p.mutex);
    if (auto it = p.buffers.lower_bound(capacity); it != p.buffers.end()) {
      std::vector<std::byte> buffer = std::move(it->second.buffer);
      p.bytes -= it->first;
      p.buffers.erase(it);
      buffer.clear();
      return buffer;
    }
  }
  std::vector<std::byte> buffer;
  buffer.reserve(capacity);
  return buffer;
}

void give_buffer(std::vector<std::byte>&& buffer) {
  const std::size_t capacity = buffer.capacity();
  if (capacity < kPooledBufferBytes) return;
  Pool& p = pool();
  std::lock_guard lock(p.mutex);
  if (p.bytes + capacity > kMaxPooledBytes) return;  // freed by the caller's vector
  p.bytes += capacity;
  p.buffers.emplace(capacity, Pooled{std::move(buffer), std::chrono::steady_clock::now()});
}

void trim_buffers(std::chrono::steady_clock::duration idle) {
  std::vector<std::vector<std::byte>> released;
  {
    Pool& p = pool();
    std::lock_guard lock(p.mutex);
    if (p.buffers.empty()) return;
    const auto cutoff = std::chrono::steady_clock::now() - idle;
    for (auto it = p.buffers.begin(); it != p.buffers.end();) {
      if (it->second.since <= cutoff) {
        p.bytes -= it->first;
        released.push_back(std::move(it->second.buffer));
        it = p.buffers.erase(it);
      } else {
        ++it;
      }
    }
  }
  if (released.empty()) return;
  released.clear();  // freed outside the lock
#if defined(__GLIBC__)
  // glibc keeps freed heap memory for reuse (its mmap threshold rises after large frees, so
  // later 1 MiB blocks come from the heap); once a burst of large messages is over, give the
  // free pages back to the system so an idle process shrinks again.
  ::malloc_trim(0);
#endif
}

std::size_t pooled_bytes() {
  Pool& p = pool();
  std::lock_guard lock(p.mutex);
  return p.bytes;
}

}  // namespace icars::planet::detail
