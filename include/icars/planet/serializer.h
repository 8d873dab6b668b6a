// PLANET serializer: the encoding of every PLANET data type (paper Table 2).
//
// A C++ type travels over PLANET through its `Codec<T>`, which writes the type's descriptor
// (a short byte string naming the type, e.g. `10 04` for sequence<int>) and its value. Values
// in CALL arguments, REPLY results and event properties are "tagged": the descriptor precedes
// the value, so a receiver rejects a value of the wrong type with a clear error instead of
// misreading it. Inside a sequence or a valued struct the element/field types are known and
// are not repeated. All integers are big-endian; docs/protocol.md is the normative description.
//
// Built-in mappings:
//   void -> void            bool -> bool              byte -> std::uint8_t
//   short -> std::int16_t   int -> std::int32_t       long -> std::int64_t
//   float -> float          double -> double          string -> std::string
//   binary -> Binary        stream -> StreamRef       sequence<T> -> std::vector<T>
//   enum -> a C++ enum declared with PLANET_ENUM      valued -> a struct declared with PLANET_VALUED
//   event -> Event          exception -> RemoteException      remote -> ObjectRef
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>
#include <string>
#include <string_view>
#include <tuple>
#include <type_traits>
#include <vector>

#include "icars/planet/detail/byte_order.h"
#include "icars/planet/error.h"

namespace icars::planet {

enum class TypeCode : std::uint8_t {
  void_type = 0x00,
  boolean = 0x01,
  byte = 0x02,
  short_int = 0x03,
  int32 = 0x04,
  int64 = 0x05,
  float32 = 0x06,
  float64 = 0x07,
  string = 0x08,
  binary = 0x09,
  stream = 0x0A,
  sequence = 0x10,
  enumeration = 0x11,
  valued = 0x12,
  event = 0x13,
  exception = 0x14,
  remote = 0x15,
};

inline constexpr std::size_t kMaxTypeDepth = 32;  // nesting limit for descriptors and values

// Opaque bytes (images, audio): PLANET `binary`.
struct Binary {
  std::vector<std::byte> bytes;
  bool operator==(const Binary&) const = default;
};

// A handle to a stream channel (PLANET `stream`); the channel itself is opened by the RMI layer.
struct StreamRef {
  std::uint32_t id = 0;
  bool operator==(const StreamRef&) const = default;
};

// A remote object passed by reference (PLANET `remote`): the PUN (PLANET unique name,
// CommunicatorOptions::pun) of the endpoint that hosts it, its servant path and its type id.
// An empty `pun` means "an object of the peer that sent this reference", reachable over the
// connection the reference arrived on.
struct ObjectRef {
  std::string pun;
  std::string path;
  std::string type_id;
  bool operator==(const ObjectRef&) const = default;
};

// Appends encoded bytes to a buffer it does not own.
class Writer {
 public:
  explicit Writer(std::vector<std::byte>& out) : out_(&out) {}

  void u8(std::uint8_t v) { out_->push_back(std::byte{v}); }
  void u16(std::uint16_t v) { detail::store_be16(grow(2), v); }
  void u32(std::uint32_t v) { detail::store_be32(grow(4), v); }
  void u64(std::uint64_t v) { detail::store_be64(grow(8), v); }
  void f32(float v) { u32(std::bit_cast<std::uint32_t>(v)); }
  void f64(double v) { u64(std::bit_cast<std::uint64_t>(v)); }
  void raw(std::span<const std::byte> bytes) {
    if (bytes.size() >= kLargeRaw) return raw_large(bytes);
    out_->insert(out_->end(), bytes.begin(), bytes.end());
  }
  void length(std::size_t n);  // u32 length prefix; throws bad_data above 4 GiB - 1
  void str(std::string_view s) {
    length(s.size());
    raw(std::as_bytes(std::span(s.data(), s.size())));
  }

  std::vector<std::byte>& buffer() { return *out_; }

