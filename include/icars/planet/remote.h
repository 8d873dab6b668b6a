// PLANET remote references: objects passed by reference (PLANET `remote`), typed by interface.
//
// A `Ref<I>` names an object that implements interface I (a struct with a `type_id`, as written
// by planet-idl or by hand): the PUN of the endpoint that hosts it, its servant path and its
// type id. It travels as a PLANET `remote` value, so it is wire-compatible with `ObjectRef`.
// A receiver turns it into a stub bound to the right connection with the stub's constructor
// (`ListenerPrx(communicator, current.connection, ref)`), which resolves the PUN: an empty PUN
// or the PUN of the peer the reference arrived from means "over that same connection", which is
// how a server calls back into an object the caller passed to it.
#pragma once

#include <string>
#include <string_view>
#include <utility>

#include "icars/planet/serializer.h"

namespace icars::planet {

template <class I>
class Ref {
 public:
  Ref() = default;
  explicit Ref(ObjectRef object) : object_(std::move(object)) {}

  const ObjectRef& object() const { return object_; }
  bool empty() const { return object_.path.empty(); }
  bool operator==(const Ref&) const = default;

 private:
  ObjectRef object_;
};

// Encoded exactly like ObjectRef; decoding checks that the reference names an object of I
// (a reference without a type id is accepted, the callee then reports any mismatch).
template <class I>
struct Codec<Ref<I>> {
  static constexpr std::size_t kMinSize = Codec<ObjectRef>::kMinSize;
  static void describe(Writer& w) { Codec<ObjectRef>::describe(w); }
  static void encode(Writer& w, const Ref<I>& v) { Codec<ObjectRef>::encode(w, v.object()); }
  static Ref<I> decode(Reader& r) {
    ObjectRef ref = Codec<ObjectRef>::decode(r);
    if (!ref.type_id.empty() && ref.type_id != I::type_id) {
      r.fail("expected a reference to " + std::string(I::type_id) + ", got one to " +
             ref.type_id + " (" + ref.path + ")");
    }
    return Ref<I>(std::move(ref));
  }
};

}  // namespace icars::planet
