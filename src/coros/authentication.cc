#include "icars/coros/authentication.h"

#include <fmt/format.h>
#include <openssl/core_names.h>
#include <openssl/crypto.h>
#include <openssl/err.h>
#include <openssl/evp.h>
#include <openssl/params.h>
#include <openssl/rand.h>

#include <array>
#include <chrono>
#include <fstream>
#include <sstream>

#include "icars/planet/serializer.h"

namespace icars::coros {

namespace {

std::string openssl_error() {
  const unsigned long code = ERR_get_error();
  if (code == 0) return "no OpenSSL error reported";
  std::array<char, 256> text{};
  ERR_error_string_n(code, text.data(), text.size());
  ERR_clear_error();
  return text.data();
}

// NOLINTBEGIN(cppcoreguidelines-pro-type-reinterpret-cast): OpenSSL takes unsigned char.
const unsigned char* uchars(const std::byte* p) {
  return reinterpret_cast<const unsigned char*>(p);
}
// NOLINTEND(cppcoreguidelines-pro-type-reinterpret-cast)

int hex_digit(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

bool is_space(char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r'; }

std::uint64_t wall_microseconds() {
  return static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::microseconds>(
                                        std::chrono::system_clock::now().time_since_epoch())
                                        .count());
}

}  // namespace

// --- FleetKey ------------------------------------------------------------------------------

FleetKey FleetKey::from_hex(std::string_view hex) {
  while (!hex.empty() && is_space(hex.front())) hex.remove_prefix(1);
  while (!hex.empty() && is_space(hex.back())) hex.remove_suffix(1);
  if (hex.size() % 2 != 0) {
    throw CorosError(
        fmt::format("a fleet key is hex digits in pairs; got an odd number ({})", hex.size()));
  }
  std::vector<std::byte> bytes(hex.size() / 2);
  for (std::size_t i = 0; i < bytes.size(); ++i) {
    const int hi = hex_digit(hex[2 * i]), lo = hex_digit(hex[2 * i + 1]);
    if (hi < 0 || lo < 0) {
      OPENSSL_cleanse(bytes.data(), bytes.size());
      throw CorosError(fmt::format("a fleet key is hex digits (0-9, a-f); character {} is not one",
                                   2 * i + (hi < 0 ? 1 : 2)));
    }
    bytes[i] = static_cast<std::byte>(hi * 16 + lo);
  }
  if (bytes.size() < kMinBytes || bytes.size() > kMaxBytes) {
    const std::size_t n = bytes.size();
    OPENSSL_cleanse(bytes.data(), bytes.size());
    throw CorosError(fmt::format(
        "a fleet key must be {} to {} bytes ({} to {} hex digits), got {} bytes; make one with "
        "`openssl rand -hex {}`",
        kMinBytes, kMaxBytes, 2 * kMinBytes, 2 * kMaxBytes, n, kMinBytes));
  }
  return FleetKey(std::move(bytes));
}

FleetKey FleetKey::load(const std::filesystem::path& file) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const auto status = fs::status(file, ec);
  if (ec || !fs::is_regular_file(status)) {
    throw CorosError(fmt::format("{}: cannot read the fleet key file: {}", file.string(),
                                 ec ? ec.message() : "not a regular file"));
  }
  const auto others = fs::perms::group_all | fs::perms::others_all;
  if ((status.permissions() & others) != fs::perms::none) {
    throw CorosError(fmt::format(
        "{}: the fleet key file may be read or written by other users (mode {:04o}); make it "
        "private with `chmod 600 {}`",
        file.string(), static_cast<unsigned>(status.permissions() & fs::perms::mask),
        file.string()));
  }
  std::ifstream in(file);
  if (!in) throw CorosError(fmt::format("{}: cannot read the fleet key file", file.string()));
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  try {
    FleetKey key = from_hex(text);
    OPENSSL_cleanse(text.data(), text.size());
    return key;
  } catch (const CorosError& e) {
    OPENSSL_cleanse(text.data(), text.size());
    throw CorosError(fmt::format("{}: {}", file.string(), e.what()));
  }
}

FleetKey FleetKey::generate() {
  std::vector<std::byte> bytes(kMinBytes);
  // NOLINTNEXTLINE(cppcoreguidelines-pro-type-reinterpret-cast): OpenSSL takes unsigned char.
  if (RAND_bytes(reinterpret_cast<unsigned char*>(bytes.data()), static_cast<int>(bytes.size())) !=
      1) {
    throw CorosError("cannot generate a fleet key: OpenSSL's random generator failed: " +
                     openssl_error());
  }
  return FleetKey(std::move(bytes));
}

FleetKey& FleetKey::operator=(const FleetKey& other) {
  if (this != &other) {
    wipe();
    bytes_ = other.bytes_;
  }
  return *this;
}

FleetKey& FleetKey::operator=(FleetKey&& other) noexcept {
  if (this != &other) {
    wipe();
    bytes_ = std::move(other.bytes_);
    other.bytes_.clear();
  }
  return *this;
}

FleetKey::~FleetKey() { wipe(); }

void FleetKey::wipe() {
  if (!bytes_.empty()) OPENSSL_cleanse(bytes_.data(), bytes_.size());
}

std::string FleetKey::to_hex() const {
  static constexpr char kDigits[] = "0123456789abcdef";
  std::string out;
  out.reserve(bytes_.size() * 2);
  for (const std::byte b : bytes_) {
    const auto v = std::to_integer<unsigned>(b);
    out.push_back(kDigits[v >> 4]);
    out.push_back(kDigits[v & 15]);
  }
  return out;
}

std::string_view to_string(Rejection why) {
  switch (why) {
    case Rejection::unsigned_datagram:
      return "unsigned";
    case Rejection::bad_tag:
      return "bad_tag";
    case Rejection::replayed:
      return "replayed";
  }
  return "rejected";
}

// --- HMAC ----------------------------------------------------------------------------------

namespace detail {

// A context keyed once with HMAC-SHA256; every tag is computed on a copy of it, so the key
// schedule is done once per agent, not per datagram.
class Hmac {
 public:
  static constexpr std::size_t kSize = 32;