 private:
  std::byte* grow(std::size_t n) {
    const std::size_t at = out_->size();
    out_->resize(at + n);
    return out_->data() + at;
  }
  static constexpr std::size_t kLargeRaw = std::size_t{1} << 20;
  void raw_large(std::span<const std::byte> bytes);  // grows into recycled memory (buffer_pool.h)
  std::vector<std::byte>* out_;
};

// Reads encoded bytes it does not own: one span, or the blocks a connection assembled a large
// message in (read where they lie, without joining them into one buffer first). Every read checks
// bounds and throws Error(bad_data) naming what was being read, so garbage input never reads out
// of range.
class Reader {
 public:
  explicit Reader(std::span<const std::byte> bytes) : bytes_(bytes), size_(bytes.size()) {}
  // The concatenation of `blocks` (which must outlive the reader). A value that straddles two
  // blocks is read from a copy the reader keeps until it is destroyed.
  explicit Reader(std::span<const std::vector<std::byte>> blocks);

  std::uint8_t u8() { return std::to_integer<std::uint8_t>(*take(1, "byte")); }
  std::uint16_t u16() { return detail::load_be16(take(2, "short")); }
  std::uint32_t u32() { return detail::load_be32(take(4, "int")); }
  std::uint64_t u64() { return detail::load_be64(take(8, "long")); }
  float f32() { return std::bit_cast<float>(u32()); }
  double f64() { return std::bit_cast<double>(u64()); }
  std::span<const std::byte> raw(std::size_t n) { return {take(n, "bytes"), n}; }
  // The next `n` bytes as a buffer of their own (a large one in recycled memory, buffer_pool.h),
  // copied once from wherever they lie.
  std::vector<std::byte> copy(std::size_t n);
  // A u32 count of items that each need at least `min_item_size` bytes; rejects counts that the
  // remaining input cannot hold, so an absurd length never causes a huge allocation.
  std::size_t count(std::size_t min_item_size, const char* what);
  std::string_view str_view() {
    const std::size_t n = count(1, "string");
    return {reinterpret_cast<const char*>(take(n, "string")), n};
  }
  std::string str() { return std::string(str_view()); }

  std::size_t remaining() const { return size_ - position(); }
  std::size_t position() const { return base_ + pos_; }
  // The unread bytes, and the bytes from `start` to the position, as one span (copied into the
  // reader when they straddle blocks).
  std::span<const std::byte> rest() const;
  std::span<const std::byte> span_from(std::size_t start) const;
  [[noreturn]] void fail(const std::string& what) const;

  std::size_t depth = 0;  // current nesting, checked against kMaxTypeDepth

 private:
  const std::byte* take(std::size_t n, const char* what) {
    if (n > bytes_.size() - pos_) return take_across(n, what);
    const std::byte* p = bytes_.data() + pos_;
    pos_ += n;
    return p;
  }
  const std::byte* take_across(std::size_t n, const char* what);  // beyond the current block
  void next_block();
  void copy_out(std::byte* to, std::size_t n);  // the next n bytes, across blocks
  void copy_range(std::size_t start, std::size_t n, std::byte* to) const;
  std::span<const std::byte> kept(std::size_t start, std::size_t n) const;
  [[noreturn]] void underflow(std::size_t n, const char* what) const;

