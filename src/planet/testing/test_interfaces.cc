#include "test_interfaces.h"

#include <algorithm>
#include <cstring>
#include <chrono>
#include <fstream>
#include <mutex>
#include <stdexcept>
#include <thread>

#include <asio/co_spawn.hpp>
#include <asio/detached.hpp>
#include <asio/steady_timer.hpp>
#include <asio/use_awaitable.hpp>

#include "icars/planet/proxy.h"
#include "icars/planet/stream.h"

namespace planet_test {

namespace {
template <class T>
void echo(p::Servant& s, const p::Operation<T(T)>& op) {
  s.implement(op, [](T v) { return v; });
}
}  // namespace

std::shared_ptr<p::Servant> make_echo_servant(p::Communicator& communicator) {
  auto s = std::make_shared<p::Servant>(std::string(Echo::type_id));
  auto counter = std::make_shared<std::atomic<std::int64_t>>(0);
  s->implement(Echo::ping, [] {});
  echo(*s, Echo::echo_bool);
  echo(*s, Echo::echo_byte);
  echo(*s, Echo::echo_short);
  echo(*s, Echo::echo_int);
  echo(*s, Echo::echo_long);
  echo(*s, Echo::echo_float);
  echo(*s, Echo::echo_double);
  echo(*s, Echo::echo_string);
  echo(*s, Echo::echo_binary);
  echo(*s, Echo::echo_stream);
  echo(*s, Echo::echo_enum);
  echo(*s, Echo::echo_pose);
  echo(*s, Echo::echo_reading);
  echo(*s, Echo::echo_event);
  echo(*s, Echo::echo_remote);
  echo(*s, Echo::echo_bools);
  echo(*s, Echo::echo_bytes);
  echo(*s, Echo::echo_shorts);
  echo(*s, Echo::echo_ints);
  echo(*s, Echo::echo_longs);
  echo(*s, Echo::echo_floats);
  echo(*s, Echo::echo_doubles);
  echo(*s, Echo::echo_strings);
  echo(*s, Echo::echo_binaries);
  echo(*s, Echo::echo_enums);
  echo(*s, Echo::echo_poses);
  echo(*s, Echo::echo_events);
  echo(*s, Echo::echo_remotes);
  echo(*s, Echo::echo_nested);
  s->implement(Echo::echo_exception, [](p::RemoteException e) { return e; });
  s->implement(Echo::mix, [](std::int32_t a, const std::string& b, double c) {
    return a + static_cast<std::int32_t>(b.size()) + static_cast<std::int32_t>(c);
  });
  s->implement(Echo::size_of,
               [](const p::Binary& b) { return static_cast<std::int64_t>(b.bytes.size()); });
  s->implement(Echo::make_binary, [](std::int32_t n) {
    p::Binary b;
    b.bytes.resize(static_cast<std::size_t>(n));
    for (std::size_t i = 0; i < b.bytes.size(); ++i) b.bytes[i] = std::byte(i * 7);
    return b;
  });
  s->implement(Echo::refuse, [](const std::string& why) {
    throw p::RemoteException("test::Refused", why, p::Properties().set("code", std::int32_t{42}));
  });
  s->implement(Echo::crash, [] { throw std::runtime_error("servant crashed on purpose"); });
  s->implement(Echo::count, [counter](std::int32_t n) { *counter += n; });
  s->implement(Echo::counted, [counter] { return counter->load(); });
  auto absorbed = std::make_shared<std::vector<std::int64_t>>(2, 0);  // io thread only
  s->implement(Echo::absorb, [absorbed](const p::Binary& b) {
    (*absorbed)[0] += static_cast<std::int64_t>(b.bytes.size());
    (*absorbed)[1] += 1;
  });
  s->implement(Echo::absorbed, [absorbed] { return *absorbed; });
  s->implement(Echo::block_ms, [](std::int32_t ms) {
    std::this_thread::sleep_for(std::chrono::milliseconds(ms));
  });
  s->implement(Echo::caller_pun,
               [](const p::Current& current) { return current.connection->peer_pun(); });
  struct Lingers {
    std::atomic<std::int64_t> started{0};
    std::atomic<std::int64_t> finished{0};
  };
  auto lingers = std::make_shared<Lingers>();
  auto linger = [&communicator, lingers](std::int32_t ms) -> asio::awaitable<std::int64_t> {
    ++lingers->started;
    asio::steady_timer timer(communicator.io());
    timer.expires_after(std::chrono::milliseconds(ms));
    co_await timer.async_wait(asio::use_awaitable);
    co_return ++lingers->finished;
  };
  s->implement(Echo::linger, linger);
  s->implement(Echo::linger_once, linger);
  s->implement(Echo::lingers_started, [lingers] { return lingers->started.load(); });
  s->implement(Echo::call_back, [&communicator](p::Ref<Callback> ref, std::string text,
                                                const p::Current& current)
                                     -> asio::awaitable<std::string> {
    // Calls the object the caller passed by reference, over the caller's own connection.
    p::Proxy back(communicator, current.connection, ref.object());
    co_return co_await back.async_call(Callback::notify_me, {text}, asio::use_awaitable);
  });
  return s;
}

namespace {
// The pattern repeats every kPatternPeriod bytes (a prime, so it does not line up with chunk
// sizes); the table holds two periods so any run of up to one period is a single copy.
constexpr std::uint64_t kPatternPeriod = 65521;
const std::vector<std::byte>& pattern_table() {
  static const std::vector<std::byte> table = [] {
    std::vector<std::byte> t(2 * kPatternPeriod);
    for (std::uint64_t i = 0; i < t.size(); ++i) {
      const std::uint64_t k = i % kPatternPeriod;
      t[i] = static_cast<std::byte>((k * 31 + k / 251) & 0xFF);
    }
    return t;
  }();
  return table;
}
}  // namespace

std::byte pattern_byte(std::uint64_t i) { return pattern_table()[i % kPatternPeriod]; }

void fill_pattern(std::uint64_t from, std::span<std::byte> out) {
  const auto& table = pattern_table();
  while (!out.empty()) {
    const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(out.size(), kPatternPeriod));
    std::memcpy(out.data(), table.data() + from % kPatternPeriod, n);
    out = out.subspan(n);
    from += n;
  }
}