  explicit Hmac(std::span<const std::byte> key) {
    EVP_MAC* mac = EVP_MAC_fetch(nullptr, "HMAC", nullptr);
    if (mac == nullptr) throw CorosError("OpenSSL offers no HMAC: " + openssl_error());
    ctx_ = EVP_MAC_CTX_new(mac);
    EVP_MAC_free(mac);  // the context keeps its own reference
    if (ctx_ == nullptr) throw CorosError("cannot create an HMAC context: " + openssl_error());
    char digest[] = "SHA256";
    const OSSL_PARAM params[] = {OSSL_PARAM_construct_utf8_string(OSSL_MAC_PARAM_DIGEST, digest, 0),
                                 OSSL_PARAM_construct_end()};
    if (EVP_MAC_init(ctx_, uchars(key.data()), key.size(), params) != 1) {
      EVP_MAC_CTX_free(ctx_);
      throw CorosError("cannot key HMAC-SHA256: " + openssl_error());
    }
  }
  ~Hmac() { EVP_MAC_CTX_free(ctx_); }
  Hmac(const Hmac&) = delete;
  Hmac& operator=(const Hmac&) = delete;

  std::array<std::byte, kSize> tag(std::span<const std::byte> data) const {
    std::array<std::byte, kSize> out{};
    EVP_MAC_CTX* ctx = EVP_MAC_CTX_dup(ctx_);
    std::size_t length = 0;
    // NOLINTNEXTLINE(cppcoreguidelines-pro-type-reinterpret-cast): OpenSSL takes unsigned char.
    auto* o = reinterpret_cast<unsigned char*>(out.data());
    const bool ok = ctx != nullptr && EVP_MAC_update(ctx, uchars(data.data()), data.size()) == 1 &&
                    EVP_MAC_final(ctx, o, &length, out.size()) == 1 && length == kSize;
    EVP_MAC_CTX_free(ctx);
    if (!ok) throw CorosError("HMAC-SHA256 failed: " + openssl_error());
    return out;
  }

