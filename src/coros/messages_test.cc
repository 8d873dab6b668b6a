// COROS datagrams: every message survives encoding, and anything malformed — bad magic,
// another version, truncation, a body of the wrong type, trailing bytes, random garbage — is
// rejected with a CorosError that says what was wrong, never read out of range.
#include "icars/coros/messages.h"

#include <gtest/gtest.h>

#include <random>

#include "icars/coros/transport.h"

namespace icars::coros {
namespace {

template <Message M>
M round_trip(const M& m) {
  const auto bytes = encode_datagram("robot1", m);
  const Datagram d = decode_datagram(bytes);
  EXPECT_EQ(d.code, M::kCode);
  EXPECT_EQ(d.sender, "robot1");
  return d.body_as<M>();
}

TEST(CorosMessages, EveryMessageRoundTrips) {
  const Place a{"office_101", 1.5, -2.25}, b{"office_112", 30, 4};
  const HelloMessage hello{"robot1", "127.0.0.1", 40001, "robot", "idle", 1.7e9, 3.5, 4.5, 2};
  EXPECT_EQ(round_trip(hello), hello);
  const AuctionMessage auction{"user-1", 2, "user", a, b, 400, {"robot3", "robot4"}};
  EXPECT_EQ(round_trip(auction), auction);
  const BidMessage bid{"user-1", 2, "robot1", 12.5};
  EXPECT_EQ(round_trip(bid), bid);
  const DeclineMessage decline{"user-1", 2, "robot3", "no path to office_112"};
  EXPECT_EQ(round_trip(decline), decline);
  const AwardMessage award{"user-1", 2, "robot1", a, b, 12.5};
  EXPECT_EQ(round_trip(award), award);
  const AwardAckMessage ack{"user-1", 2, "robot1", false, "busy"};
  EXPECT_EQ(round_trip(ack), ack);
  const RevokeMessage revoke{"user-1", 2, "robot1"};
  EXPECT_EQ(round_trip(revoke), revoke);
  const TaskStatusMessage status{"user-1", 2, "robot1", "user", "to_pickup", 3.25, 1.7e9};
  EXPECT_EQ(round_trip(status), status);
  const ResultMessage result{"user-1", 2, "robot1", true, 20.5, 41.0, ""};
  EXPECT_EQ(round_trip(result), result);
  const ResultAckMessage result_ack{"user-1", 2, "robot1"};
  EXPECT_EQ(round_trip(result_ack), result_ack);
}

TEST(CorosMessages, HeaderIsDocumentedLayout) {
  const auto bytes = encode_datagram("r", BidMessage{"t", 1, "r", 1.0});
  ASSERT_GE(bytes.size(), 10u);
  EXPECT_EQ(bytes[0], std::byte{'C'});
  EXPECT_EQ(bytes[1], std::byte{'R'});
  EXPECT_EQ(bytes[2], std::byte{1});   // version
  EXPECT_EQ(bytes[3], std::byte{0});   // code, big-endian
  EXPECT_EQ(bytes[4], std::byte{11});  // BID
  EXPECT_EQ(bytes[8], std::byte{1});   // sender length 1
  EXPECT_EQ(bytes[9], std::byte{'r'});
  EXPECT_EQ(bytes[10], std::byte{0x12});  // the body is a tagged valued
}

std::string error_of(std::span<const std::byte> bytes) {
  try {
    decode_datagram(bytes);
  } catch (const CorosError& e) {
    return e.what();
  }
  return "";
}

TEST(CorosMessages, MalformedHeadersAreRejectedClearly) {
  auto good = encode_datagram("robot1", BidMessage{"t", 1, "robot1", 1.0});
  EXPECT_NE(error_of({}).find("bad magic"), std::string::npos);
  auto bad = good;
  bad[0] = std::byte{'X'};
  EXPECT_NE(error_of(bad).find("bad magic"), std::string::npos);
  bad = good;
  bad[2] = std::byte{9};
  EXPECT_NE(error_of(bad).find("unsupported COROS version 9"), std::string::npos);
  for (std::size_t n = 2; n < 11; ++n) {
    EXPECT_FALSE(error_of(std::span(good).first(n)).empty()) << "truncated to " << n;
  }
  bad = good;
  bad[5] = std::byte{0xFF};  // sender length 0xFF000006: more than the datagram holds
  EXPECT_NE(error_of(bad).find("truncated"), std::string::npos);
  std::vector<std::byte> huge(kMaxDatagram + 1, std::byte{0});
  EXPECT_NE(error_of(huge).find("exceeds"), std::string::npos);
}

TEST(CorosMessages, BodyOfAnotherTypeIsRejectedNotMisread) {
  // A BID code with an AWARD body: the tagged value names its type.
  auto award = encode_datagram("robot1", AwardMessage{"t", 1, "robot1", {}, {}, 1.0});
  const auto bid_code = encode_header(MessageCode::bid, "robot1");
  std::copy(bid_code.begin(), bid_code.end(), award.begin());
  const Datagram d = decode_datagram(award);
  try {
    (void)d.body_as<BidMessage>();
    FAIL() << "decoded an award as a bid";
  } catch (const CorosError& e) {
    EXPECT_NE(std::string(e.what()).find("malformed BID from robot1"), std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("AwardMessage"), std::string::npos) << e.what();
  }
  auto trailing = encode_datagram("robot1", BidMessage{"t", 1, "robot1", 1.0});
  trailing.push_back(std::byte{0});
  EXPECT_THROW((void)decode_datagram(trailing).body_as<BidMessage>(), CorosError);
}

TEST(CorosMessages, RandomBytesNeverCrash) {
  std::mt19937 rng(7);
  const auto seed =
      encode_datagram("robot1", AuctionMessage{"t", 1, "u", {"a", 1, 2}, {"b", 3, 4}, 100, {"x"}});
  int decoded = 0;
  for (int i = 0; i < 20000; ++i) {
    auto bytes = seed;
    // Flip a few bytes, or truncate, or both.
    const int flips = std::uniform_int_distribution<int>(1, 4)(rng);
    for (int f = 0; f < flips; ++f) {
      bytes[std::uniform_int_distribution<std::size_t>(0, bytes.size() - 1)(rng)] =
          std::byte(static_cast<unsigned char>(rng()));
    }
    if (rng() % 3 == 0)
      bytes.resize(std::uniform_int_distribution<std::size_t>(0, bytes.size())(rng));
    try {
      (void)decode_datagram(bytes).body_as<AuctionMessage>();
      ++decoded;
    } catch (const CorosError&) {
    }
  }
  EXPECT_GT(decoded, 0);  // flips inside strings and numbers still decode
}

TEST(CorosMessages, SenderMustBeShortAndPresent) {
  EXPECT_THROW(encode_datagram("", BidMessage{}), CorosError);
  EXPECT_THROW(encode_datagram(std::string(256, 'x'), BidMessage{}), CorosError);
}

TEST(CorosFaultInjection, ParsesAndRejectsClearly) {
  const auto f = FaultInjection::parse("drop=0.2,duplicate=0.1,delay=0.3,max_delay_ms=80,seed=7");
  EXPECT_DOUBLE_EQ(f.drop, 0.2);
  EXPECT_DOUBLE_EQ(f.duplicate, 0.1);
  EXPECT_DOUBLE_EQ(f.delay, 0.3);
  EXPECT_EQ(f.max_delay_ms, 80);
  EXPECT_EQ(f.seed, 7u);
  EXPECT_TRUE(f.active());
  EXPECT_FALSE(FaultInjection::parse("").active());
  for (const char* bad : {"drop=2", "drop=x", "lose=0.1", "drop", "max_delay_ms=0", "seed=-1"}) {
    EXPECT_THROW(FaultInjection::parse(bad), CorosError) << bad;
  }
}

}  // namespace
}  // namespace icars::coros
