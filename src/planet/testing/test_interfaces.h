// Interfaces and servants shared by the PLANET tests, the test server process and benchmarks.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "icars/planet/event.h"
#include "icars/planet/remote.h"
#include "icars/planet/servant.h"

namespace planet_test {

enum class Color { red = 1, green = 2, blue = 3 };
struct Pose {
  double x = 0;
  double y = 0;
  double theta = 0;
  bool operator==(const Pose&) const = default;
};
struct Reading {
  std::string sensor;
  std::vector<Pose> path;
  Color color = Color::red;
  std::int64_t stamp = 0;
  bool operator==(const Reading&) const = default;
};

}  // namespace planet_test

namespace planet_test {
// The event of the publish/subscribe tests: a sequence number and a payload.
struct Tick {
  std::int64_t seq = 0;
  icars::planet::Binary payload;
};
}  // namespace planet_test

PLANET_ENUM(planet_test::Color);
PLANET_EVENT(planet_test::Tick, seq, payload);
PLANET_VALUED(planet_test::Pose, x, y, theta);
PLANET_VALUED(planet_test::Reading, sensor, path, color, stamp);

namespace planet_test {

namespace p = icars::planet;

struct Callback {
  static constexpr std::string_view type_id = "test::Callback";
  static constexpr p::Operation<std::string(std::string)> notify_me{"notify_me"};
};

// Echoes every PLANET type back, and a few operations the tests need.
struct Echo {
  static constexpr std::string_view type_id = "test::Echo";
  static constexpr p::Operation<void()> ping{"ping"};
  static constexpr p::Operation<bool(bool)> echo_bool{"echo_bool"};
  static constexpr p::Operation<std::uint8_t(std::uint8_t)> echo_byte{"echo_byte"};
  static constexpr p::Operation<std::int16_t(std::int16_t)> echo_short{"echo_short"};
  static constexpr p::Operation<std::int32_t(std::int32_t)> echo_int{"echo_int"};
  static constexpr p::Operation<std::int64_t(std::int64_t)> echo_long{"echo_long"};
  static constexpr p::Operation<float(float)> echo_float{"echo_float"};
  static constexpr p::Operation<double(double)> echo_double{"echo_double"};
  static constexpr p::Operation<std::string(std::string)> echo_string{"echo_string"};
  static constexpr p::Operation<p::Binary(p::Binary)> echo_binary{"echo_binary"};
  static constexpr p::Operation<p::StreamRef(p::StreamRef)> echo_stream{"echo_stream"};
  static constexpr p::Operation<Color(Color)> echo_enum{"echo_enum"};
  static constexpr p::Operation<Pose(Pose)> echo_pose{"echo_pose"};
  static constexpr p::Operation<Reading(Reading)> echo_reading{"echo_reading"};
  static constexpr p::Operation<p::Event(p::Event)> echo_event{"echo_event"};
  static constexpr p::Operation<p::RemoteException(p::RemoteException)> echo_exception{
      "echo_exception"};
  static constexpr p::Operation<p::ObjectRef(p::ObjectRef)> echo_remote{"echo_remote"};
  static constexpr p::Operation<std::vector<bool>(std::vector<bool>)> echo_bools{"echo_bools"};
  static constexpr p::Operation<std::vector<std::uint8_t>(std::vector<std::uint8_t>)> echo_bytes{
      "echo_bytes"};
  static constexpr p::Operation<std::vector<std::int16_t>(std::vector<std::int16_t>)> echo_shorts{
      "echo_shorts"};
  static constexpr p::Operation<std::vector<std::int32_t>(std::vector<std::int32_t>)> echo_ints{
      "echo_ints"};
  static constexpr p::Operation<std::vector<std::int64_t>(std::vector<std::int64_t>)> echo_longs{
      "echo_longs"};
  static constexpr p::Operation<std::vector<float>(std::vector<float>)> echo_floats{"echo_floats"};
  static constexpr p::Operation<std::vector<double>(std::vector<double>)> echo_doubles{
      "echo_doubles"};
  static constexpr p::Operation<std::vector<std::string>(std::vector<std::string>)> echo_strings{
      "echo_strings"};
  static constexpr p::Operation<std::vector<p::Binary>(std::vector<p::Binary>)> echo_binaries{
      "echo_binaries"};
  static constexpr p::Operation<std::vector<Color>(std::vector<Color>)> echo_enums{"echo_enums"};
  static constexpr p::Operation<std::vector<Pose>(std::vector<Pose>)> echo_poses{"echo_poses"};
  static constexpr p::Operation<std::vector<p::Event>(std::vector<p::Event>)> echo_events{
      "echo_events"};
  static constexpr p::Operation<std::vector<p::ObjectRef>(std::vector<p::ObjectRef>)>
      echo_remotes{"echo_remotes"};
  static constexpr p::Operation<std::vector<std::vector<std::vector<std::int32_t>>>(
      std::vector<std::vector<std::vector<std::int32_t>>>)>
      echo_nested{"echo_nested"};
  static constexpr p::Operation<std::int32_t(std::int32_t, std::string, double)> mix{"mix"};

