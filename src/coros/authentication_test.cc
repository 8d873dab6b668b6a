// Message authentication, as a stranger on the network meets it: agents on real loopback UDP
// sockets with a fleet key, and a "stranger" socket that hears the fleet's broadcasts (they are
// not encrypted) and sends what it likes. A forged BID with the lowest price does not win the
// auction, a forged HELLO adds no neighbour, a recorded datagram replayed or altered in one
// byte is dropped, a restarted agent is accepted again, and a configuration without a key is
// refused. The same forgery against an insecure fleet wins, which shows the tests can fail.
#include "icars/coros/authentication.h"

#include <gtest/gtest.h>
#include <spdlog/sinks/ringbuffer_sink.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <asio/io_context.hpp>
#include <asio/ip/udp.hpp>
#include <atomic>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <thread>

#include "child_process.h"
#include "fleet.h"
#include "icars/coros/agent.h"
#include "icars/coros/courier.h"
#include "icars/coros/discovery.h"

namespace icars::coros {
namespace {

using namespace std::chrono_literals;
using planet_test::wait_until;

const std::string kMap = std::string(ICARS_HOUSES_DIR) + "/paper_house.xml";

// A host on the network without the fleet key: it hears every broadcast on the fleet's port
// and sends raw datagrams from a socket of its own.
class Stranger {
 public:
  using Listener =
      std::function<void(const std::vector<std::byte>&, const asio::ip::udp::endpoint&)>;

  explicit Stranger(std::uint16_t fleet_port)
      : fleet_port_(fleet_port), listen_(io_), send_(io_, {asio::ip::udp::v4(), 0}) {
    listen_.open(asio::ip::udp::v4());
    listen_.set_option(asio::socket_base::reuse_address(true));
    listen_.bind({asio::ip::address_v4::any(), fleet_port});
    send_.set_option(asio::socket_base::broadcast(true));
    receive();
    thread_ = std::thread([this] { io_.run(); });
  }
  ~Stranger() {
    io_.stop();
    thread_.join();
  }

  // Called on the stranger's thread for every broadcast heard.
  void on_broadcast(Listener l) {
    std::lock_guard lock(mutex_);
    listener_ = std::move(l);
  }
  // Every broadcast heard so far.
  std::vector<std::vector<std::byte>> heard() const {
    std::lock_guard lock(mutex_);
    return heard_;
  }
  void send(const std::vector<std::byte>& bytes, const asio::ip::udp::endpoint& to) {
    std::lock_guard lock(send_mutex_);
    send_.send_to(asio::buffer(bytes), to);
  }
  void broadcast(const std::vector<std::byte>& bytes) {
    send(bytes, {asio::ip::make_address("127.255.255.255"), fleet_port_});
  }

 private:
  void receive() {
    listen_.async_receive_from(
        asio::buffer(buffer_), from_, [this](const std::error_code& ec, std::size_t n) {
          if (ec) return;
          std::vector<std::byte> bytes(buffer_.begin(),
                                       buffer_.begin() + static_cast<std::ptrdiff_t>(n));
          Listener l;
          {
            std::lock_guard lock(mutex_);
            heard_.push_back(bytes);
            l = listener_;
          }
          if (l) l(bytes, from_);
          receive();
        });
  }

  std::uint16_t fleet_port_;
  asio::io_context io_;
  asio::ip::udp::socket listen_, send_;
  std::array<std::byte, kMaxDatagram + 1> buffer_{};
  asio::ip::udp::endpoint from_;
  mutable std::mutex mutex_, send_mutex_;
  Listener listener_;
  std::vector<std::vector<std::byte>> heard_;
  std::thread thread_;
};

class Authentication : public ::testing::Test, protected coros_test::FleetBase {
 protected:
  Authentication() : FleetBase(kMap) {
    logger_ = std::make_shared<spdlog::logger>("coros-test", log_sink_);
    bid_window_ = 1500ms;
  }
  std::vector<nlohmann::json> events(const std::string& kind) { return log_.find(kind); }
  std::vector<std::string> log_lines() { return log_sink_->last_formatted(); }
  void TearDown() override { stop_all(); }

