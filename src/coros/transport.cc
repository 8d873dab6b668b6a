#include "icars/coros/transport.h"

#include <fmt/format.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <array>
#include <asio/ip/address.hpp>
#include <asio/socket_base.hpp>
#include <atomic>
#include <charconv>
#include <chrono>
#include <map>
#include <mutex>
#include <sstream>
#include <utility>

namespace icars::coros {

namespace {

double parse_probability(const std::string& key, const std::string& value) {
  double v = 0;
  const auto [end, ec] = std::from_chars(value.data(), value.data() + value.size(), v);
  if (ec != std::errc{} || end != value.data() + value.size() || !(v >= 0 && v <= 1)) {
    throw CorosError(
        fmt::format("fault injection: {}={} must be a probability from 0 to 1", key, value));
  }
  return v;
}

template <class T>
T parse_integer(const std::string& key, const std::string& value) {
  T v{};
  const auto [end, ec] = std::from_chars(value.data(), value.data() + value.size(), v);
  if (ec != std::errc{} || end != value.data() + value.size()) {
    throw CorosError(fmt::format("fault injection: {}={} must be a whole number", key, value));
  }
  return v;
}

// An id as a log may show it: the sender id is whatever a stranger put there, so control
// characters and non-ASCII bytes are escaped and it is cut at 64 characters.
std::string printable(std::string_view text) {
  std::string out;
  for (const char c : text.substr(0, 64)) {
    const auto u = static_cast<unsigned char>(c);
    if (u >= 0x20 && u < 0x7f && c != '\\') {
      out.push_back(c);
    } else {
      out += fmt::format("\\x{:02x}", u);
    }
  }
  if (text.size() > 64) out += "...";
  return out;
}

std::string_view explain(Rejection why) {
  switch (why) {
    case Rejection::unsigned_datagram:
      return "it is unsigned (its sender has no fleet key, or runs with 'insecure')";
    case Rejection::bad_tag:
      return "its authentication tag does not match (another fleet key, or bytes changed on the "
             "way)";
    case Rejection::replayed:
      return "it was replayed (this generation and counter were accepted before, or are too old)";
  }
  return "it failed authentication";
}

}  // namespace

FaultInjection FaultInjection::parse(const std::string& spec) {
  FaultInjection f;
  std::stringstream in(spec);
  std::string item;
  while (std::getline(in, item, ',')) {
    if (item.empty()) continue;
    const auto eq = item.find('=');
    if (eq == std::string::npos) {
      throw CorosError(fmt::format("fault injection: '{}' is not key=value", item));
    }
    const std::string key = item.substr(0, eq), value = item.substr(eq + 1);
    if (key == "drop")
      f.drop = parse_probability(key, value);
    else if (key == "duplicate")
      f.duplicate = parse_probability(key, value);
    else if (key == "delay")
      f.delay = parse_probability(key, value);
    else if (key == "max_delay_ms")
      f.max_delay_ms = parse_integer<int>(key, value);
    else if (key == "seed")
      f.seed = parse_integer<std::uint64_t>(key, value);
    else {
      throw CorosError(fmt::format(
          "fault injection: unknown key '{}' (expected drop, duplicate, delay, max_delay_ms, seed)",
          key));
    }
  }
  if (f.max_delay_ms < 1) throw CorosError("fault injection: max_delay_ms must be at least 1");
  return f;
}

std::string FaultInjection::spec() const {
  // {} is the shortest text that reads back as the same double.
  return fmt::format("drop={},duplicate={},delay={},max_delay_ms={},seed={}", drop, duplicate,
                     delay, max_delay_ms, seed);
}

struct UdpTransport::Impl : std::enable_shared_from_this<UdpTransport::Impl> {
  Impl(asio::io_context& io_context, const TransportOptions& options)
      : io(io_context),
        unicast(io_context),
        group(io_context),
        rng(options.faults.seed),
        faults(options.faults),
        log(options.logger
                ? options.logger
                : std::make_shared<spdlog::logger>(
                      "coros", std::make_shared<spdlog::sinks::stderr_color_sink_mt>())) {
    if (options.key) {
      signer.emplace(*options.key);
      verifier.emplace(*options.key);
    }
  }

