// PLANET events and remote exceptions: named, typed properties passed by value.
//
// An `Event` has a type name and a set of properties; each property holds a value of any PLANET
// type together with its descriptor, so a receiver reads a property by name and type
// (`event.get<std::int32_t>("volume")`) and is told clearly when the type differs. A
// `RemoteException` is what a servant throws to report a domain failure; it reaches the caller
// with the same type id, message and properties.
#pragma once

#include <string>
#include <tuple>
#include <type_traits>
#include <string_view>
#include <utility>
#include <vector>

#include "icars/planet/error.h"
#include "icars/planet/serializer.h"

namespace icars::planet {

// One value of any PLANET type, stored encoded together with its descriptor.
class Value {
 public:
  Value() = default;
  template <Encodable T>
  static Value of(const T& v) {
    Value out;
    Writer w(out.bytes_);
    Codec<T>::describe(w);
    out.descriptor_size_ = out.bytes_.size();
    Codec<T>::encode(w, v);
    return out;
  }

  // Decodes the value as T; throws Error(bad_data) naming both types when it is not a T.
  template <Encodable T>
  T as(std::string_view what = "value") const {
    Reader r(bytes_);
    T v = decode_tagged<T>(r, what);
    if (r.remaining() != 0) r.fail(std::string(what) + ": trailing bytes after the value");
    return v;
  }
  template <Encodable T>
  bool is() const {
    const auto d = descriptor_of<T>();
    return descriptor().size() == d.size() &&
           std::equal(d.begin(), d.end(), descriptor().begin());
  }

  std::span<const std::byte> descriptor() const {
    return std::span(bytes_).first(descriptor_size_);
  }
  std::span<const std::byte> encoded_value() const {
    return std::span(bytes_).subspan(descriptor_size_);
  }
  std::string type_name() const { return describe(descriptor()); }
  bool empty() const { return bytes_.empty(); }
  bool operator==(const Value&) const = default;

  // Wire form inside a property list: descriptor, u32 value length, value bytes.
  void encode(Writer& w) const;
  static Value decode(Reader& r);

 private:
  std::vector<std::byte> bytes_;  // descriptor followed by the encoded value
  std::size_t descriptor_size_ = 0;
};

// An ordered list of named values; names are unique.
class Properties {
 public:
  template <Encodable T>
  Properties& set(std::string_view name, const T& v) {
    put(name, Value::of(v));
    return *this;
  }
  void put(std::string_view name, Value v);

  bool has(std::string_view name) const { return find(name) != nullptr; }
  const Value& value(std::string_view name) const;  // throws Error(bad_data) when absent
  template <Encodable T>
  T get(std::string_view name) const {
    return value(name).as<T>("property '" + std::string(name) + "'");
  }
  const std::vector<std::pair<std::string, Value>>& items() const { return items_; }
  std::size_t size() const { return items_.size(); }
  bool operator==(const Properties&) const = default;

  void encode(Writer& w) const;
  static Properties decode(Reader& r);

 private:
  const Value* find(std::string_view name) const;
  std::vector<std::pair<std::string, Value>> items_;
};

// A PLANET event: a type name and its properties (e.g. "SoundEvent" with "direction").
class Event : public Properties {
 public:
  Event() = default;
  explicit Event(std::string type) : type_(std::move(type)) {}
  const std::string& type() const { return type_; }
  bool operator==(const Event&) const = default;

 private:
  std::string type_;
};

// An exception raised by a servant and re-raised at the caller (PLANET `exception`).
class RemoteException : public Error {
 public:
  RemoteException() : RemoteException("", "") {}
  RemoteException(std::string type_id, std::string message, Properties properties = {});
  const std::string& type_id() const { return type_id_; }
  const std::string& remote_message() const { return message_; }
  const Properties& properties() const { return properties_; }