  std::shared_ptr<spdlog::sinks::ringbuffer_sink_mt> log_sink_ =
      std::make_shared<spdlog::sinks::ringbuffer_sink_mt>(1000);
};

// The user, two bidding robots and a robot that never bids, so the round stays open for its
// whole bid window and a forged bid, whenever it arrives, is in time. The stranger answers
// every AUCTION it hears with BIDs of 1 cm: unsigned, and signed with a key of its own, as
// itself and in robot2's name.
TEST_F(Authentication, ForgedBidsDoNotWinTheAuction) {
  add_robot("robot1", 1.0, 1.5);
  add_robot("robot2", 3.0, 2.0);
  add_agent(config("robot3", "robot"));  // a robot that never bids: rounds run their window
  Agent& user_agent = add_agent(config("user", "user"));
  auto user = std::make_shared<CourierUserOperator>(map_);
  user_agent.add_operator(user);

  Stranger stranger(port_);
  DatagramSigner wrong_key(FleetKey::generate());
  std::atomic<int> auctions_heard{0};
  stranger.on_broadcast(
      [&](const std::vector<std::byte>& bytes, const asio::ip::udp::endpoint& from) {
        const Datagram d = decode_datagram(bytes);  // broadcasts are readable without the key
        if (d.code != MessageCode::auction) return;
        const auto auction = d.body_as<AuctionMessage>();
        ++auctions_heard;
        for (const std::string name : {"intruder", "robot2"}) {
          const BidMessage bid{auction.task_id, auction.round, name, 0.01};
          stranger.send(encode_datagram(name, bid), from);  // no tag
          auto forged = encode_datagram(name, bid);
          wrong_key.sign(forged);  // a tag, with the wrong key
          stranger.send(forged, from);
        }
      });

  for (auto& a : agents_) a->start();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  const auto task =
      user_agent.call([&] { return user->request("living_room_center", "bedroom_window"); });
  ASSERT_TRUE(
      wait_until([&] { return user_agent.call([&] { return user->all_finished(); }); }, 60s));
  const auto record = user_agent.call([&] { return user->deliveries().at(task); });

  ASSERT_GT(auctions_heard.load(), 0) << "the stranger never heard the auction";
  EXPECT_TRUE(record.success) << record.detail;
  EXPECT_TRUE(record.robot == "robot1" || record.robot == "robot2") << record.robot;
  EXPECT_FALSE(record.bids.contains("intruder"));
  ASSERT_TRUE(record.bids.contains("robot2"));
  EXPECT_GT(record.bids.at("robot2"), 1.0);  // robot2's own bid, not the forged 1 cm
  for (const auto& e : events("awarded")) EXPECT_NE(e["robot"], "intruder") << e.dump();
  const TransportStats s = user_agent.stats();
  EXPECT_GE(s.rejected_unsigned, 2u);
  EXPECT_GE(s.rejected_bad_tag, 2u);
  EXPECT_EQ(user_agent.bad_datagrams(), 0u);  // dropped before decoding the body
  // Logged (once a second per source address, so not every reason shows), naming the claim.
  bool logged = false;
  for (const auto& line : log_lines()) {
    logged = logged || (line.find("dropped a BID from 127.0.0.1:") != std::string::npos &&
                        line.find("claiming to be '") != std::string::npos);
  }
  EXPECT_TRUE(logged);
}

// The control: without authentication the same stranger wins with its unsigned 1 cm bid.
TEST_F(Authentication, InsecureFleetIsWonByTheForgedBid) {
  insecure_ = true;
  add_robot("robot1", 1.0, 1.5);
  add_agent(config("robot3", "robot"));
  Agent& user_agent = add_agent(config("user", "user"));
  auto user = std::make_shared<CourierUserOperator>(map_);
  user_agent.add_operator(user);
  Stranger stranger(port_);
  stranger.on_broadcast([&](const std::vector<std::byte>& bytes,
                            const asio::ip::udp::endpoint& from) {
    const Datagram d = decode_datagram(bytes);
    if (d.code != MessageCode::auction) return;
    const auto auction = d.body_as<AuctionMessage>();
    stranger.send(
        encode_datagram("intruder", BidMessage{auction.task_id, auction.round, "intruder", 0.01}),
        from);
  });
  for (auto& a : agents_) a->start();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  user_agent.call([&] { return user->request("living_room_center", "bedroom_window"); });
  ASSERT_TRUE(wait_until([&] { return !events("awarded").empty(); }, 30s));
  EXPECT_EQ(events("awarded")[0]["robot"], "intruder");
  bool warned = false;
  for (const auto& line : log_lines())
    warned = warned || line.find("INSECURE") != std::string::npos;
  EXPECT_TRUE(warned);
  EXPECT_EQ(events("started")[0]["authentication"], "none");
}

TEST_F(Authentication, ForgedHellosAddNoNeighbourAndAreLoggedOncePerSecond) {
  Agent& a = add_agent(config("agent1", "robot"));
  Agent& b = add_agent(config("agent2", "robot"));
  for (auto& x : agents_) x->start();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  const auto b_port = b.call([&] { return b.transport().local_endpoint().port(); });

  Stranger stranger(port_);
  DatagramSigner wrong_key(FleetKey::generate());
  const auto started = std::chrono::steady_clock::now();
  constexpr int kRounds = 20;
  for (int i = 0; i < kRounds; ++i) {
    // A ghost, and an impersonation of agent2 pointing replies at the stranger.
    const HelloMessage ghost{"ghost", "127.0.0.1", 9, "robot", "idle", Agent::wall_seconds() + 60,
                             0,       0,           0};
    HelloMessage fake_b = ghost;
    fake_b.id = "agent2";
    stranger.broadcast(encode_datagram("ghost", ghost));
    auto signed_ghost = encode_datagram("ghost", ghost);
    wrong_key.sign(signed_ghost);
    stranger.broadcast(signed_ghost);
    auto signed_b = encode_datagram("agent2", fake_b);
    wrong_key.sign(signed_b);
    stranger.broadcast(signed_b);
  }
  ASSERT_TRUE(wait_until(
      [&] {
        const auto s = a.stats();
        return s.rejected_unsigned >= kRounds && s.rejected_bad_tag >= 2 * kRounds;
      },
      20s));
  const double elapsed =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  // Every forged datagram was counted as dropped, so none reached the neighbour table.
  EXPECT_EQ(a.call([&] { return a.neighbors().find("ghost"); }), nullptr);
  EXPECT_EQ(a.call([&] { return a.neighbors().size(); }), 1u);
  EXPECT_EQ(a.call([&] { return a.neighbors().find("agent2")->port; }), b_port);
  EXPECT_EQ(a.bad_datagrams(), 0u);

  // 60 datagrams from one address: warned at most once a second (each agent has its own
  // transport; both log into the same sink).
  int warnings = 0;
  for (const auto& line : log_lines()) {
    if (line.find("dropped a HELLO") != std::string::npos) {
      ++warnings;
      EXPECT_NE(line.find("[warning]"), std::string::npos) << line;
    }
  }
  EXPECT_GE(warnings, 2);  // both agents
  EXPECT_LE(warnings, 2 * (static_cast<int>(elapsed) + 2)) << elapsed << " s";
}

TEST_F(Authentication, ReplayedDatagramsAreDropped) {
  Agent& a = add_agent(config("agent1", "robot"));
  add_agent(config("agent2", "robot"));
  Stranger stranger(port_);  // records everything broadcast, agent2's signed HELLOs included
  for (auto& x : agents_) x->start();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  const auto hellos_of_agent2 = [&] {
    std::vector<std::vector<std::byte>> out;
    for (const auto& bytes : stranger.heard()) {
      const Datagram d = decode_datagram(bytes);
      if (d.sender == "agent2" && d.code == MessageCode::hello) out.push_back(bytes);
    }
    return out;
  };
  ASSERT_TRUE(wait_until([&] { return hellos_of_agent2().size() >= 3; }, 20s));
  agents_[1]->stop();
  ASSERT_TRUE(wait_until(
      [&] { return a.call([&] { return a.neighbors().find("agent2") == nullptr; }); }, 20s));

  const auto hellos = hellos_of_agent2();
  // Played back, the dead agent2's HELLOs would bring it back to life.
  const auto a_endpoint = a.call([&] { return a.transport().local_endpoint(); });
  const auto before = a.stats().rejected_replayed;
  for (const auto& h : hellos) {
    stranger.broadcast(h);
    stranger.send(h, a_endpoint);
  }
  ASSERT_TRUE(
      wait_until([&] { return a.stats().rejected_replayed >= before + 2 * hellos.size(); }, 20s));
  EXPECT_EQ(a.call([&] { return a.neighbors().find("agent2"); }), nullptr);
  EXPECT_EQ(a.stats().rejected_bad_tag, 0u);
}

TEST_F(Authentication, OneChangedByteIsDetected) {
  Agent& a = add_agent(config("agent1", "robot"));
  add_agent(config("agent2", "robot"));
  Stranger stranger(port_);
  for (auto& x : agents_) x->start();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  // agent2's latest HELLO, moved 100 m east by changing one byte of its x coordinate: the
  // first byte of the double, 8 + 8 + 4 + 8 bytes before the trailer.
  std::vector<std::byte> hello;
  ASSERT_TRUE(wait_until([&] {
    for (const auto& bytes : stranger.heard()) {
      if (decode_datagram(bytes).sender == "agent2") hello = bytes;
    }
    return !hello.empty();
  }));
  const std::size_t x_at = hello.size() - kAuthTrailerSize - 4 - 8 - 8;
  auto moved = hello;
  moved[x_at] ^= std::byte{0x40};
  EXPECT_NE(decode_datagram(moved).body_as<HelloMessage>().x,
            decode_datagram(hello).body_as<HelloMessage>().x);
  auto recounted = hello;  // a fresh counter, to pass the replay check
  recounted[hello.size() - kAuthTagSize - 1] ^= std::byte{0x7f};
  const auto before = a.stats().rejected_bad_tag;
  stranger.broadcast(moved);
  stranger.broadcast(recounted);
  ASSERT_TRUE(wait_until([&] { return a.stats().rejected_bad_tag >= before + 2; }, 20s));
  EXPECT_NEAR(a.call([&] { return a.neighbors().find("agent2")->x; }), 0.0, 1e-9);
}

TEST_F(Authentication, RestartedAgentIsAcceptedAgain) {
  Agent& a = add_agent(config("agent1", "robot"));
  add_agent(config("agent2", "robot"));
  for (auto& x : agents_) x->start();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  agents_[1]->stop();
  // Restarted at once, before agent1 forgets it: a new generation on a new port.
  Agent& again = add_agent(config("agent2", "robot"));
  again.start();
  const auto port = again.call([&] { return again.transport().local_endpoint().port(); });
  ASSERT_TRUE(wait_until(
      [&] {
        return a.call([&] {
          const auto* n = a.neighbors().find("agent2");
          return n != nullptr && n->port == port;
        });
      },
      20s));
  EXPECT_EQ(a.stats().rejected_replayed, 0u);
}

// --- The pieces, without sockets ----------------------------------------------------------

std::vector<std::byte> hello_from(const std::string& id) {
  return encode_datagram(id, HelloMessage{id, "127.0.0.1", 1, "robot", "idle", 1, 2, 3, 0});
}

TEST(DatagramAuthentication, SignedDatagramsDecodeAndVerify) {
  const FleetKey key = FleetKey::generate();
  DatagramSigner signer(key, 1000);
  DatagramVerifier verifier(key);
  auto bytes = hello_from("robot1");
  const std::size_t unsigned_size = bytes.size();
  signer.sign(bytes);
  EXPECT_EQ(bytes.size(), unsigned_size + kAuthTrailerSize);
  const Datagram d = decode_datagram(bytes);
  ASSERT_TRUE(d.authentication);
  EXPECT_EQ(d.authentication->generation, 1000u);
  EXPECT_EQ(d.authentication->counter, 1u);
  EXPECT_EQ(d.body_as<HelloMessage>().x, 2.0);  // the body stops before the trailer
  EXPECT_EQ(verifier.verify(bytes, d), std::nullopt);
  EXPECT_EQ(verifier.verify(bytes, d), Rejection::replayed);  // the same bytes again
  EXPECT_THROW(signer.sign(bytes), CorosError);               // signed already

  const auto plain = hello_from("robot1");
  EXPECT_EQ(verifier.verify(plain, decode_datagram(plain)), Rejection::unsigned_datagram);
  DatagramVerifier other(FleetKey::generate());
  auto again = hello_from("robot1");
  signer.sign(again);
  EXPECT_EQ(other.verify(again, decode_datagram(again)), Rejection::bad_tag);
}

TEST(DatagramAuthentication, EveryChangedByteIsRejected) {
  const FleetKey key = FleetKey::generate();
  DatagramSigner signer(key);
  auto genuine = hello_from("robot1");
  signer.sign(genuine);
  for (std::size_t i = 0; i < genuine.size(); ++i) {
    for (const std::byte flip : {std::byte{0x01}, std::byte{0x80}}) {
      auto bytes = genuine;
      bytes[i] ^= flip;
      DatagramVerifier verifier(key);  // fresh: only the tag can refuse it
      Datagram d;
      try {
        d = decode_datagram(bytes);
      } catch (const CorosError&) {
        continue;  // no longer a datagram at all (magic, version, lengths): refused too
      }
      EXPECT_NE(verifier.verify(bytes, d), std::nullopt) << "byte " << i;
    }
  }
  auto cut = genuine;  // the tag cut short
  cut.pop_back();
  DatagramVerifier verifier(key);
  EXPECT_EQ(verifier.verify(cut, decode_datagram(cut)), Rejection::bad_tag);
}

TEST(DatagramAuthentication, ReorderedWithinTheWindowIsAcceptedOnce) {
  const FleetKey key = FleetKey::generate();
  DatagramSigner signer(key, 5000);
  DatagramVerifier verifier(key);
  std::vector<std::vector<std::byte>> sent;
  for (std::uint64_t i = 0; i < DatagramVerifier::kReplayWindow + 10; ++i) {
    sent.push_back(hello_from("robot1"));
    signer.sign(sent.back());
  }
  const auto check = [&](std::size_t i) {
    return verifier.verify(sent[i], decode_datagram(sent[i]));
  };
  EXPECT_EQ(check(5), std::nullopt);
  EXPECT_EQ(check(3), std::nullopt);  // overtaken by 5: still new
  EXPECT_EQ(check(4), std::nullopt);
  EXPECT_EQ(check(3), Rejection::replayed);
  EXPECT_EQ(check(DatagramVerifier::kReplayWindow + 9), std::nullopt);
  EXPECT_EQ(check(9), Rejection::replayed);  // now older than the window: refused
  EXPECT_EQ(check(DatagramVerifier::kReplayWindow + 8), std::nullopt);

  // The sender restarts (a later generation): accepted from counter 1; the earlier generation's
  // datagrams are refused from then on, also those never seen.
  DatagramSigner restarted(key, 6000);
  auto fresh = hello_from("robot1");
  restarted.sign(fresh);
  EXPECT_EQ(verifier.verify(fresh, decode_datagram(fresh)), std::nullopt);
  EXPECT_EQ(check(DatagramVerifier::kReplayWindow + 7), Rejection::replayed);
  // Windows are per sender.
  auto other = hello_from("robot2");
  signer.sign(other);
  EXPECT_EQ(verifier.verify(other, decode_datagram(other)), std::nullopt);
}

TEST(DatagramAuthentication, UnsignedDecodingIsUnchanged) {
  const auto plain = hello_from("robot1");
  const Datagram d = decode_datagram(plain);
  EXPECT_FALSE(d.authentication);
  EXPECT_EQ(d.body_as<HelloMessage>().id, "robot1");
  // A version 2 datagram too short for its trailer is malformed, not a crash.
  auto short_signed = encode_header(MessageCode::hello, "robot1");
  short_signed[2] = std::byte{kAuthenticatedVersion};
  short_signed.resize(short_signed.size() + kAuthTrailerSize);
  EXPECT_THROW(decode_datagram(short_signed), CorosError);
}

// --- Keys and configuration ---------------------------------------------------------------

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const CorosError& e) {
    return e.what();
  }
  return "";
}

