// COROS message authentication: the fleet's shared key, and signing and checking datagrams with
// it, so that a host without the key can neither forge a message (a HELLO, a winning BID, an
// AWARD) nor replay one it recorded (docs/coros.md, "Message authentication").
//
// Every agent of a fleet holds the same FleetKey. DatagramSigner turns an encoded datagram into
// an authenticated one (version 2): it appends its generation (the signer's start time), a
// counter that grows with every datagram, and an HMAC-SHA256 tag, truncated to 16 bytes, over
// every byte before the tag, header and sender id included. DatagramVerifier checks a received
// datagram in a step of its own after decode_datagram(): the tag, recomputed with the key and
// compared in constant time, then that its generation and counter are new for that sender.
// UdpTransport does both when it has a key, so handlers only see datagrams that passed.
//
// Not provided: confidentiality (datagrams travel in clear), and any protection from a holder
// of the key, who may sign as any sender id.
#pragma once

#include <bitset>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "icars/coros/messages.h"

namespace icars::coros {

// The fleet's secret: at least 32 random bytes, written as hex in configurations and key files.
// The bytes are wiped from memory when the key is destroyed; what() of errors never shows them.
class FleetKey {
 public:
  static constexpr std::size_t kMinBytes = 32;
  static constexpr std::size_t kMaxBytes = 1024;

  // From hex digits (white space around them ignored); throws CorosError saying what is wrong.
  static FleetKey from_hex(std::string_view hex);
  // Reads a key file holding the key as hex (`openssl rand -hex 32 > fleet.key`). Refuses a
  // file that users other than its owner may read or write; throws CorosError naming the file.
  static FleetKey load(const std::filesystem::path& file);
  // kMinBytes fresh bytes from OpenSSL's random generator.
  static FleetKey generate();

  FleetKey(const FleetKey&) = default;
  FleetKey(FleetKey&&) noexcept = default;
  FleetKey& operator=(const FleetKey&);
  FleetKey& operator=(FleetKey&&) noexcept;
  ~FleetKey();

  std::string to_hex() const;
  std::span<const std::byte> bytes() const { return bytes_; }

 private:
  explicit FleetKey(std::vector<std::byte> bytes) : bytes_(std::move(bytes)) {}
  void wipe();
  std::vector<std::byte> bytes_;
};

// Why a datagram was dropped before any handler saw it.
enum class Rejection {
  unsigned_datagram,  // version 1: no trailer at all
  bad_tag,            // the tag does not match: another key, or bytes changed on the way
  replayed,           // its generation and counter were accepted before, or are too old
};
std::string_view to_string(Rejection why);

namespace detail {
class Hmac;  // HMAC-SHA256 keyed once (OpenSSL EVP_MAC)
}

// Signs the datagrams of one agent. One object per agent process start: its generation orders
// it after every earlier start of the same agent. Not thread-safe.
class DatagramSigner {
 public:
  // generation 0 means now: the wall clock in microseconds since the Unix epoch.
  explicit DatagramSigner(const FleetKey& key, std::uint64_t generation = 0);
  ~DatagramSigner();
  DatagramSigner(DatagramSigner&&) noexcept;
  DatagramSigner& operator=(DatagramSigner&&) noexcept;

  // Makes an unsigned (version 1) datagram a signed one: sets the version to 2 and appends the
  // generation, the next counter and the tag. Throws CorosError for bytes that are not an
  // unsigned COROS datagram or that would not fit in kMaxDatagram once signed.
  void sign(std::vector<std::byte>& datagram);

  std::uint64_t generation() const { return generation_; }
  std::uint64_t counter() const { return counter_; }  // the last one used; 0 before the first

 private:
  std::unique_ptr<detail::Hmac> mac_;
  std::uint64_t generation_;
  std::uint64_t counter_ = 0;
};

// Checks received datagrams and remembers, per sender id, the newest generation and which of
// the last kReplayWindow counters it accepted, so a datagram delayed behind up to that many
// later ones of its sender is still accepted once. Not thread-safe.
class DatagramVerifier {
 public:
  static constexpr std::uint64_t kReplayWindow = 1024;

  explicit DatagramVerifier(const FleetKey& key);
  ~DatagramVerifier();
  DatagramVerifier(DatagramVerifier&&) noexcept;
  DatagramVerifier& operator=(DatagramVerifier&&) noexcept;

  // `bytes` as received and `datagram` what decode_datagram() made of them. Returns why the
  // datagram must be dropped, or nothing when it is authentic and new (its counter is then
  // recorded, so the same bytes are refused next time).
  std::optional<Rejection> verify(std::span<const std::byte> bytes, const Datagram& datagram);

  // Only the tag, without touching the replay state.
  bool tag_matches(std::span<const std::byte> bytes) const;

 private:
  struct Window {
    std::uint64_t generation = 0;
    std::uint64_t highest = 0;        // the newest counter accepted in this generation
    std::bitset<kReplayWindow> seen;  // bit i: counter highest - i was accepted
  };
  bool accept(const std::string& sender, const AuthenticationTrailer& trailer);

  std::unique_ptr<detail::Hmac> mac_;
  std::map<std::string, Window> windows_;
};

}  // namespace icars::coros