  asio::io_context& io;
  asio::ip::udp::socket unicast;
  asio::ip::udp::socket group;
  asio::ip::udp::endpoint broadcast_to;
  asio::ip::udp::endpoint self;
  Receiver on_datagram;
  ErrorSink on_error;
  std::mt19937_64 rng;
  FaultInjection faults;
  mutable std::mutex stats_mutex;
  TransportStats stats;
  bool closed = false;
  std::shared_ptr<spdlog::logger> log;
  std::mutex sign_mutex;                     // send_to() may be called from any thread
  std::optional<DatagramSigner> signer;      // with a key
  std::optional<DatagramVerifier> verifier;  // with a key; on the io_context only
  // Rejection warnings per source address: when the last was logged, how many since.
  struct Warned {
    std::chrono::steady_clock::time_point at;
    std::uint64_t suppressed = 0;
  };
  std::map<asio::ip::udp::endpoint, Warned> warned;

  struct Receive {
    asio::ip::udp::socket* socket;
    std::array<std::byte, kMaxDatagram + 1> buffer{};
    asio::ip::udp::endpoint from;
  };

  void count(std::uint64_t TransportStats::*field) {
    std::lock_guard lock(stats_mutex);
    ++(stats.*field);
  }

  // Counts a dropped datagram by reason, in total and for its source address.
  void count_drop(std::uint64_t TransportStats::*total,
                  std::uint64_t TransportStats::SourceDrops::*by_source,
                  const asio::ip::udp::endpoint& from) {
    std::string source = from.address().to_string();
    std::lock_guard lock(stats_mutex);
    ++(stats.*total);
    auto& sources = stats.dropped_by_source;
    auto it = sources.find(source);
    if (it == sources.end()) {
      if (sources.size() >= TransportStats::kMaxDropSources) source = "other";
      it = sources.try_emplace(std::move(source)).first;
    }
    ++(it->second.*by_source);
  }

  void receive(const std::shared_ptr<Receive>& r) {
    r->socket->async_receive_from(
        asio::buffer(r->buffer), r->from,
        [self = shared_from_this(), r](const std::error_code& ec, std::size_t n) {
          if (self->closed || ec == asio::error::operation_aborted) return;
          if (!ec) self->deliver(std::span<const std::byte>(r->buffer.data(), n), r->from);
          self->receive(r);
        });
  }

  void deliver(std::span<const std::byte> bytes, const asio::ip::udp::endpoint& from) {
    if (from.port() == self.port() &&
        (from.address() == self.address() || self.address().is_unspecified())) {
      return;  // our own broadcast, heard back
    }
    Datagram d;
    try {
      d = decode_datagram(bytes);
    } catch (const CorosError& e) {
      count_drop(&TransportStats::malformed, &TransportStats::SourceDrops::malformed, from);
      if (on_error) on_error(e.what(), from);
      return;
    }
    if (verifier) {
      std::optional<Rejection> why;
      try {
        why = verifier->verify(bytes, d);
      } catch (const CorosError& e) {  // OpenSSL failed: nothing to trust either
        log->error("cannot check a datagram from {}: {}", describe(from), e.what());
        why = Rejection::bad_tag;
      }
      if (why) {
        reject(*why, d, from);
        return;
      }
    }
    count(&TransportStats::received);
    if (on_datagram) on_datagram(d, from);
  }

  static std::string describe(const asio::ip::udp::endpoint& e) {
    return fmt::format("{}:{}", e.address().to_string(), e.port());
  }