void Checksum::add(std::span<const std::byte> chunk) {
  for (auto b : chunk) {
    value = (value ^ std::to_integer<std::uint64_t>(b)) * 1099511628211ull;
  }
  bytes += chunk.size();
}

std::vector<std::int64_t> memory_kb(bool reset_peak) {
  std::ifstream status("/proc/self/status");
  std::int64_t hwm = 0;
  std::int64_t rss = 0;
  std::string key;
  while (status >> key) {
    if (key == "VmHWM:") status >> hwm;
    if (key == "VmRSS:") status >> rss;
  }
  if (reset_peak) std::ofstream("/proc/self/clear_refs") << "5";
  return {hwm, rss};
}

namespace {

struct StreamsState {
  std::mutex mutex;
  std::string last_write;
  std::int64_t max_queued = 0;
};

asio::awaitable<void> produce(std::shared_ptr<p::OutputStream> out, std::int64_t bytes,
                              std::int32_t chunk, std::shared_ptr<p::Connection> connection,
                              std::shared_ptr<StreamsState> state) {
  std::string result = "ok";
  try {
    std::uint64_t at = 0;
    const auto total = static_cast<std::uint64_t>(bytes);
    while (at < total) {
      std::vector<std::byte> block(std::min<std::uint64_t>(total - at, static_cast<std::uint64_t>(chunk)));
      fill_pattern(at, block);
      at += block.size();
      co_await out->async_write(std::move(block), asio::use_awaitable);
      std::lock_guard lock(state->mutex);
      state->max_queued = std::max(state->max_queued,
                                   static_cast<std::int64_t>(connection->queued_bytes()));
    }
    out->close();
  } catch (const std::exception& e) {
    result = e.what();
  }
  std::lock_guard lock(state->mutex);
  state->last_write = result;
}

}  // namespace

std::shared_ptr<p::Servant> make_streams_servant(p::Communicator& communicator) {
  auto s = std::make_shared<p::Servant>(std::string(Streams::type_id));
  auto state = std::make_shared<StreamsState>();
  s->implement(Streams::produce, [&communicator, state](std::int64_t bytes, std::int32_t chunk,
                                                        const p::Current& current) {
    auto out = p::OutputStream::create(communicator);
    {
      std::lock_guard lock(state->mutex);
      state->last_write.clear();
    }
    asio::co_spawn(communicator.executor(),
                   produce(out, bytes, std::max(chunk, 1), current.connection, state),
                   asio::detached);
    return out->ref();
  });
  s->implement(Streams::consume, [&communicator](p::StreamRef ref, std::int32_t delay_us,
                                                 const p::Current& current)
                                     -> asio::awaitable<std::vector<std::int64_t>> {
    auto in = p::InputStream::open(communicator, current.connection, ref);
    Checksum sum;
    asio::steady_timer pause(communicator.io());
    try {
      for (;;) {
        auto chunk = co_await in->async_read(asio::use_awaitable);
        if (chunk.empty()) break;
        sum.add(chunk);
        if (delay_us > 0) {
          pause.expires_after(std::chrono::microseconds(delay_us));
          co_await pause.async_wait(asio::use_awaitable);
        }
      }
    } catch (const std::exception& e) {
      throw p::RemoteException("test::StreamFailed", e.what());
    }
    co_return std::vector<std::int64_t>{static_cast<std::int64_t>(sum.bytes),
                                        static_cast<std::int64_t>(sum.value)};
  });
  s->implement(Streams::memory, [state] {
    auto kb = memory_kb(true);
    std::lock_guard lock(state->mutex);
    std::vector<std::int64_t> out{state->max_queued, kb[0], kb[1]};
    state->max_queued = 0;
    return out;
  });
  s->implement(Streams::last_write, [state] {
    std::lock_guard lock(state->mutex);
    return state->last_write;
  });
  return s;
}

}  // namespace planet_test