  std::span<const std::byte> bytes_;  // the current block (the whole input for one span)
  std::size_t pos_ = 0;               // within bytes_
  std::size_t base_ = 0;              // where bytes_ starts in the input
  std::size_t size_ = 0;              // of the whole input
  std::span<const std::vector<std::byte>> blocks_;  // empty for one span
  std::size_t block_ = 0;                           // bytes_ is blocks_[block_]
  mutable std::vector<std::vector<std::byte>> kept_;  // copies of values that straddle blocks
};

// --- Codecs --------------------------------------------------------------------------------

template <class T>
struct Codec;  // specialised for every type PLANET can carry

template <class T>
concept Encodable = requires(Writer& w, Reader& r, const T& v) {
  Codec<T>::describe(w);
  Codec<T>::encode(w, v);
  { Codec<T>::decode(r) } -> std::same_as<T>;
  { Codec<T>::kMinSize } -> std::convertible_to<std::size_t>;
};

namespace detail {
// A copy of `bytes`; a large one is made in recycled memory (buffer_pool.h).
std::vector<std::byte> copy_bytes(std::span<const std::byte> bytes);

// Once a decoded value is done with (a servant's arguments and result), the memory of its large
// buffers goes back to the pool.
template <class T>
void recycle(T&) {}
void recycle(Binary& value);
template <class... T>
void recycle_all(std::tuple<T...>& values) {
  std::apply([](auto&... v) { (recycle(v), ...); }, values);
}

template <class T, TypeCode C, std::size_t Size>
struct ScalarCodec {
  static constexpr std::size_t kMinSize = Size;
  static void describe(Writer& w) { w.u8(static_cast<std::uint8_t>(C)); }
};
}  // namespace detail

template <>
struct Codec<bool> : detail::ScalarCodec<bool, TypeCode::boolean, 1> {
  static void encode(Writer& w, bool v) { w.u8(v ? 1 : 0); }
  static bool decode(Reader& r) {
    const std::uint8_t b = r.u8();
    if (b > 1) r.fail("bool must be 0 or 1, got " + std::to_string(b));
    return b == 1;
  }
};
template <>
struct Codec<std::uint8_t> : detail::ScalarCodec<std::uint8_t, TypeCode::byte, 1> {
  static void encode(Writer& w, std::uint8_t v) { w.u8(v); }
  static std::uint8_t decode(Reader& r) { return r.u8(); }
};
template <>
struct Codec<std::int16_t> : detail::ScalarCodec<std::int16_t, TypeCode::short_int, 2> {
  static void encode(Writer& w, std::int16_t v) { w.u16(static_cast<std::uint16_t>(v)); }
  static std::int16_t decode(Reader& r) { return static_cast<std::int16_t>(r.u16()); }
};
template <>
struct Codec<std::int32_t> : detail::ScalarCodec<std::int32_t, TypeCode::int32, 4> {
  static void encode(Writer& w, std::int32_t v) { w.u32(static_cast<std::uint32_t>(v)); }
  static std::int32_t decode(Reader& r) { return static_cast<std::int32_t>(r.u32()); }
};
template <>
struct Codec<std::int64_t> : detail::ScalarCodec<std::int64_t, TypeCode::int64, 8> {
  static void encode(Writer& w, std::int64_t v) { w.u64(static_cast<std::uint64_t>(v)); }
  static std::int64_t decode(Reader& r) { return static_cast<std::int64_t>(r.u64()); }
};
template <>
struct Codec<float> : detail::ScalarCodec<float, TypeCode::float32, 4> {
  static void encode(Writer& w, float v) { w.f32(v); }
  static float decode(Reader& r) { return r.f32(); }
};
template <>
struct Codec<double> : detail::ScalarCodec<double, TypeCode::float64, 8> {
  static void encode(Writer& w, double v) { w.f64(v); }
  static double decode(Reader& r) { return r.f64(); }
};
template <>
struct Codec<std::string> : detail::ScalarCodec<std::string, TypeCode::string, 4> {
  static void encode(Writer& w, const std::string& v) { w.str(v); }
  static std::string decode(Reader& r) { return r.str(); }
};
template <>
struct Codec<Binary> : detail::ScalarCodec<Binary, TypeCode::binary, 4> {
  static void encode(Writer& w, const Binary& v) {
    w.length(v.bytes.size());
    w.raw(v.bytes);
  }
  static Binary decode(Reader& r) {
    const std::size_t n = r.count(1, "binary");
    return Binary{r.copy(n)};
  }
};
template <>
struct Codec<StreamRef> : detail::ScalarCodec<StreamRef, TypeCode::stream, 4> {
  static void encode(Writer& w, const StreamRef& v) { w.u32(v.id); }
  static StreamRef decode(Reader& r) { return StreamRef{r.u32()}; }
};
template <>
struct Codec<ObjectRef> : detail::ScalarCodec<ObjectRef, TypeCode::remote, 12> {
  static void encode(Writer& w, const ObjectRef& v) {
    w.str(v.pun);
    w.str(v.path);
    w.str(v.type_id);
  }
  static ObjectRef decode(Reader& r) {
    ObjectRef ref;
    ref.pun = r.str();
    ref.path = r.str();
    ref.type_id = r.str();
    return ref;
  }
};

template <class T>
struct Codec<std::vector<T>> {
  static constexpr std::size_t kMinSize = 4;
  static void describe(Writer& w) {
    w.u8(static_cast<std::uint8_t>(TypeCode::sequence));
    Codec<T>::describe(w);
  }
  static void encode(Writer& w, const std::vector<T>& v) {
    w.length(v.size());
    if constexpr (std::is_same_v<T, std::uint8_t>) {
      w.raw(std::as_bytes(std::span(v)));
    } else {
      for (const auto& item : v) Codec<T>::encode(w, item);
    }
  }
  static std::vector<T> decode(Reader& r) {
    const std::size_t min = Codec<T>::kMinSize == 0 ? 1 : Codec<T>::kMinSize;
    const std::size_t n = r.count(min, "sequence");
    std::vector<T> out;
    if constexpr (std::is_same_v<T, std::uint8_t>) {
      auto bytes = r.raw(n);
      out.resize(n);
      if (n != 0) std::memcpy(out.data(), bytes.data(), n);
    } else {
      if (++r.depth > kMaxTypeDepth) r.fail("values nested deeper than 32 levels");
      out.reserve(n);
      for (std::size_t i = 0; i < n; ++i) out.push_back(Codec<T>::decode(r));
      --r.depth;
    }
    return out;
  }
};

// Type names for enums and valued structs, set by PLANET_ENUM / PLANET_VALUED.
template <class T>
struct TypeName;

template <class T>
  requires std::is_enum_v<T> && requires { TypeName<T>::value; }
struct Codec<T> {
  static constexpr std::size_t kMinSize = 4;
  static void describe(Writer& w) {
    w.u8(static_cast<std::uint8_t>(TypeCode::enumeration));
    w.str(TypeName<T>::value);
  }
  static void encode(Writer& w, T v) { w.u32(static_cast<std::uint32_t>(v)); }
  static T decode(Reader& r) {
    return static_cast<T>(static_cast<std::underlying_type_t<T>>(static_cast<std::int32_t>(r.u32())));
  }
};

// Field lists of valued structs, set by PLANET_VALUED: a tuple of member pointers.
template <class T>
struct ValuedFields;

template <class T>
  requires requires { ValuedFields<T>::value; }
struct Codec<T> {
  static constexpr std::size_t kMinSize = std::apply(
      [](auto... members) {
        return (std::size_t{0} + ... +
                Codec<std::remove_cvref_t<decltype(std::declval<T&>().*members)>>::kMinSize);
      },
      ValuedFields<T>::value);
  static void describe(Writer& w) {
    w.u8(static_cast<std::uint8_t>(TypeCode::valued));
    w.str(TypeName<T>::value);
  }
  static void encode(Writer& w, const T& v) {
    std::apply(
        [&](auto... members) {
          (Codec<std::remove_cvref_t<decltype(v.*members)>>::encode(w, v.*members), ...);
        },
        ValuedFields<T>::value);
  }
  static T decode(Reader& r) {
    if (++r.depth > kMaxTypeDepth) r.fail("values nested deeper than 32 levels");
    T v{};
    std::apply(
        [&](auto... members) {
          ((v.*members = Codec<std::remove_cvref_t<decltype(v.*members)>>::decode(r)), ...);
        },
        ValuedFields<T>::value);
    --r.depth;
    return v;
  }
};

// --- Descriptors and tagged values ---------------------------------------------------------

// The descriptor bytes of T, computed once.
template <Encodable T>
std::span<const std::byte> descriptor_of() {
  static const std::vector<std::byte> bytes = [] {
    std::vector<std::byte> out;
    Writer w(out);
    Codec<T>::describe(w);
    return out;
  }();
  return bytes;
}

// Reads one descriptor and returns its bytes; throws bad_data on an unknown code or too deep
// nesting.
std::span<const std::byte> read_descriptor(Reader& r);

// Human-readable form of a descriptor ("sequence<int>", "valued nav::Pose").
std::string describe(std::span<const std::byte> descriptor);

template <Encodable T>
void encode_tagged(Writer& w, const T& v) {
  w.raw(descriptor_of<T>());
  Codec<T>::encode(w, v);
}

// Checks that the next descriptor is T's, naming both types on a mismatch.
template <Encodable T>
void expect_descriptor(Reader& r, std::string_view what) {
  const auto actual = read_descriptor(r);
  const auto expected = descriptor_of<T>();
  if (actual.size() != expected.size() ||
      std::memcmp(actual.data(), expected.data(), actual.size()) != 0) {
    r.fail(std::string(what) + ": expected " + describe(expected) + ", got " + describe(actual));
  }
}

template <Encodable T>
T decode_tagged(Reader& r, std::string_view what = "value") {
  expect_descriptor<T>(r, what);
  return Codec<T>::decode(r);
}

// Skips one value of the given descriptor; used for values whose C++ type is unknown here.
// Valued structs cannot be skipped without their layout, so this throws bad_data for them.
void skip_value(Reader& r, std::span<const std::byte> descriptor);

}  // namespace icars::planet

