// The serializer: every type's encoding, descriptors, and rejection of malformed input.
#include "icars/planet/serializer.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "icars/planet/event.h"
#include "test_interfaces.h"

namespace icars::planet {
namespace {

using planet_test::Color;
using planet_test::Pose;
using planet_test::Reading;

template <class T>
T round_trip(const T& v) {
  std::vector<std::byte> buf;
  Writer w(buf);
  encode_tagged(w, v);
  Reader r(buf);
  T out = decode_tagged<T>(r);
  EXPECT_EQ(r.remaining(), 0u);
  return out;
}

std::vector<std::byte> tagged_bytes(auto v) {
  std::vector<std::byte> buf;
  Writer w(buf);
  encode_tagged(w, v);
  return buf;
}

std::vector<std::byte> bytes(std::initializer_list<int> v) {
  std::vector<std::byte> out;
  for (int b : v) out.push_back(std::byte(b));
  return out;
}

TEST(Serializer, ScalarsAreBigEndianAndTagged) {
  EXPECT_EQ(tagged_bytes(true), bytes({0x01, 0x01}));
  EXPECT_EQ(tagged_bytes(std::uint8_t{0xAB}), bytes({0x02, 0xAB}));
  EXPECT_EQ(tagged_bytes(std::int16_t{-2}), bytes({0x03, 0xFF, 0xFE}));
  EXPECT_EQ(tagged_bytes(std::int32_t{0x01020304}), bytes({0x04, 1, 2, 3, 4}));
  EXPECT_EQ(tagged_bytes(std::int64_t{1}), bytes({0x05, 0, 0, 0, 0, 0, 0, 0, 1}));
  EXPECT_EQ(tagged_bytes(1.0f), bytes({0x06, 0x3F, 0x80, 0, 0}));
  EXPECT_EQ(tagged_bytes(1.0), bytes({0x07, 0x3F, 0xF0, 0, 0, 0, 0, 0, 0}));
  EXPECT_EQ(tagged_bytes(std::string("hi")), bytes({0x08, 0, 0, 0, 2, 'h', 'i'}));
  EXPECT_EQ(tagged_bytes(Binary{{std::byte{9}}}), bytes({0x09, 0, 0, 0, 1, 9}));
  EXPECT_EQ(tagged_bytes(StreamRef{5}), bytes({0x0A, 0, 0, 0, 5}));
  EXPECT_EQ(tagged_bytes(std::vector<std::int32_t>{7}), bytes({0x10, 0x04, 0, 0, 0, 1, 0, 0, 0, 7}));
  EXPECT_EQ(tagged_bytes(Color::blue), bytes({0x11, 0, 0, 0, 18, 'p', 'l', 'a', 'n', 'e', 't', '_', 't',
                                              'e', 's', 't', ':', ':', 'C', 'o', 'l', 'o', 'r', 0,
                                              0, 0, 3}));
}

TEST(Serializer, RoundTripsEveryType) {
  EXPECT_EQ(round_trip(false), false);
  EXPECT_EQ(round_trip(std::uint8_t{255}), 255);
  EXPECT_EQ(round_trip(std::numeric_limits<std::int16_t>::min()),
            std::numeric_limits<std::int16_t>::min());
  EXPECT_EQ(round_trip(std::numeric_limits<std::int32_t>::min()),
            std::numeric_limits<std::int32_t>::min());
  EXPECT_EQ(round_trip(std::numeric_limits<std::int64_t>::max()),
            std::numeric_limits<std::int64_t>::max());
  EXPECT_EQ(round_trip(-1.5f), -1.5f);
  EXPECT_TRUE(std::isnan(round_trip(std::numeric_limits<double>::quiet_NaN())));
  EXPECT_EQ(round_trip(std::string()), "");
  EXPECT_EQ(round_trip(std::string("h\0llo", 5)), std::string("h\0llo", 5));
  EXPECT_EQ(round_trip(Binary{}), Binary{});
  EXPECT_EQ(round_trip(Color::green), Color::green);
  const Pose pose{1.5, -2.25, 3.0};
  EXPECT_EQ(round_trip(pose), pose);
  const Reading reading{"lidar", {pose, Pose{}}, Color::red, -77};
  EXPECT_EQ(round_trip(reading), reading);
  const ObjectRef ref{"10.0.0.2:4000", "/home/tv", "home::TV"};
  EXPECT_EQ(round_trip(ref), ref);
  const std::vector<std::vector<std::string>> nested{{}, {"a", ""}, {"bcd"}};
  EXPECT_EQ(round_trip(nested), nested);
  const std::vector<bool> bools{true, false, true};
  EXPECT_EQ(round_trip(bools), bools);
}

TEST(Serializer, EventPropertiesAreReadByNameAndType) {
  Event e("SoundEvent");
  e.set("direction", 90.5).set("loud", true).set("source", std::string("tv")).set("pose", Pose{1, 2, 3});
  const Event back = round_trip(e);
  EXPECT_EQ(back.type(), "SoundEvent");
  EXPECT_EQ(back.get<double>("direction"), 90.5);
  EXPECT_TRUE(back.get<bool>("loud"));
  EXPECT_EQ(back.get<Pose>("pose"), (Pose{1, 2, 3}));
  EXPECT_EQ(back.value("source").type_name(), "string");
  EXPECT_EQ(back.value("pose").type_name(), "valued planet_test::Pose");
  try {
    (void)back.get<std::int32_t>("direction");
    FAIL() << "reading a double as int must fail";
  } catch (const Error& err) {
    EXPECT_EQ(err.kind(), ErrorKind::bad_data);
    EXPECT_NE(std::string(err.what()).find("property 'direction': expected int, got double"),
              std::string::npos)
        << err.what();
  }
  EXPECT_THROW((void)back.get<double>("missing"), Error);
}

TEST(Serializer, RemoteExceptionCarriesTypeMessageAndProperties) {
  RemoteException ex("nav::Unreachable", "no path to the kitchen",
                     Properties().set("distance", std::int32_t{12}));
  const RemoteException back = round_trip(ex);
  EXPECT_EQ(back.type_id(), "nav::Unreachable");
  EXPECT_EQ(back.remote_message(), "no path to the kitchen");
  EXPECT_EQ(back.properties().get<std::int32_t>("distance"), 12);
}

TEST(Serializer, HugeValuesRoundTrip) {
  Binary big;
  big.bytes.resize(8u << 20);
  for (std::size_t i = 0; i < big.bytes.size(); ++i) big.bytes[i] = std::byte(i);
  EXPECT_EQ(round_trip(big), big);
  std::vector<std::string> many(100000, "x");
  EXPECT_EQ(round_trip(many), many);
}

// `bytes` cut into blocks of the given sizes (the rest in one last block), as a connection
// assembles a large message.
std::vector<std::vector<std::byte>> in_blocks(const std::vector<std::byte>& bytes,
                                              std::initializer_list<std::size_t> sizes) {
  std::vector<std::vector<std::byte>> blocks;
  std::size_t at = 0;
  for (std::size_t n : sizes) {
    blocks.emplace_back(bytes.begin() + static_cast<std::ptrdiff_t>(at),
                        bytes.begin() + static_cast<std::ptrdiff_t>(at + n));
    at += n;
  }
  blocks.emplace_back(bytes.begin() + static_cast<std::ptrdiff_t>(at), bytes.end());
  return blocks;
}

TEST(Serializer, ValuesThatStraddleBlocksAreReadWithoutJoiningThem) {
  Binary big;
  big.bytes.resize(3u << 20);
  for (std::size_t i = 0; i < big.bytes.size(); ++i) big.bytes[i] = std::byte(i * 7);
  std::vector<std::byte> buf;
  Writer w(buf);
  encode_tagged(w, std::int32_t{-5});
  encode_tagged(w, std::string("a string across a block boundary"));
  encode_tagged(w, big);
  encode_tagged(w, std::vector<std::string>{"after", "the", "binary"});
  // Cuts inside the int, inside the string, inside the binary's length, an empty block, and
  // blocks smaller than a value.
  const auto blocks = in_blocks(buf, {3, 20, 1, 0, 2, 1u << 20, 7, 1u << 20});
  Reader r(blocks);
  EXPECT_EQ(r.remaining(), buf.size());
  EXPECT_EQ(decode_tagged<std::int32_t>(r), -5);
  EXPECT_EQ(decode_tagged<std::string>(r), "a string across a block boundary");
  const std::size_t binary_at = r.position();
  EXPECT_EQ(decode_tagged<Binary>(r), big);
  const std::size_t after = r.position();
  // span_from and rest see the input as one, wherever it was cut.
  const auto spanned = r.span_from(binary_at);
  ASSERT_EQ(spanned.size(), after - binary_at);
  EXPECT_TRUE(std::equal(spanned.begin(), spanned.end(), buf.begin() + static_cast<std::ptrdiff_t>(binary_at)));
  const auto rest = r.rest();
  EXPECT_TRUE(std::equal(rest.begin(), rest.end(), buf.begin() + static_cast<std::ptrdiff_t>(after),
                         buf.end()));
  EXPECT_EQ(r.remaining(), rest.size());
  EXPECT_EQ(decode_tagged<std::vector<std::string>>(r),
            (std::vector<std::string>{"after", "the", "binary"}));
  EXPECT_EQ(r.remaining(), 0u);
  EXPECT_THROW(r.u8(), Error);
}

TEST(Serializer, TruncatedAndGarbageBlocksAreRejectedNeverOverread) {
  std::vector<std::byte> buf;
  Writer w(buf);
  encode_tagged(w, std::string(100, 'x'));
  buf.pop_back();
  const auto blocks = in_blocks(buf, {10, 50});
  Reader truncated(blocks);
  EXPECT_THROW((void)decode_tagged<std::string>(truncated), Error);
  // A binary claiming more than the blocks hold.
  const auto lying = in_blocks(bytes({0x09, 0x00, 0x10, 0x00, 0x00, 1, 2, 3}), {2, 3});
  Reader r(lying);
  EXPECT_THROW((void)decode_tagged<Binary>(r), Error);
  const std::vector<std::vector<std::byte>> none;
  Reader empty(none);
  EXPECT_EQ(empty.remaining(), 0u);
  EXPECT_THROW(empty.u32(), Error);
  std::uint32_t seed = 777;
  for (int i = 0; i < 5000; ++i) {
    std::vector<std::byte> garbage(static_cast<std::size_t>(seed % 64));
    for (auto& b : garbage) {
      seed = seed * 1103515245u + 12345u;
      b = std::byte(seed >> 24);
    }
    const auto cut = in_blocks(garbage, {garbage.size() / 3, garbage.size() / 3});
    try {
      Reader g(cut);
      (void)decode_tagged<std::vector<std::vector<std::string>>>(g);
    } catch (const Error&) {
    }
  }
}

TEST(Serializer, WrongTypeNamesBothTypes) {
  const auto buf = tagged_bytes(std::string("x"));
  Reader r(buf);
  try {
    (void)decode_tagged<std::vector<std::int32_t>>(r, "argument 1");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("argument 1: expected sequence<int>, got string"),
              std::string::npos)
        << e.what();
  }
}

TEST(Serializer, TruncatedInputIsRejected) {
  auto buf = tagged_bytes(std::string("hello"));
  buf.pop_back();
  Reader r(buf);
  EXPECT_THROW((void)decode_tagged<std::string>(r), Error);
}

TEST(Serializer, AbsurdLengthsAreRejectedWithoutAllocating) {
  // A sequence<long> claiming 2^32-1 elements in a 10-byte message.
  const auto buf = bytes({0x10, 0x05, 0xFF, 0xFF, 0xFF, 0xFF, 0, 0, 0, 0});
  Reader r(buf);
  try {
    (void)decode_tagged<std::vector<std::int64_t>>(r);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("sequence length 4294967295 exceeds"), std::string::npos)
        << e.what();
  }
}