TEST(FleetKeys, HexFilesAndFreshKeys) {
  const std::string hex(64, 'a');
  EXPECT_EQ(FleetKey::from_hex("  " + hex + "\n").to_hex(), hex);
  EXPECT_NE(error_of([] { FleetKey::from_hex(std::string(62, 'a')); }).find("must be 32 to"),
            std::string::npos);
  EXPECT_NE(error_of([] { FleetKey::from_hex(std::string(63, 'a')); }).find("odd"),
            std::string::npos);
  const std::string bad = error_of([&] { FleetKey::from_hex("zz" + hex); });
  EXPECT_NE(bad.find("hex digits"), std::string::npos);
  EXPECT_EQ(bad.find(hex), std::string::npos);  // the key is never shown
  EXPECT_NE(FleetKey::generate().to_hex(), FleetKey::generate().to_hex());
  EXPECT_EQ(FleetKey::generate().bytes().size(), FleetKey::kMinBytes);

  const auto dir =
      std::filesystem::path(::testing::TempDir()) / ("coros_keys_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const auto file = dir / "fleet.key";
  {
    std::ofstream out(file);
    out << hex << "\n";
  }
  ::chmod(file.c_str(), 0644);
  const std::string open = error_of([&] { FleetKey::load(file); });
  EXPECT_NE(open.find("chmod 600"), std::string::npos) << open;
  ::chmod(file.c_str(), 0600);
  EXPECT_EQ(FleetKey::load(file).to_hex(), hex);
  EXPECT_NE(error_of([&] { FleetKey::load(dir / "missing.key"); }).find("missing.key"),
            std::string::npos);
  std::filesystem::remove_all(dir);
}

// What icars-agent prints for a configuration without a key (it exits with status 2).
TEST(FleetKeys, AConfigurationWithoutAKeyIsRefused) {
  const auto parse = [](const std::string& json) {
    return AgentConfiguration::parse(json, "/maps", "robot.json");
  };
  const std::string none = error_of([&] { parse(R"({"id": "r", "map": "m.xml"})"); });
  EXPECT_NE(none.find("robot.json: no fleet key"), std::string::npos) << none;
  EXPECT_NE(none.find("'key_file'"), std::string::npos) << none;
  EXPECT_NE(none.find("'insecure': true"), std::string::npos) << none;

  const std::string hex(64, 'b');
  EXPECT_TRUE(parse(R"({"id": "r", "map": "m.xml", "insecure": true})").transport.insecure);
  EXPECT_NE(error_of([&] {
              parse(R"({"id": "r", "map": "m.xml", "insecure": true, "key": ")" + hex + "\"}");
            }).find("remove one"),
            std::string::npos);
  EXPECT_NE(error_of([&] {
              parse(R"({"id": "r", "map": "m.xml", "key": "abcd"})");
            }).find("'key': a fleet key must be"),
            std::string::npos);
  EXPECT_NE(error_of([&] {
              parse(R"({"id": "r", "map": "m.xml", "key_file": "nope.key"})");
            }).find("/maps/nope.key"),
            std::string::npos);

  // A program that builds its configuration itself meets the same rule in Agent's constructor.
  AgentConfiguration c;
  c.id = "r";
  c.transport.broadcast_port = free_udp_port();
  EXPECT_NE(error_of([&] { Agent agent(c); }).find("no fleet key"), std::string::npos);
  c.transport.insecure = true;
  EXPECT_NO_THROW(Agent agent(c));
}

}  // namespace
}  // namespace icars::coros