// --- Declaring user types ------------------------------------------------------------------

#define PLANET_DETAIL_MEMBER(Type, field) &Type::field
#define PLANET_DETAIL_EXPAND(x) x
#define PLANET_DETAIL_FE_1(T, a) PLANET_DETAIL_MEMBER(T, a)
#define PLANET_DETAIL_FE_2(T, a, ...) \
  PLANET_DETAIL_MEMBER(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_FE_1(T, __VA_ARGS__))
#define PLANET_DETAIL_FE_3(T, a, ...) \
  PLANET_DETAIL_MEMBER(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_FE_2(T, __VA_ARGS__))
#define PLANET_DETAIL_FE_4(T, a, ...) \
  PLANET_DETAIL_MEMBER(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_FE_3(T, __VA_ARGS__))
#define PLANET_DETAIL_FE_5(T, a, ...) \
  PLANET_DETAIL_MEMBER(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_FE_4(T, __VA_ARGS__))
#define PLANET_DETAIL_FE_6(T, a, ...) \
  PLANET_DETAIL_MEMBER(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_FE_5(T, __VA_ARGS__))
#define PLANET_DETAIL_FE_7(T, a, ...) \
  PLANET_DETAIL_MEMBER(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_FE_6(T, __VA_ARGS__))
#define PLANET_DETAIL_FE_8(T, a, ...) \
  PLANET_DETAIL_MEMBER(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_FE_7(T, __VA_ARGS__))