 private:
  EVP_MAC_CTX* ctx_ = nullptr;
};

}  // namespace detail

// --- DatagramSigner ------------------------------------------------------------------------

DatagramSigner::DatagramSigner(const FleetKey& key, std::uint64_t generation)
    : mac_(std::make_unique<detail::Hmac>(key.bytes())),
      generation_(generation != 0 ? generation : wall_microseconds()) {}

DatagramSigner::~DatagramSigner() = default;
DatagramSigner::DatagramSigner(DatagramSigner&&) noexcept = default;
DatagramSigner& DatagramSigner::operator=(DatagramSigner&&) noexcept = default;

void DatagramSigner::sign(std::vector<std::byte>& datagram) {
  if (datagram.size() < 3 || datagram[0] != std::byte{'C'} || datagram[1] != std::byte{'R'} ||
      datagram[2] != std::byte{kProtocolVersion}) {
    throw CorosError("only an unsigned COROS datagram (version 1) can be signed");
  }
  if (datagram.size() + kAuthTrailerSize > kMaxDatagram) {
    throw CorosError(fmt::format("a datagram of {} bytes does not fit in {} once signed",
                                 datagram.size(), kMaxDatagram));
  }
  datagram[2] = std::byte{kAuthenticatedVersion};
  planet::Writer w(datagram);
  w.u64(generation_);
  w.u64(++counter_);
  const auto tag = mac_->tag(datagram);
  datagram.insert(datagram.end(), tag.begin(), tag.begin() + kAuthTagSize);
}

// --- DatagramVerifier ----------------------------------------------------------------------

DatagramVerifier::DatagramVerifier(const FleetKey& key)
    : mac_(std::make_unique<detail::Hmac>(key.bytes())) {}

DatagramVerifier::~DatagramVerifier() = default;
DatagramVerifier::DatagramVerifier(DatagramVerifier&&) noexcept = default;
DatagramVerifier& DatagramVerifier::operator=(DatagramVerifier&&) noexcept = default;

bool DatagramVerifier::tag_matches(std::span<const std::byte> bytes) const {
  if (bytes.size() < kAuthTrailerSize) return false;
  const auto covered = bytes.first(bytes.size() - kAuthTagSize);
  const auto tag = mac_->tag(covered);
  return CRYPTO_memcmp(tag.data(), bytes.data() + covered.size(), kAuthTagSize) == 0;
}

std::optional<Rejection> DatagramVerifier::verify(std::span<const std::byte> bytes,
                                                  const Datagram& datagram) {
  if (!datagram.authentication) return Rejection::unsigned_datagram;
  if (!tag_matches(bytes)) return Rejection::bad_tag;
  // Only now, with the sender and counter known to come from a key holder, is state touched.
  if (!accept(datagram.sender, *datagram.authentication)) return Rejection::replayed;
  return std::nullopt;
}

bool DatagramVerifier::accept(const std::string& sender, const AuthenticationTrailer& trailer) {
  auto [it, added] = windows_.try_emplace(sender);
  Window& w = it->second;
  if (added || trailer.generation > w.generation) {  // first heard, or the sender restarted
    w.generation = trailer.generation;
    w.highest = trailer.counter;
    w.seen.reset();
    w.seen.set(0);
    return true;
  }
  if (trailer.generation < w.generation) return false;  // an earlier start of the sender
  if (trailer.counter > w.highest) {
    const std::uint64_t shift = trailer.counter - w.highest;
    if (shift >= kReplayWindow) {
      w.seen.reset();
    } else {
      w.seen <<= static_cast<std::size_t>(shift);
    }
    w.seen.set(0);
    w.highest = trailer.counter;
    return true;
  }
  const std::uint64_t age = w.highest - trailer.counter;
  if (age >= kReplayWindow) return false;  // older than the window: cannot tell, so refuse
  const auto bit = static_cast<std::size_t>(age);
  if (w.seen.test(bit)) return false;
  w.seen.set(bit);
  return true;
}

}  // namespace icars::coros