  // Counts the datagram and warns, at most once a second per source address.
  void reject(Rejection why, const Datagram& d, const asio::ip::udp::endpoint& from) {
    using Drops = TransportStats::SourceDrops;
    if (why == Rejection::unsigned_datagram) {
      count_drop(&TransportStats::rejected_unsigned, &Drops::rejected_unsigned, from);
    } else if (why == Rejection::bad_tag) {
      count_drop(&TransportStats::rejected_bad_tag, &Drops::rejected_bad_tag, from);
    } else {
      count_drop(&TransportStats::rejected_replayed, &Drops::rejected_replayed, from);
    }
    const auto now = std::chrono::steady_clock::now();
    auto it = warned.find(from);
    if (it != warned.end() && now - it->second.at < std::chrono::seconds(1)) {
      ++it->second.suppressed;
      return;
    }
    if (it == warned.end()) {
      if (warned.size() >= 4096) {  // many source addresses: forget those quiet for a second
        std::erase_if(warned,
                      [&](const auto& w) { return now - w.second.at >= std::chrono::seconds(1); });
      }
      it = warned.emplace(from, Warned{}).first;
    }
    const std::uint64_t suppressed = std::exchange(it->second.suppressed, 0);
    it->second.at = now;
    log->warn("dropped a {} from {} claiming to be '{}': {}{}", to_string(d.code), describe(from),
              printable(d.sender), explain(why),
              suppressed == 0 ? std::string()
                              : fmt::format(" ({} more dropped from there before this, not logged)",
                                            suppressed));
  }

  void transmit(const asio::ip::udp::endpoint& to,
                const std::shared_ptr<std::vector<std::byte>>& bytes) {
    unicast.async_send_to(
        asio::buffer(*bytes), to,
        [self = shared_from_this(), bytes](const std::error_code& ec, std::size_t) {
          if (ec && ec != asio::error::operation_aborted) {
            self->count(&TransportStats::send_errors);
          } else if (!ec) {
            self->count(&TransportStats::sent);
          }
        });
  }

