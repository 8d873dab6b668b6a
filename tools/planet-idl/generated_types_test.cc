// Code generated from testdata/*.idl: every generated type round-trips through the PLANET
// serializer with the expected descriptor, typed events are ordinary PLANET events readable by
// property name, generated exceptions survive the trip through RemoteException, and interface
// descriptions carry the declared signatures and exception translators.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cstdint>
#include <limits>
#include <type_traits>

#include "home.planet.h"

namespace fixture {
namespace {

namespace p = icars::planet;

template <class T>
T round_trip(const T& value) {
  std::vector<std::byte> bytes;
  p::Writer w(bytes);
  p::encode_tagged(w, value);
  p::Reader r(bytes);
  T back = p::decode_tagged<T>(r);
  EXPECT_EQ(r.remaining(), 0u);
  return back;
}

template <class T>
std::string descriptor() {
  return p::describe(p::descriptor_of<T>());
}

template <class T>
std::vector<std::byte> encoded(const T& value) {
  std::vector<std::byte> bytes;
  p::Writer w(bytes);
  p::Codec<T>::encode(w, value);
  return bytes;
}

Everything make_everything() {
  Everything e;
  e.flag = true;
  e.small = 250;
  e.medium = -12345;
  e.normal = std::numeric_limits<std::int32_t>::min();
  e.big = std::numeric_limits<std::int64_t>::max();
  e.single = 1.5f;
  e.twice = -2.25;
  e.text = "grüße";
  e.blob = p::Binary{{std::byte{0}, std::byte{255}}};
  e.color = Color::white;
  e.mode = nav::Mode::docking;
  e.pose = Pose{1, 2, 3};
  e.sound = SoundEvent{90, 0.5, "door"};
  e.flags = {true, false};
  e.bytes = {1, 2, 3};
  e.shorts = {-1, 1};
  e.ints = {7};
  e.longs = {-5, 5};
  e.floats = {0.5f};
  e.doubles = {1e300};
  e.texts = {"", "a"};
  e.blobs = {p::Binary{}, p::Binary{{std::byte{9}}}};
  e.colors = {Color::black, Color::green};
  e.poses = {Pose{4, 5, 6}};
  e.sounds = {SoundEvent{1, 2, "x"}, SoundEvent{}};
  e.cube = {{{1, 2}, {}}, {}, {{3}}};
  return e;
}

TEST(GeneratedEnum, HasTheDeclaredValuesAndRoundTrips) {
  static_assert(std::is_same_v<std::underlying_type_t<Color>, std::int32_t>);
  EXPECT_EQ(static_cast<std::int32_t>(Color::red), 0);
  EXPECT_EQ(static_cast<std::int32_t>(Color::green), 5);
  EXPECT_EQ(static_cast<std::int32_t>(Color::blue), 6);
  EXPECT_EQ(static_cast<std::int32_t>(Color::black), -3);
  EXPECT_EQ(static_cast<std::int32_t>(Color::white), std::numeric_limits<std::int32_t>::max());
  EXPECT_EQ(static_cast<std::int32_t>(nav::Mode::docking), 3);
  EXPECT_EQ(static_cast<std::int32_t>(geo::Unit::millimeter), 1000);
  EXPECT_EQ(round_trip(Color::black), Color::black);
  EXPECT_EQ(round_trip(nav::Mode::driving), nav::Mode::driving);
  EXPECT_EQ(descriptor<Color>(), "enum fixture::Color");
  EXPECT_EQ(descriptor<nav::Mode>(), "enum fixture::nav::Mode");
  EXPECT_EQ(descriptor<geo::Unit>(), "enum geo::Unit");
}

TEST(GeneratedValued, DefaultsToZeroAndTheFirstEnumerator) {
  EXPECT_EQ(Pose{}, (Pose{0, 0, 0}));
  EXPECT_EQ(nav::Waypoint{}.mode, nav::Mode::idle);
  EXPECT_EQ(nav::Route{}.unit, geo::Unit::meter);
  EXPECT_EQ(Everything{}.color, Color::red);
}

TEST(GeneratedValued, EncodesItsFieldsInDeclarationOrder) {
  std::vector<std::byte> expected;
  p::Writer w(expected);
  w.f64(1);
  w.f64(2);
  w.f64(3);
  EXPECT_EQ(encoded(Pose{1, 2, 3}), expected);
  EXPECT_EQ(descriptor<Pose>(), "valued fixture::Pose");
  EXPECT_EQ(descriptor<nav::Route>(), "valued fixture::nav::Route");
  EXPECT_EQ(descriptor<std::vector<std::vector<Pose>>>(),
            "sequence<sequence<valued fixture::Pose>>");
}

TEST(GeneratedValued, EveryFieldTypeRoundTrips) {
  const Everything e = make_everything();
  EXPECT_EQ(round_trip(e), e);
  EXPECT_EQ(round_trip(Everything{}), Everything{});
  const nav::Route route{{nav::Waypoint{Pose{1, 2, 3}, nav::Mode::docking, "dock"}},
                         geo::Point{4, 5},
                         geo::Unit::millimeter};
  EXPECT_EQ(round_trip(route), route);
  EXPECT_EQ(round_trip(std::vector<nav::Route>{route, nav::Route{}}),
            (std::vector<nav::Route>{route, nav::Route{}}));
}

TEST(GeneratedValued, TruncatedInputIsRejected) {
  std::vector<std::byte> bytes;
  p::Writer w(bytes);
  p::encode_tagged(w, make_everything());
  bytes.resize(bytes.size() - 3);
  p::Reader r(bytes);
  EXPECT_THROW(p::decode_tagged<Everything>(r), p::Error);
}

TEST(GeneratedEvent, IsAPlanetEventWithOnePropertyPerField) {
  const SoundEvent sound{45.0, 0.75, "tv"};
  const p::Event e = p::to_event(sound);
  EXPECT_EQ(e.type(), "fixture::SoundEvent");
  EXPECT_EQ(e.size(), 3u);
  EXPECT_EQ(e.get<double>("direction"), 45.0);
  EXPECT_EQ(e.get<double>("level"), 0.75);
  EXPECT_EQ(e.get<std::string>("source"), "tv");
  EXPECT_EQ(p::from_event<SoundEvent>(e), sound);
  EXPECT_EQ(descriptor<SoundEvent>(), "event");
  EXPECT_EQ(round_trip(sound), sound);
}

TEST(GeneratedEvent, GenericReceiversReadTheSameBytes) {
  const Detection d{{geo::Point{1, 2}, geo::Point{3, 4}},
                    Color::blue,
                    nav::Waypoint{Pose{5, 6, 7}, nav::Mode::driving, "hall"}};
  std::vector<std::byte> bytes;
  p::Writer w(bytes);
  p::encode_tagged(w, d);
  p::Reader r(bytes);
  const p::Event generic = p::decode_tagged<p::Event>(r);
  EXPECT_EQ(generic.type(), "fixture::Detection");
  EXPECT_EQ(generic.get<std::vector<geo::Point>>("outline"), d.outline);
  EXPECT_EQ(generic.get<Color>("color"), Color::blue);
  EXPECT_EQ(generic.get<nav::Waypoint>("where").label, "hall");
  EXPECT_EQ(round_trip(generic), generic);
  EXPECT_EQ(p::from_event<Detection>(generic), d);
  EXPECT_EQ(round_trip(Heartbeat{}), Heartbeat{});
}

TEST(GeneratedEvent, MismatchedGenericEventsAreRejected) {
  p::Event other("fixture::Heartbeat");
  EXPECT_THROW(p::from_event<SoundEvent>(other), p::Error);
  p::Event missing("fixture::SoundEvent");
  missing.set("direction", 1.0).set("level", 2.0);
  EXPECT_THROW(p::from_event<SoundEvent>(missing), p::Error);
  p::Event mistyped("fixture::SoundEvent");
  mistyped.set("direction", 1.0).set("level", std::int32_t{2}).set("source", std::string("x"));
  EXPECT_THROW(p::from_event<SoundEvent>(mistyped), p::Error);
}

TEST(GeneratedException, StoresItsFieldsAsProperties) {
  const NoSuchChannel e(7, "there is no channel 7");
  EXPECT_EQ(e.channel(), 7);
  const p::RemoteException& remote = e;
  EXPECT_EQ(remote.type_id(), "fixture::NoSuchChannel");
  EXPECT_EQ(NoSuchChannel::static_type_id, "fixture::NoSuchChannel");
  EXPECT_EQ(remote.remote_message(), "there is no channel 7");
  EXPECT_EQ(remote.properties().get<std::int32_t>("channel"), 7);
  EXPECT_EQ(remote.kind(), p::ErrorKind::failed);
}

TEST(GeneratedException, RoundTripsThroughRemoteException) {
  const Busy busy("kitchen", 250, Color::green, {Pose{1, 2, 3}}, "busy for a while");
  const p::RemoteException wire = round_trip(static_cast<const p::RemoteException&>(busy));
  const Busy back(wire);
  EXPECT_EQ(back.who(), "kitchen");
  EXPECT_EQ(back.retry_ms(), 250);
  EXPECT_EQ(back.color(), Color::green);
  EXPECT_EQ(back.poses(), (std::vector<Pose>{Pose{1, 2, 3}}));
  EXPECT_EQ(back.remote_message(), "busy for a while");
  const Failed failed(round_trip(static_cast<const p::RemoteException&>(Failed("gave up"))));
  EXPECT_EQ(failed.remote_message(), "gave up");
}

TEST(GeneratedException, WireConstructorRejectsMissingOrMistypedFields) {
  const p::RemoteException mistyped("fixture::NoSuchChannel", "m",
                                    p::Properties().set("channel", std::string("seven")));
  const p::RemoteException missing("fixture::NoSuchChannel", "m");
  for (const p::RemoteException& bad : {mistyped, missing}) {
    try {
      NoSuchChannel typed(bad);
      ADD_FAILURE() << "accepted " << typed.what();
    } catch (const p::Error& e) {
      EXPECT_EQ(e.kind(), p::ErrorKind::bad_data);
    }
  }
}

TEST(GeneratedInterface, DescribesItsOperations) {
  static_assert(home::TV::type_id == "fixture::home::TV");
  static_assert(std::is_same_v<decltype(home::TV::subscribe),
                               const p::Operation<void(p::Ref<home::Listener>, std::string)>>);
  static_assert(
      std::is_same_v<decltype(home::TV::record), const p::Operation<p::StreamRef(std::int32_t)>>);
  static_assert(std::is_same_v<decltype(home::TV::log), const p::OneWay<std::string>>);
  static_assert(std::is_same_v<decltype(home::TV::self), const p::Operation<p::Ref<home::TV>()>>);
  static_assert(std::is_base_of_v<p::Proxy, home::TVPrx>);
  static_assert(std::is_base_of_v<p::Servant, home::TVServant>);
  static_assert(std::is_abstract_v<home::TVServant>);
  EXPECT_EQ(home::TV::set_channel.name(), "set_channel");
  EXPECT_NE(home::TV::set_channel.translator(), nullptr);
  EXPECT_EQ(home::TV::logged.translator(), nullptr);
}

TEST(GeneratedInterface, TranslatorsTurnRemoteExceptionsIntoGeneratedClasses) {
  const auto translate = home::TV::power.translator();
  const auto rethrown = [&](const p::RemoteException& e) {
    try {
      std::rethrow_exception(translate(e));
    } catch (const Busy& busy) {
      return "Busy " + busy.who();
    } catch (const Failed&) {
      return std::string("Failed");
    } catch (const NoSuchChannel& n) {
      return fmt::format("NoSuchChannel {}", n.channel());
    } catch (const p::RemoteException& other) {
      return "RemoteException " + other.type_id();
    } catch (const p::Error& error) {
      return fmt::format("Error {}", p::to_string(error.kind()));
    }
  };
  EXPECT_EQ(rethrown(Busy("tv", 1, Color::red, {})), "Busy tv");
  EXPECT_EQ(rethrown(Failed()), "Failed");
  EXPECT_EQ(rethrown(NoSuchChannel(3)), "NoSuchChannel 3");
  EXPECT_EQ(rethrown(p::RemoteException("other::Thing", "m")), "RemoteException other::Thing");
  EXPECT_EQ(rethrown(p::RemoteException("fixture::Busy", "no fields")), "Error bad_data");
}

}  // namespace
}  // namespace fixture

// testdata/names.idl exists to make the generated code compile despite hostile names; this
// only checks that the names ended up where the IDL put them.
#include "names.planet.h"

namespace names {
namespace {

TEST(GeneratedNames, HostileNamesMapOneToOne) {
  static_assert(std::is_same_v<decltype(Pose{}.inner), fixture::Pose>);
  static_assert(std::is_same_v<decltype(Pose{}.outer), ::fixture::Pose>);
  EXPECT_EQ(Pose{}.kind, Kind::value);
  EXPECT_EQ(Shadows::Pose.name(), "Pose");
  const Problem problem(3, Kind::result, "v");
  EXPECT_EQ(problem.channel(), 3);
  EXPECT_EQ(problem.result(), Kind::result);
  EXPECT_EQ(problem.value(), "v");
}

}  // namespace
}  // namespace names