TEST(Serializer, GarbageNeverCrashes) {
  std::uint32_t seed = 12345;
  for (int i = 0; i < 20000; ++i) {
    std::vector<std::byte> buf(static_cast<std::size_t>(seed % 64));
    for (auto& b : buf) {
      seed = seed * 1103515245u + 12345u;
      b = std::byte(seed >> 24);
    }
    try {
      Reader r(buf);
      (void)decode_tagged<Reading>(r);
    } catch (const Error&) {
    }
    try {
      Reader r(buf);
      (void)decode_tagged<Event>(r);
    } catch (const Error&) {
    }
    try {
      Reader r(buf);
      (void)decode_tagged<std::vector<std::vector<std::string>>>(r);
    } catch (const Error&) {
    }
  }
}

TEST(Serializer, DeepNestingIsBounded) {
  std::vector<std::byte> buf;
  for (int i = 0; i < 100; ++i) buf.push_back(std::byte{0x10});
  buf.push_back(std::byte{0x04});
  Reader r(buf);
  EXPECT_THROW((void)read_descriptor(r), Error);
}

TEST(Serializer, DescriptorsDescribeThemselves) {
  EXPECT_EQ(describe(descriptor_of<std::vector<std::vector<Pose>>>()),
            "sequence<sequence<valued planet_test::Pose>>");
  EXPECT_EQ(describe(descriptor_of<Color>()), "enum planet_test::Color");
  EXPECT_EQ(describe(descriptor_of<ObjectRef>()), "remote");
}

}  // namespace
}  // namespace icars::planet
