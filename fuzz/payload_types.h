// What payload_fuzz reads, shared with make_corpus so that the seeds are valid inputs.
//
// The fuzz target reads a sequence of PLANET values; the first input byte selects which
// sequence (a small generator walks the list of read kinds from that seed). The types here
// cover every PLANET type: scalars, strings, binary, stream and object references, sequences
// (nested too), an enum, valued structs (nested), events, typed events and exceptions.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "icars/planet/event.h"
#include "icars/planet/remote.h"
#include "icars/planet/serializer.h"
#include "icars/planet/servant.h"

namespace icars_fuzz {

enum class Color : std::int32_t { red = 0, green = 1, blue = 2 };

struct Pose {
  double x = 0;
  double y = 0;
  std::string frame;
  std::vector<std::int32_t> tags;
  bool operator==(const Pose&) const = default;
};

struct Route {
  std::string name;
  Color color = Color::red;
  Pose start;
  std::vector<Pose> waypoints;
  std::vector<std::vector<double>> grid;
  bool operator==(const Route&) const = default;
};

struct Alarm {
  std::int32_t level = 0;
  std::string where;
};

struct Listener {
  static constexpr std::string_view type_id = "fuzz::Listener";
};

}  // namespace icars_fuzz

PLANET_ENUM(icars_fuzz::Color);
PLANET_VALUED(icars_fuzz::Pose, x, y, frame, tags);
PLANET_VALUED(icars_fuzz::Route, name, color, start, waypoints, grid);
PLANET_EVENT(icars_fuzz::Alarm, level, where);

namespace icars_fuzz {

// One read of the sequence. The first group are Codec types, read tagged or bare.
enum class ReadKind : std::uint8_t {
  boolean, byte, short_int, int32, int64, float32, float64, string, binary, stream, object_ref,
  listener_ref, byte_seq, int_seq, string_seq, double_grid, bool_seq, color, pose, route, event,
  exception, alarm, event_seq, ref_seq,
  // Not Codec types: read through their own decoders.
  properties,  // Properties::decode
  value,       // Value::decode (descriptor, u32 length, value)
  any_tagged,  // read_descriptor + skip_value, as for a value of an unknown type
  count
};
inline constexpr std::uint32_t kReadKinds = static_cast<std::uint32_t>(ReadKind::count);

template <class T>
struct Bare {
  using type = T;
};
struct Special {
  ReadKind kind;
};

// Calls `f(Bare<T>{})` with the C++ type of a Codec kind, or `f(Special{kind})`.
template <class F>
decltype(auto) visit_kind(ReadKind kind, F&& f) {
  using namespace icars::planet;
  switch (kind) {
    case ReadKind::boolean: return f(Bare<bool>{});
    case ReadKind::byte: return f(Bare<std::uint8_t>{});
    case ReadKind::short_int: return f(Bare<std::int16_t>{});
    case ReadKind::int32: return f(Bare<std::int32_t>{});
    case ReadKind::int64: return f(Bare<std::int64_t>{});
    case ReadKind::float32: return f(Bare<float>{});
    case ReadKind::float64: return f(Bare<double>{});
    case ReadKind::string: return f(Bare<std::string>{});
    case ReadKind::binary: return f(Bare<Binary>{});
    case ReadKind::stream: return f(Bare<StreamRef>{});
    case ReadKind::object_ref: return f(Bare<ObjectRef>{});
    case ReadKind::listener_ref: return f(Bare<Ref<Listener>>{});
    case ReadKind::byte_seq: return f(Bare<std::vector<std::uint8_t>>{});
    case ReadKind::int_seq: return f(Bare<std::vector<std::int32_t>>{});
    case ReadKind::string_seq: return f(Bare<std::vector<std::string>>{});
    case ReadKind::double_grid: return f(Bare<std::vector<std::vector<double>>>{});
    case ReadKind::bool_seq: return f(Bare<std::vector<bool>>{});
    case ReadKind::color: return f(Bare<Color>{});
    case ReadKind::pose: return f(Bare<Pose>{});
    case ReadKind::route: return f(Bare<Route>{});
    case ReadKind::event: return f(Bare<Event>{});
    case ReadKind::exception: return f(Bare<RemoteException>{});
    case ReadKind::alarm: return f(Bare<Alarm>{});
    case ReadKind::event_seq: return f(Bare<std::vector<Event>>{});
    case ReadKind::ref_seq: return f(Bare<std::vector<ObjectRef>>{});
    case ReadKind::properties:
    case ReadKind::value:
    case ReadKind::any_tagged:
    case ReadKind::count:
      break;
  }
  return f(Special{kind});
}

// The sequence of reads chosen by the first input byte: kind and whether it is tagged.
class ReadSequence {
 public:
  explicit ReadSequence(std::uint8_t seed) : state_(seed * 2654435761u + 1) {}
  struct Step {
    ReadKind kind;
    bool tagged;
  };
  Step next() {
    state_ = state_ * 1103515245u + 12345u;
    const std::uint32_t bits = state_ >> 8;
    return {static_cast<ReadKind>(bits % kReadKinds), ((bits >> 12) & 1u) != 0};
  }

 private:
  std::uint32_t state_;
};

// First bytes below this select an RMI message (the rest of the input) instead of a sequence.
inline constexpr std::uint8_t kRmiModes = 32;
inline constexpr std::size_t kMaxReads = 64;

// The interface of the servant the fuzzer dispatches CALL and NOTIFY messages to, at "/fuzz".
struct FuzzApi {
  template <class S>
  using Op = icars::planet::Operation<S>;
  using Binary = icars::planet::Binary;
  using Event = icars::planet::Event;
  using ObjectRef = icars::planet::ObjectRef;
  using StreamRef = icars::planet::StreamRef;

  static constexpr std::string_view type_id = "fuzz::Api";
  static constexpr Op<std::int32_t(std::int32_t, std::int32_t)> add{"add"};
  static constexpr Op<Pose(Pose)> echo_pose{"echo_pose"};
  static constexpr Op<std::vector<Pose>(Route, Color)> waypoints{"waypoints"};
  static constexpr Op<std::string(std::string, std::vector<std::string>)> join{"join"};
  static constexpr Op<void(Binary, StreamRef)> store{"store"};
  static constexpr Op<ObjectRef(icars::planet::Ref<Listener>)> listen{"listen"};
  static constexpr Op<Event(Event, Alarm)> relay{"relay"};
  static constexpr Op<void(std::string)> fail{"fail"};  // raises fuzz::Failed
  static constexpr Op<std::int64_t()> now{"now"};
  static constexpr icars::planet::OneWay<std::string, double, bool, std::int16_t, std::uint8_t,
                                         float, std::vector<bool>>
      log{"log"};
};
inline constexpr std::string_view kServantPath = "/fuzz";

}  // namespace icars_fuzz