 private:
  std::string type_id_;
  std::string message_;
  Properties properties_;
};

template <>
struct Codec<Event> {
  static constexpr std::size_t kMinSize = 8;
  static void describe(Writer& w) { w.u8(static_cast<std::uint8_t>(TypeCode::event)); }
  static void encode(Writer& w, const Event& e) {
    w.str(e.type());
    e.Properties::encode(w);
  }
  static Event decode(Reader& r) {
    Event e(r.str());
    static_cast<Properties&>(e) = Properties::decode(r);
    return e;
  }
};

template <>
struct Codec<RemoteException> {
  static constexpr std::size_t kMinSize = 12;
  static void describe(Writer& w) { w.u8(static_cast<std::uint8_t>(TypeCode::exception)); }
  static void encode(Writer& w, const RemoteException& e) {
    w.str(e.type_id());
    w.str(e.remote_message());
    e.properties().encode(w);
  }
  static RemoteException decode(Reader& r) {
    std::string type = r.str();
    std::string message = r.str();
    return RemoteException(std::move(type), std::move(message), Properties::decode(r));
  }
};

// --- Typed events ----------------------------------------------------------------------------
//
// A struct becomes a typed event type through TypeName<T> (its event type name) and
// EventFields<T> (a tuple of event_field("name", &T::member)), written by planet-idl or by
// PLANET_EVENT. It travels as a PLANET `event` whose properties are its fields, so the same
// bytes read either as the struct or, by a generic receiver, as an Event.

template <class M>
struct EventField {
  std::string_view name;
  M member;
};
template <class M>
constexpr EventField<M> event_field(std::string_view name, M member) {
  return EventField<M>{name, member};
}

template <class T>
struct EventFields;

template <class T>
concept TypedEvent = requires {
  EventFields<T>::value;
  TypeName<T>::value;
};

template <TypedEvent T>
Event to_event(const T& v) {
  Event e{std::string(TypeName<T>::value)};
  std::apply([&](const auto&... field) { (e.set(field.name, v.*(field.member)), ...); },
             EventFields<T>::value);
  return e;
}

// Reads a typed event from a generic one; throws Error(bad_data) when the event type differs or
// a property is missing or of another type. Extra properties are ignored (newer publishers).
template <TypedEvent T>
T from_event(const Event& e) {
  if (e.type() != TypeName<T>::value) {
    throw Error(ErrorKind::bad_data, "expected event " + std::string(TypeName<T>::value) +
                                         ", got " + e.type());
  }
  T v{};
  std::apply(
      [&](const auto&... field) {
        ((v.*(field.member) =
              e.template get<std::remove_cvref_t<decltype(v.*(field.member))>>(field.name)),
         ...);
      },
      EventFields<T>::value);
  return v;
}

template <TypedEvent T>
struct Codec<T> {
  static constexpr std::size_t kMinSize = Codec<Event>::kMinSize;
  static void describe(Writer& w) { Codec<Event>::describe(w); }
  static void encode(Writer& w, const T& v) { Codec<Event>::encode(w, to_event(v)); }
  static T decode(Reader& r) {
    Event e = Codec<Event>::decode(r);
    try {
      return from_event<T>(e);
    } catch (const Error& error) {
      r.fail(error.message());
    }
  }
};

}  // namespace icars::planet

// Declares a struct as a typed PLANET event named after the type, with the listed fields as its
// properties, e.g. PLANET_EVENT(home::SoundEvent, direction, level). Use at global scope.
#define PLANET_DETAIL_EVENT_FIELD(Type, field) icars::planet::event_field(#field, &Type::field)
#define PLANET_DETAIL_EF_1(T, a) PLANET_DETAIL_EVENT_FIELD(T, a)
#define PLANET_DETAIL_EF_2(T, a, ...) \
  PLANET_DETAIL_EVENT_FIELD(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_EF_1(T, __VA_ARGS__))
#define PLANET_DETAIL_EF_3(T, a, ...) \
  PLANET_DETAIL_EVENT_FIELD(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_EF_2(T, __VA_ARGS__))
#define PLANET_DETAIL_EF_4(T, a, ...) \
  PLANET_DETAIL_EVENT_FIELD(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_EF_3(T, __VA_ARGS__))
#define PLANET_DETAIL_EF_5(T, a, ...) \
  PLANET_DETAIL_EVENT_FIELD(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_EF_4(T, __VA_ARGS__))
#define PLANET_DETAIL_EF_6(T, a, ...) \
  PLANET_DETAIL_EVENT_FIELD(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_EF_5(T, __VA_ARGS__))
#define PLANET_DETAIL_EF_7(T, a, ...) \
  PLANET_DETAIL_EVENT_FIELD(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_EF_6(T, __VA_ARGS__))
#define PLANET_DETAIL_EF_8(T, a, ...) \
  PLANET_DETAIL_EVENT_FIELD(T, a), PLANET_DETAIL_EXPAND(PLANET_DETAIL_EF_7(T, __VA_ARGS__))
#define PLANET_EVENT(Type, ...)                                                              \
  template <>                                                                                \
  struct icars::planet::TypeName<Type> {                                                     \
    static constexpr std::string_view value = #Type;                                         \
  };                                                                                         \
  template <>                                                                                \
  struct icars::planet::EventFields<Type> {                                                  \
    static constexpr auto value = std::make_tuple(PLANET_DETAIL_EXPAND(PLANET_DETAIL_PICK(   \
        __VA_ARGS__, _12, _11, _10, _9, PLANET_DETAIL_EF_8, PLANET_DETAIL_EF_7,               \
        PLANET_DETAIL_EF_6, PLANET_DETAIL_EF_5, PLANET_DETAIL_EF_4, PLANET_DETAIL_EF_3,       \
        PLANET_DETAIL_EF_2, PLANET_DETAIL_EF_1)(Type, __VA_ARGS__)));                         \
  }