  static constexpr p::Operation<std::int64_t(p::Binary)> size_of{"size_of"};
  static constexpr p::Operation<p::Binary(std::int32_t)> make_binary{"make_binary"};
  // Raises a RemoteException of type "test::Refused" with the given message.
  static constexpr p::Operation<void(std::string)> refuse{"refuse"};
  // Raises a plain std::runtime_error.
  static constexpr p::Operation<void()> crash{"crash"};
  // Counts one-way notifications; `counted` reads the count.
  static constexpr p::OneWay<std::int32_t> count{"count"};
  static constexpr p::Operation<std::int64_t()> counted{"counted"};
  // Absorbs one-way binaries; `absorbed` returns the bytes and messages absorbed so far.
  static constexpr p::OneWay<p::Binary> absorb{"absorb"};
  static constexpr p::Operation<std::vector<std::int64_t>()> absorbed{"absorbed"};
  // Blocks the servant's io thread: only for tests of what a stuck peer looks like.
  static constexpr p::Operation<void(std::int32_t)> block_ms{"block_ms"};
  // Calls `Callback::notify_me` on the object passed by reference, over the caller's link, and
  // returns what it answered.
  static constexpr p::Operation<std::string(p::Ref<Callback>, std::string)> call_back{
      "call_back"};
  // The PUN the server sees for the calling connection.
  static constexpr p::Operation<std::string()> caller_pun{"caller_pun"};
  // Both answer after `ms` milliseconds (a timer: the io thread stays free) with how many times
  // either has run to its end so far, this one included. `linger` is declared idempotent, so a
  // caller sends it again after a reconnection; `linger_once` is at most once.
  static constexpr p::Operation<std::int64_t(std::int32_t)> linger{"linger",
                                                                  p::CallMode::idempotent};
  static constexpr p::Operation<std::int64_t(std::int32_t)> linger_once{"linger_once"};
  // How many times `linger` or `linger_once` started (ran or is running).
  static constexpr p::Operation<std::int64_t()> lingers_started{"lingers_started",
                                                                p::CallMode::idempotent};
};

// A listener of Ticks (hosted by each subscriber process) and the source it subscribes to.
struct TickListener {
  static constexpr std::string_view type_id = "test::TickListener";
  static constexpr p::OneWay<Tick> on_tick{"on_tick"};
};
struct TickSource {
  static constexpr std::string_view type_id = "test::TickSource";
  static constexpr p::Operation<void(p::Ref<TickListener>)> subscribe{"subscribe"};
};

// Stream producer and consumer for the stream tests. The test pattern is byte i = pattern_byte(i).
struct Streams {
  static constexpr std::string_view type_id = "test::Streams";
  // A stream of `bytes` bytes of the test pattern, written in writes of `chunk` bytes.
  static constexpr p::Operation<p::StreamRef(std::int64_t, std::int32_t)> produce{"produce"};
  // Reads the stream to its end, pausing `delay_us` after every chunk; returns {bytes,
  // checksum}, or raises "test::StreamFailed" with the error.
  static constexpr p::Operation<std::vector<std::int64_t>(p::StreamRef, std::int32_t)> consume{
      "consume"};
  // {largest send queue seen on a producing connection, VmHWM kB, VmRSS kB}, then resets both
  // peaks.
  static constexpr p::Operation<std::vector<std::int64_t>()> memory{"memory"};
  // How the last produce ended: "" while it runs, "ok", or the error.
  static constexpr p::Operation<std::string()> last_write{"last_write"};
};

std::byte pattern_byte(std::uint64_t i);
void fill_pattern(std::uint64_t from, std::span<std::byte> out);  // out[k] = pattern_byte(from + k)
// FNV-1a over a stream, fed chunk by chunk.
struct Checksum {
  std::uint64_t value = 14695981039346656037ull;
  std::uint64_t bytes = 0;
  void add(std::span<const std::byte> chunk);
};
// {VmHWM kB, VmRSS kB} of this process; `reset_peak` then restarts VmHWM from VmRSS.
std::vector<std::int64_t> memory_kb(bool reset_peak);

}  // namespace planet_test
namespace icars::planet {
class Communicator;
}  // namespace icars::planet
namespace planet_test {

// The Echo servant. `communicator` is needed for call_back (it calls the caller's object).
std::shared_ptr<p::Servant> make_echo_servant(p::Communicator& communicator);
std::shared_ptr<p::Servant> make_streams_servant(p::Communicator& communicator);

}  // namespace planet_test
