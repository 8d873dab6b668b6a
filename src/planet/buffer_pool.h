// Recycled memory for large byte buffers (message reassembly blocks, encoded large arguments and
// replies, decoded Binary values). Moving a large message through fresh memory costs a page
// fault per 4 KiB page, which costs more than copying the bytes; recycling the buffers keeps a
// process that moves large messages from faulting its memory in again for every one.
//
// Buffers below kPooledBufferBytes are not pooled. The pool holds at most kMaxPooledBytes, and
// buffers unused for a while are given back to the allocator (trim_buffers, which every
// Communicator calls periodically), so a quiet process keeps no more than it needs. Thread-safe.
#pragma once

#include <chrono>
#include <cstddef>
#include <vector>

namespace icars::planet::detail {

inline constexpr std::size_t kPooledBufferBytes = 1u << 20;
inline constexpr std::size_t kMaxPooledBytes = 1u << 30;

// An empty buffer with at least `capacity` bytes of capacity, recycled when one is pooled.
std::vector<std::byte> take_buffer(std::size_t capacity);
// Keeps `buffer`'s memory for a later take_buffer (when it is large enough and there is room).
void give_buffer(std::vector<std::byte>&& buffer);
// Releases the pooled buffers unused for `idle` or longer and, when it released any, returns the
// allocator's free memory to the system (glibc: malloc_trim).
void trim_buffers(std::chrono::steady_clock::duration idle);
// Bytes held by the pool now (for tests and statistics).
std::size_t pooled_bytes();

}  // namespace icars::planet::detail