#define PLANET_DETAIL_FE_9(T, a, ...) \
  PLANET_DETAIL_MEMBER(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_FE_8(T, __VA_ARGS__))
#define PLANET_DETAIL_FE_10(T, a, ...) \
  PLANET_DETAIL_MEMBER(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_FE_9(T, __VA_ARGS__))
#define PLANET_DETAIL_FE_11(T, a, ...) \
  PLANET_DETAIL_MEMBER(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_FE_10(T, __VA_ARGS__))
#define PLANET_DETAIL_FE_12(T, a, ...) \
  PLANET_DETAIL_MEMBER(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_FE_11(T, __VA_ARGS__))
#define PLANET_DETAIL_PICK(_1, _2, _3, _4, _5, _6, _7, _8, _9, _10, _11, _12, N, ...) N
#define PLANET_DETAIL_FOR_EACH(T, ...)                                                          \
  PLANET_DETAIL_EXPAND(PLANET_DETAIL_PICK(__VA_ARGS__, PLANET_DETAIL_FE_12, PLANET_DETAIL_FE_11, \
                                          PLANET_DETAIL_FE_10, PLANET_DETAIL_FE_9,              \
                                          PLANET_DETAIL_FE_8, PLANET_DETAIL_FE_7,               \
                                          PLANET_DETAIL_FE_6, PLANET_DETAIL_FE_5,               \
                                          PLANET_DETAIL_FE_4, PLANET_DETAIL_FE_3,               \
                                          PLANET_DETAIL_FE_2, PLANET_DETAIL_FE_1)(T, __VA_ARGS__))

// Declares a C++ enum as a PLANET enum named after the type, e.g. PLANET_ENUM(demo::Color).
// Use at global namespace scope.
#define PLANET_ENUM(Type)                          \
  template <>                                      \
  struct icars::planet::TypeName<Type> {           \
    static constexpr std::string_view value = #Type; \
  }

// Declares a struct as a PLANET valued type with the listed fields (1 to 12, encoded in this
// order), e.g. PLANET_VALUED(nav::Pose, x, y, theta). Use at global namespace scope.
#define PLANET_VALUED(Type, ...)                                         \
  template <>                                                            \
  struct icars::planet::TypeName<Type> {                                 \
    static constexpr std::string_view value = #Type;                     \
  };                                                                     \
  template <>                                                            \
  struct icars::planet::ValuedFields<Type> {                             \
    static constexpr auto value = std::make_tuple(PLANET_DETAIL_FOR_EACH(Type, __VA_ARGS__)); \
  }
