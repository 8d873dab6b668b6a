#include "icars/planet/event.h"

#include <fmt/format.h>

#include <algorithm>
#include <string_view>
#include <unordered_set>

namespace icars::planet {

void Value::encode(Writer& w) const {
  if (bytes_.empty()) throw Error(ErrorKind::bad_data, "cannot encode an empty Value");
  w.raw(descriptor());
  w.length(encoded_value().size());
  w.raw(encoded_value());
}

Value Value::decode(Reader& r) {
  Value out;
  const auto descriptor = read_descriptor(r);
  const std::size_t n = r.count(1, "property value");
  const auto value = r.raw(n);
  // The value must be exactly one well-formed value of its type (values containing valued types
  // are checked when read with as<T>(), since only code with the definition knows the layout).
  std::size_t base = 0;  // descriptors nest only through sequence: find the element type
  while (base + 1 < descriptor.size() && std::to_integer<std::uint8_t>(descriptor[base]) ==
                                             static_cast<std::uint8_t>(TypeCode::sequence)) {
    ++base;
  }
  if (std::to_integer<std::uint8_t>(descriptor[base]) !=
      static_cast<std::uint8_t>(TypeCode::valued)) {
    Reader check(value);
    check.depth = r.depth;
    skip_value(check, descriptor);
    if (check.remaining() != 0) {
      r.fail(fmt::format("property value of type {} has {} trailing bytes", describe(descriptor),
                         check.remaining()));
    }
  }
  out.bytes_.reserve(descriptor.size() + value.size());
  out.bytes_.insert(out.bytes_.end(), descriptor.begin(), descriptor.end());
  out.bytes_.insert(out.bytes_.end(), value.begin(), value.end());
  out.descriptor_size_ = descriptor.size();
  return out;
}

void Properties::put(std::string_view name, Value v) {
  for (auto& [key, value] : items_) {
    if (key == name) {
      value = std::move(v);
      return;
    }
  }
  items_.emplace_back(std::string(name), std::move(v));
}

const Value* Properties::find(std::string_view name) const {
  auto it = std::find_if(items_.begin(), items_.end(),
                         [&](const auto& item) { return item.first == name; });
  return it == items_.end() ? nullptr : &it->second;
}

const Value& Properties::value(std::string_view name) const {
  if (const Value* v = find(name)) return *v;
  throw Error(ErrorKind::bad_data, fmt::format("no property named '{}'", name));
}

void Properties::encode(Writer& w) const {
  w.length(items_.size());
  for (const auto& [name, value] : items_) {
    w.str(name);
    value.encode(w);
  }
}

Properties Properties::decode(Reader& r) {
  if (++r.depth > kMaxTypeDepth) r.fail("values nested deeper than 32 levels");
  Properties out;
  const std::size_t n = r.count(9, "property list");
  out.items_.reserve(n);
  // Names seen so far, as views into the input. A linear search per name made a list of 40,000
  // properties (720 KB, one message) hold the receiving thread for 25 s.
  std::unordered_set<std::string_view> names;
  names.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    const std::string_view name = r.str_view();
    if (!names.insert(name).second) r.fail(fmt::format("duplicate property '{}'", name));
    out.items_.emplace_back(std::string(name), Value::decode(r));
  }
  --r.depth;
  return out;
}

RemoteException::RemoteException(std::string type_id, std::string message, Properties properties)
    : Error(ErrorKind::failed, type_id + ": " + message),
      type_id_(std::move(type_id)),
      message_(std::move(message)),
      properties_(std::move(properties)) {}

}  // namespace icars::planet
