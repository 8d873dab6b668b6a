// Fuzz target: the PLANET payload deserializer and the RMI message headers.
//
// First input byte below kRmiModes: the rest is one RMI message, decoded as the communicator
// decodes what arrives: CALL and NOTIFY go through a real Servant (header, arity, tagged
// argument type checks, argument decoding), REPLY is read as the result of a call whose result
// type the first byte names, ERROR as an error kind and exception, STREAM as one stream
// operation. Any other first byte chooses a sequence of reads (payload_types.h): every scalar
// type, strings, binary, sequences, enums, valued structs, events, exceptions and references,
// bare or tagged, plus property lists, values and skipping values of unknown type.
//
// Expected failures are icars::planet::Error (bad_data for malformed input); anything else
// escapes to the fuzzer. Every value that decodes must re-encode to exactly the bytes it came
// from, so a decoder that accepts input and misreads it is found too.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "icars/planet/event.h"
#include "icars/planet/remote.h"
#include "icars/planet/rmi_message.h"
#include "icars/planet/serializer.h"
#include "icars/planet/servant.h"
#include "fuzz_util.h"
#include "payload_types.h"

namespace {

using namespace icars::planet;
using namespace icars_fuzz;

void check(bool ok, const char* what) { icars_fuzz::check(ok, "payload_fuzz", what); }

void check_same(std::span<const std::byte> decoded_from, const std::vector<std::byte>& encoded,
                const char* what) {
  check(decoded_from.size() == encoded.size() &&
            std::memcmp(decoded_from.data(), encoded.data(), encoded.size()) == 0,
        what);
}

// Reads every property of a decoded list as several types, as a receiver asking for what it
// expects would; a mismatch must be a clean Error.
void probe(const Properties& properties) {
  std::size_t probed = 0;
  for (const auto& item : properties.items()) {
    if (++probed > 16) return;  // each lookup is linear: keep long lists cheap to fuzz
    const std::string& name = item.first;
    const Value& value = item.second;
    (void)value.type_name();
    const auto attempt = [&](auto bare) {
      using T = typename decltype(bare)::type;
      try {
        (void)properties.get<T>(name);
        check(value.is<T>(), "a property read as a type it does not have");
      } catch (const Error&) {
      }
    };
    attempt(Bare<std::int32_t>{});
    attempt(Bare<double>{});
    attempt(Bare<std::string>{});
    attempt(Bare<Pose>{});
    attempt(Bare<std::vector<Route>>{});
    attempt(Bare<Event>{});
  }
}

template <class T>
void probe_value(const T& v) {
  if constexpr (std::is_same_v<T, Event>) {
    probe(v);
    try {
      (void)from_event<Alarm>(v);
    } catch (const Error&) {
    }
  } else if constexpr (std::is_same_v<T, RemoteException>) {
    probe(v.properties());
  } else if constexpr (std::is_same_v<T, std::vector<Event>>) {
    for (const Event& e : v) probe(e);
  }
}

// Typed events read by field name, ignoring other properties, so they need not re-encode as read.
template <class T>
constexpr bool kCanonical = !std::is_same_v<T, Alarm>;

void read_one(Reader& r, ReadSequence::Step step) {
  const std::size_t start = r.position();
  visit_kind(step.kind, [&](auto what) {
    using W = decltype(what);
    if constexpr (std::is_same_v<W, Special>) {
      std::vector<std::byte> again;
      Writer w(again);
      switch (what.kind) {
        case ReadKind::properties: {
          const Properties p = Properties::decode(r);
          probe(p);
          p.encode(w);
          check_same(r.span_from(start), again, "properties re-encode differently");
          return;
        }
        case ReadKind::value: {
          const Value v = Value::decode(r);
          (void)v.type_name();
          v.encode(w);
          check_same(r.span_from(start), again, "value re-encodes differently");
          return;
        }
        default: {
          const auto descriptor = read_descriptor(r);
          (void)describe(descriptor);
          skip_value(r, descriptor);
          return;
        }
      }
    } else {
      using T = typename W::type;
      const T v = step.tagged ? decode_tagged<T>(r) : Codec<T>::decode(r);
      probe_value(v);
      if constexpr (kCanonical<T>) {
        std::vector<std::byte> again;
        Writer w(again);
        if (step.tagged) {
          encode_tagged(w, v);
        } else {
          Codec<T>::encode(w, v);
        }
        check_same(r.span_from(start), again, "a decoded value re-encodes differently");
      }
    }
  });
}

void read_sequence(std::uint8_t seed, std::span<const std::byte> input) {
  Reader r(input);
  ReadSequence sequence(seed);
  for (std::size_t i = 0; i < kMaxReads && r.remaining() != 0; ++i) {
    read_one(r, sequence.next());
    check(r.depth == 0, "nesting depth not restored after a read");
  }
}

std::shared_ptr<Servant> make_servant() {
  auto s = std::make_shared<Servant>(std::string(FuzzApi::type_id));
  s->implement(FuzzApi::add, [](std::int32_t a, std::int32_t b) {
    return static_cast<std::int32_t>(static_cast<std::uint32_t>(a) + static_cast<std::uint32_t>(b));
  });
  s->implement(FuzzApi::echo_pose, [](Pose p) { return p; });
  s->implement(FuzzApi::waypoints, [](Route route, Color) { return route.waypoints; });
  s->implement(FuzzApi::join, [](std::string head, std::vector<std::string> rest) {
    for (const auto& part : rest) head += part;
    return head;
  });
  s->implement(FuzzApi::store, [](Binary, StreamRef) {});
  s->implement(FuzzApi::listen, [](Ref<Listener> ref) { return ref.object(); });
  s->implement(FuzzApi::relay, [](Event e, Alarm a) {
    e.set("level", a.level);
    return e;
  });
  s->implement(FuzzApi::fail, [](std::string why) -> void {
    throw RemoteException("fuzz::Failed", why);
  });
  s->implement(FuzzApi::now, [] { return std::int64_t{42}; });
  s->implement(FuzzApi::log, [](std::string, double, bool, std::int16_t, std::uint8_t, float,
                                std::vector<bool>) {});
  return s;
}

void dispatch(Reader& r, bool oneway) {
  static const std::shared_ptr<Servant> servant = make_servant();
  const std::uint32_t request_id = r.u32();
  const std::string_view path = r.str_view();
  const std::string_view method = r.str_view();
  if (path != kServantPath) return;  // the communicator answers "no servant at path"
  std::vector<std::byte> reply;
  Writer w(reply);
  const Current current{nullptr, path, method, oneway ? 0 : request_id, nullptr};
  const auto pending = servant->dispatch(method, r, oneway ? nullptr : &w, current);
  check(!pending, "a synchronous servant returned a coroutine");
  if (oneway) {
    check(reply.empty(), "a NOTIFY produced a reply");
    return;
  }
  // What the servant answers must itself be one well-formed tagged value (valued structs
  // cannot be skipped without their definition).
  Reader result(reply);
  const auto descriptor = read_descriptor(result);
  if (describe(descriptor).find("valued") != std::string::npos) return;
  skip_value(result, descriptor);
  check(result.remaining() == 0, "trailing bytes after the servant's result");
}

// A REPLY's result as a proxy whose call returns the type that `mode` names reads it.
void read_result(Reader& r, std::uint8_t mode) {
  const auto kind = static_cast<ReadKind>(mode % kReadKinds);
  visit_kind(kind, [&](auto what) {
    using W = decltype(what);
    if constexpr (std::is_same_v<W, Special>) {
      if (r.u8() != static_cast<std::uint8_t>(TypeCode::void_type) || r.remaining() != 0) {
        r.fail("result: expected void");
      }
    } else {
      using T = typename W::type;
      const T value = decode_tagged<T>(r, "result");
      if (r.remaining() != 0) r.fail("trailing bytes after the result");
      probe_value(value);
    }
  });
}

void read_stream_operation(Reader& r) {
  (void)r.u32();  // stream id
  switch (static_cast<StreamOp>(r.u8())) {
    case StreamOp::data: {
      const std::size_t n = r.count(1, "stream data");
      (void)r.raw(n);
      break;
    }
    case StreamOp::pull:
      (void)r.u32();
      break;
    case StreamOp::end:
      break;
    case StreamOp::cancel:
    case StreamOp::abort:
      (void)r.str();
      break;
    default:
      r.fail("unknown stream operation");
  }
  if (r.remaining() != 0) r.fail("trailing bytes after the stream operation");
}

void read_rmi_message(std::uint8_t mode, std::span<const std::byte> message) {
  Reader r(message);
  const auto code = static_cast<RmiCode>(r.u8());
  (void)to_string(code);
  switch (code) {
    case RmiCode::call:
    case RmiCode::notify:
      dispatch(r, code == RmiCode::notify);
      return;
    case RmiCode::reply:
      (void)r.u32();
      read_result(r, mode);
      return;
    case RmiCode::error: {
      (void)r.u32();
      const auto kind = static_cast<ErrorKind>(r.u8());
      (void)to_string(kind);
      const RemoteException e = Codec<RemoteException>::decode(r);
      probe(e.properties());
      return;
    }
    case RmiCode::stream:
      read_stream_operation(r);
      return;
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  const std::span<const std::byte> rest(reinterpret_cast<const std::byte*>(data) + 1, size - 1);
  try {
    if (data[0] < kRmiModes) {
      read_rmi_message(data[0], rest);
    } else {
      read_sequence(data[0], rest);
    }
  } catch (const Error& e) {
    // Malformed input rejected with a message: what the decoders promise.
    note_rejected("payload_fuzz", e.what());
  }
  return 0;
}