  // Applies the fault injection hook, then transmits; on the io_context.
  void send(const asio::ip::udp::endpoint& to, std::shared_ptr<std::vector<std::byte>> bytes) {
    if (closed) return;
    if (!faults.active()) {
      transmit(to, bytes);
      return;
    }
    std::uniform_real_distribution<double> p(0, 1);
    if (p(rng) < faults.drop) {
      count(&TransportStats::dropped_by_hook);
      return;
    }
    const int copies = p(rng) < faults.duplicate ? 2 : 1;
    if (copies == 2) count(&TransportStats::duplicated_by_hook);
    for (int i = 0; i < copies; ++i) {
      if (p(rng) < faults.delay) {
        count(&TransportStats::delayed_by_hook);
        std::uniform_int_distribution<int> ms(1, faults.max_delay_ms);
        auto timer = std::make_shared<asio::steady_timer>(io, std::chrono::milliseconds(ms(rng)));
        timer->async_wait([self = shared_from_this(), timer, to, bytes](const std::error_code& ec) {
          if (!ec && !self->closed) self->transmit(to, bytes);
        });
      } else {
        transmit(to, bytes);
      }
    }
  }
};

UdpTransport::UdpTransport(asio::io_context& io, TransportOptions options)
    : impl_(std::make_shared<Impl>(io, options)), options_(std::move(options)) {
  if (!options_.key && !options_.insecure) {
    throw CorosError(
        "no fleet key: an agent signs and checks every datagram with the fleet's shared key; set "
        "'key_file' (a file holding the key as hex, made once with `openssl rand -hex 32`) or "
        "'key' in the configuration, or 'insecure': true to run without authentication");
  }
  if (options_.key && options_.insecure) {
    throw CorosError("'insecure' is set together with a fleet key: remove one of them");
  }
  std::error_code ec;
  const auto ip = asio::ip::make_address(options_.ip, ec);
  if (ec) throw CorosError(fmt::format("agent address '{}' is not an IPv4 address", options_.ip));
  const auto bcast = asio::ip::make_address(options_.broadcast_address, ec);
  if (ec || !bcast.is_v4()) {
    throw CorosError(
        fmt::format("broadcast address '{}' is not an IPv4 address", options_.broadcast_address));
  }
  impl_->unicast.open(asio::ip::udp::v4());
  impl_->unicast.set_option(asio::socket_base::broadcast(true));
  impl_->unicast.bind({ip, options_.port}, ec);
  if (ec) {
    throw CorosError(fmt::format("cannot bind the agent socket to {}:{}: {}", options_.ip,
                                 options_.port, ec.message()));
  }
  impl_->self = impl_->unicast.local_endpoint();
  impl_->group.open(asio::ip::udp::v4());
  impl_->group.set_option(asio::socket_base::reuse_address(true));
  // A fleet's HELLOs and bids arrive in bursts; the default receive buffer (about 200 KiB)
  // overflows when an agent's thread is busy for a moment (the kernel caps the request at
  // net.core.rmem_max; a smaller buffer only means more datagrams dropped, which the protocol
  // tolerates).
  impl_->unicast.set_option(asio::socket_base::receive_buffer_size(4 << 20), ec);
  impl_->group.set_option(asio::socket_base::receive_buffer_size(4 << 20), ec);
  impl_->group.bind({asio::ip::address_v4::any(), options_.broadcast_port}, ec);
  if (ec) {
    throw CorosError(fmt::format("cannot bind the fleet's broadcast port {}: {}",
                                 options_.broadcast_port, ec.message()));
  }
  impl_->broadcast_to = {bcast, options_.broadcast_port};
}

UdpTransport::~UdpTransport() { close(); }

void UdpTransport::start(Receiver on_datagram, ErrorSink on_error) {
  impl_->on_datagram = std::move(on_datagram);
  impl_->on_error = std::move(on_error);
  if (options_.insecure) {
    impl_->log->warn(
        "INSECURE: agent socket {} runs without a fleet key: datagrams are neither signed nor "
        "checked, so any host that reaches port {} can forge HELLOs, bids and awards",
        Impl::describe(impl_->self), options_.broadcast_port);
  }
  auto unicast = std::make_shared<Impl::Receive>();
  unicast->socket = &impl_->unicast;
  auto group = std::make_shared<Impl::Receive>();
  group->socket = &impl_->group;
  impl_->receive(unicast);
  impl_->receive(group);
}

void UdpTransport::close() {
  if (impl_->closed) return;
  impl_->closed = true;
  std::error_code ec;
  impl_->unicast.close(ec);
  impl_->group.close(ec);
}

void UdpTransport::send_to(const asio::ip::udp::endpoint& to, std::vector<std::byte> datagram) {
  if (impl_->signer) {
    std::lock_guard lock(impl_->sign_mutex);
    impl_->signer->sign(datagram);
  }
  auto bytes = std::make_shared<std::vector<std::byte>>(std::move(datagram));
  asio::post(impl_->io, [impl = impl_, to, bytes] { impl->send(to, bytes); });
}

void UdpTransport::broadcast(std::vector<std::byte> datagram) {
  send_to(impl_->broadcast_to, std::move(datagram));
}

asio::ip::udp::endpoint UdpTransport::local_endpoint() const { return impl_->self; }

TransportStats UdpTransport::stats() const {
  std::lock_guard lock(impl_->stats_mutex);
  return impl_->stats;
}

std::uint16_t free_udp_port() {
  asio::io_context io;
  asio::ip::udp::socket socket(io);
  asio::error_code error;
  socket.open(asio::ip::udp::v4(), error);
  if (!error) socket.bind(asio::ip::udp::endpoint(asio::ip::udp::v4(), 0), error);
  if (error) throw CorosError(fmt::format("cannot find a free UDP port: {}", error.message()));
  return socket.local_endpoint().port();
}

}  // namespace icars::coros
