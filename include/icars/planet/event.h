// PLANET events and remote exceptions: named, typed properties passed by value.
//
// An `Event` has a type name and a set of properties; each property holds a value of any PLANET
// type together with its descriptor, so a receiver reads a property by name and type
// (`event.get<std::int32_t>("volume")`) and is told clearly when the type differs. A
// `RemoteException` is what a servant throws to report a domain failure; it reaches the caller
// with the same type id, message and properties.
#pragma once

#include <string>
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

}  // namespace icars::planet
