// COROS application messages and their datagram encoding.
//
// Agents exchange application messages (COROS 4.2, BaseMessage) in UDP datagrams. Each
// message is a PLANET valued struct, so it is encoded by PLANET's serializer and is the same
// on every platform (the paper serialized with Boost and named platform independence as
// future work). A datagram is:
//
//   magic "CR" | version u8 | code u16 | sender string | tagged value [| trailer]
//
// all big-endian (docs/coros.md). Version 1 has no trailer; version 2, what agents with a fleet
// key send, ends in the authentication trailer (generation u64 | counter u64 | 16-byte tag),
// which authentication.h writes and checks. The tagged value carries the struct's type name, so
// a datagram whose code and body disagree is rejected instead of misread. decode_datagram()
// never reads out of range and throws CorosError for anything malformed; it does not check the
// tag (that is DatagramVerifier's separate step).
#pragma once

#include <cstddef>
#include <cstdint>
#include <map>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "icars/planet/serializer.h"

namespace icars::coros {

inline constexpr std::size_t kMaxDatagram = 65507;        // the largest UDP payload over IPv4
inline constexpr std::uint8_t kProtocolVersion = 1;       // unsigned datagrams
inline constexpr std::uint8_t kAuthenticatedVersion = 2;  // with the authentication trailer
inline constexpr std::size_t kAuthTagSize = 16;           // HMAC-SHA256 truncated to 128 bits
inline constexpr std::size_t kAuthTrailerSize = 8 + 8 + kAuthTagSize;

// A datagram or configuration that cannot be used; what() says what was wrong.
class CorosError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Message codes (the paper's message_code). Applications add their own from 1000 up.
enum class MessageCode : std::uint16_t {
  hello = 1,         // discovery: who I am, where, how busy
  auction = 10,      // a task for sale: bid before the deadline
  bid = 11,          // a robot's cost for a task
  award = 12,        // the auctioneer gives the task to the winner
  award_ack = 13,    // the winner accepts (or refuses) the award
  revoke = 14,       // the auctioneer takes a task back (a newer round exists)
  task_status = 15,  // progress of a task, broadcast by the robot doing it
  result = 16,       // the task ended: delivered or failed
  result_ack = 17,   // the auctioneer got the result
  decline = 18,      // a robot will not bid in this round: the auctioneer need not wait for it
  // Errands (errands.h): single stops auctioned one after another; BID, AWARD_ACK and REVOKE
  // are shared with the courier market.
  errand_auction = 20,  // a stop for sale: bid the cost of appending it to your route
  errand_award = 21,    // the auctioneer gives the stop to the winner
};
std::string_view to_string(MessageCode code);

// A named place on the map with its coordinates (metres, map frame).
struct Place {
  std::string name;
  double x = 0;
  double y = 0;
  bool operator==(const Place&) const = default;
};

// HELLO (COROS 5.1): id, ip, port, role, status and timestamp, plus the agent's position and
// how many tasks it holds, which monitors show and auctioneers may use.
struct HelloMessage {
  std::string id;
  std::string ip;
  std::int32_t port = 0;
  std::string role;      // robot, user, monitor
  std::string status;    // idle, busy, failed
  double timestamp = 0;  // sender's wall clock, seconds since the Unix epoch
  double x = 0;
  double y = 0;
  std::int32_t load = 0;  // tasks queued or in progress
  static constexpr MessageCode kCode = MessageCode::hello;
  bool operator==(const HelloMessage&) const = default;
};

// A delivery for sale. Rounds count auctions of the same task: a task whose robot died is
// auctioned again with round + 1, and everything about an older round is stale.
struct AuctionMessage {
  std::string task_id;
  std::int32_t round = 1;
  std::string auctioneer;
  Place pickup;
  Place dropoff;
  std::int32_t window_ms = 0;        // bids are taken for this long after the first announcement
  std::vector<std::string> exclude;  // robots that must not bid (failed this task before)
  static constexpr MessageCode kCode = MessageCode::auction;
  bool operator==(const AuctionMessage&) const = default;
};

struct BidMessage {
  std::string task_id;
  std::int32_t round = 1;
  std::string robot;
  double cost = 0;  // metres the robot would drive, planned over the map
  static constexpr MessageCode kCode = MessageCode::bid;
  bool operator==(const BidMessage&) const = default;
};

// A robot's answer to an AUCTION (or ERRAND_AUCTION, `task_id` naming the errand) it will not
// bid on: it has failed, cannot reach a place, cannot work now. The auctioneer stops waiting for
// it in that round; a robot that says nothing is waited for until the bid window ends.
struct DeclineMessage {
  std::string task_id;
  std::int32_t round = 1;
  std::string robot;
  std::string reason;
  static constexpr MessageCode kCode = MessageCode::decline;
  bool operator==(const DeclineMessage&) const = default;
};

// The winner of a round's bids (by robot id): the lowest cost, equal costs going to the smaller
// robot id. `bids` must not be empty.
inline std::map<std::string, double>::const_iterator winning_bid(const std::map<std::string, double>& bids) {
  auto best = bids.begin();
  for (auto it = bids.begin(); it != bids.end(); ++it) {
    if (it->second < best->second) best = it;
  }
  return best;
}

struct AwardMessage {
  std::string task_id;
  std::int32_t round = 1;
  std::string robot;  // the winner
  Place pickup;
  Place dropoff;
  double cost = 0;  // the winning bid
  static constexpr MessageCode kCode = MessageCode::award;
  bool operator==(const AwardMessage&) const = default;
};

struct AwardAckMessage {
  std::string task_id;
  std::int32_t round = 1;
  std::string robot;
  bool accepted = true;
  std::string reason;  // why not, when refused
  static constexpr MessageCode kCode = MessageCode::award_ack;
  bool operator==(const AwardAckMessage&) const = default;
};

struct RevokeMessage {
  std::string task_id;
  std::int32_t round = 1;  // every assignment of this round or older is void
  std::string robot;
  static constexpr MessageCode kCode = MessageCode::revoke;
  bool operator==(const RevokeMessage&) const = default;
};

struct TaskStatusMessage {
  std::string task_id;
  std::int32_t round = 1;
  std::string robot;
  std::string auctioneer;
  std::string state;    // assigned, to_pickup, picked_up, to_dropoff, delivered, failed
  double distance = 0;  // metres driven for this task so far
  double timestamp = 0;
  static constexpr MessageCode kCode = MessageCode::task_status;
  bool operator==(const TaskStatusMessage&) const = default;
};

// The paper's ResultMessage: a task ended.
struct ResultMessage {
  std::string task_id;
  std::int32_t round = 1;
  std::string robot;
  bool success = false;
  double distance = 0;    // metres driven for the task
  double duration_s = 0;  // simulated seconds from award to the end
  std::string detail;
  static constexpr MessageCode kCode = MessageCode::result;
  bool operator==(const ResultMessage&) const = default;
};

struct ResultAckMessage {
  std::string task_id;
  std::int32_t round = 1;
  std::string robot;
  static constexpr MessageCode kCode = MessageCode::result_ack;
  bool operator==(const ResultAckMessage&) const = default;
};

// An errand for sale (errands.h): one stop a robot is to drive to. Robots bid what appending it
// to the route they are committed to would cost them. A stop with a name is located on each
// robot's own map (a waypoint, furniture or room); one without a name is at (x, y).
struct ErrandAuctionMessage {
  std::string errand;
  std::int32_t round = 1;
  std::string auctioneer;
  Place stop;
  std::int32_t window_ms = 0;
  std::vector<std::string> exclude;  // robots that must not bid
  static constexpr MessageCode kCode = MessageCode::errand_auction;
  bool operator==(const ErrandAuctionMessage&) const = default;
};

struct ErrandAwardMessage {
  std::string errand;
  std::int32_t round = 1;
  std::string robot;  // the winner
  Place stop;
  double cost = 0;  // the winning bid
  static constexpr MessageCode kCode = MessageCode::errand_award;
  bool operator==(const ErrandAwardMessage&) const = default;
};

}  // namespace icars::coros

PLANET_VALUED(icars::coros::Place, name, x, y);
PLANET_VALUED(icars::coros::HelloMessage, id, ip, port, role, status, timestamp, x, y, load);
PLANET_VALUED(icars::coros::AuctionMessage, task_id, round, auctioneer, pickup, dropoff, window_ms,
              exclude);
PLANET_VALUED(icars::coros::BidMessage, task_id, round, robot, cost);
PLANET_VALUED(icars::coros::DeclineMessage, task_id, round, robot, reason);
PLANET_VALUED(icars::coros::AwardMessage, task_id, round, robot, pickup, dropoff, cost);
PLANET_VALUED(icars::coros::AwardAckMessage, task_id, round, robot, accepted, reason);
PLANET_VALUED(icars::coros::RevokeMessage, task_id, round, robot);
PLANET_VALUED(icars::coros::TaskStatusMessage, task_id, round, robot, auctioneer, state, distance,
              timestamp);
PLANET_VALUED(icars::coros::ResultMessage, task_id, round, robot, success, distance, duration_s,
              detail);
PLANET_VALUED(icars::coros::ResultAckMessage, task_id, round, robot);
PLANET_VALUED(icars::coros::ErrandAuctionMessage, errand, round, auctioneer, stop, window_ms, exclude);
PLANET_VALUED(icars::coros::ErrandAwardMessage, errand, round, robot, stop, cost);

namespace icars::coros {

// An application message: any PLANET valued struct with a static kCode.
template <class M>
concept Message = planet::Encodable<M> && requires {
  { M::kCode } -> std::convertible_to<MessageCode>;
};

// The fields of a version 2 datagram's trailer, as read: not checked by decode_datagram().
struct AuthenticationTrailer {
  std::uint64_t generation = 0;  // the sender's start time, microseconds since the Unix epoch
  std::uint64_t counter = 0;     // grows by one with every datagram that generation sends
  bool operator==(const AuthenticationTrailer&) const = default;
};

// A datagram taken apart: the header, and the body still encoded (decoded by body_as<M>()).
struct Datagram {
  MessageCode code{};
  std::string sender;
  std::vector<std::byte> body;                          // the tagged value (without the trailer)
  std::optional<AuthenticationTrailer> authentication;  // version 2 only

  template <Message M>
  M body_as() const {
    try {
      planet::Reader r(body);
      M m = planet::decode_tagged<M>(r, to_string(M::kCode));
      if (r.remaining() != 0) {
        throw CorosError(std::string(to_string(M::kCode)) + ": " + std::to_string(r.remaining()) +
                         " bytes after the message");
      }
      return m;
    } catch (const planet::Error& e) {
      throw CorosError(std::string("malformed ") + std::string(to_string(M::kCode)) + " from " +
                       sender + ": " + e.what());
    }
  }
};

std::vector<std::byte> encode_header(MessageCode code, std::string_view sender);

template <Message M>
std::vector<std::byte> encode_datagram(std::string_view sender, const M& message) {
  std::vector<std::byte> out = encode_header(M::kCode, sender);
  planet::Writer w(out);
  planet::encode_tagged(w, message);
  if (out.size() + kAuthTrailerSize > kMaxDatagram) {  // room to sign it
    throw CorosError(std::string(to_string(M::kCode)) + " of " + std::to_string(out.size()) +
                     " bytes does not fit in a datagram");
  }
  return out;
}

// Checks magic, version and sizes and splits header, body and (version 2) trailer; throws
// CorosError. Does not authenticate: see DatagramVerifier (authentication.h).
Datagram decode_datagram(std::span<const std::byte> bytes);

}  // namespace icars::coros
