// Code generated from testdata/home.idl, end to end: two communicators over loopback, every
// operation of the TV interface called through the generated TVPrx (synchronously, with a
// callback and with a future) against a servant derived from the generated TVServant. Raised
// exceptions arrive as their generated classes, a oneway call arrives, a listener living in the
// caller is passed by reference and called back, an interface result arrives as a bound proxy
// and streams pass in both directions.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <asio/co_spawn.hpp>
#include <asio/detached.hpp>
#include <asio/use_awaitable.hpp>
#include <asio/use_future.hpp>
#include <chrono>
#include <functional>
#include <future>
#include <mutex>
#include <thread>

#include "home.planet.h"
#include "icars/planet/communicator.h"

namespace fixture {
namespace {

namespace p = icars::planet;
using namespace std::chrono_literals;

// `idempotent` in the IDL reaches the operation constant the stub passes to the call.
static_assert(home::TV::set_channel.idempotent());
static_assert(!home::TV::power.idempotent() && !home::TV::logged.idempotent());

bool wait_until(const std::function<bool()>& condition, std::chrono::milliseconds timeout = 20s) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!condition()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(5ms);
  }
  return true;
}

std::vector<std::byte> chunk_of(std::size_t size, int fill) {
  return std::vector<std::byte>(size, std::byte(static_cast<unsigned char>(fill)));
}

// The TV: echoes, raises, remembers what it was told and streams in both directions.
class TV final : public home::TVServant {
 public:
  std::string id(const p::Current&) override { return "tv-1"; }

  std::int32_t set_channel(std::int32_t channel, const p::Current&) override {
    if (channel < 0 || channel > 99) {
      throw NoSuchChannel(channel, fmt::format("there is no channel {}", channel));
    }
    return channel;
  }
  void power(bool on, const p::Current&) override {
    if (!on) throw Busy("kitchen", 250, Color::blue, {Pose{1, 2, 3}}, "recording");
  }
  void log(const std::string& text, const p::Current&) override {
    std::lock_guard lock(mutex_);
    logged_.push_back(text);
  }
  std::vector<std::string> logged(const p::Current&) override {
    std::lock_guard lock(mutex_);
    return logged_;
  }

  bool echo_bool(bool v, const p::Current&) override { return v; }
  std::uint8_t echo_byte(std::uint8_t v, const p::Current&) override { return v; }
  std::int16_t echo_short(std::int16_t v, const p::Current&) override { return v; }
  std::int64_t echo_long(std::int64_t v, const p::Current&) override { return v; }
  float echo_float(float v, const p::Current&) override { return v; }
  double echo_double(double v, const p::Current&) override { return v; }
  p::Binary echo_binary(const p::Binary& v, const p::Current&) override { return v; }
  Everything echo(const Everything& value, const p::Current&) override { return value; }
  nav::Route echo_route(const nav::Route& route, const p::Current&) override { return route; }
  std::vector<Pose> reverse(const std::vector<Pose>& poses, const p::Current&) override {
    return {poses.rbegin(), poses.rend()};
  }
  Detection detect(Color color, nav::Mode mode, const geo::Point& point,
                   const p::Current&) override {
    return Detection{{point}, color, nav::Waypoint{Pose{point.x, point.y, 0}, mode, "seen"}};
  }
  std::vector<std::vector<std::int32_t>> transpose(const std::vector<std::vector<std::int32_t>>& m,
                                                   const p::Current&) override {
    std::vector<std::vector<std::int32_t>> t(m.empty() ? 0 : m[0].size());
    for (const auto& row : m) {
      for (std::size_t c = 0; c < row.size(); ++c) t[c].push_back(row[c]);
    }
    return t;
  }

  // Calls the caller's listener back: a oneway call, and a two-way call made asynchronously
  // (a synchronous call here would block the io thread that must deliver its reply).
  void subscribe(home::ListenerPrx listener, const std::string& tag, const p::Current&) override {
    listener.heard(SoundEvent{90, 0.75, tag});
    listener.name_async([this](std::exception_ptr error, std::string name) {
      std::lock_guard lock(mutex_);
      listener_name_ = error ? "failed" : name;
    });
  }
  std::string listener_name(const p::Current&) override {
    std::lock_guard lock(mutex_);
    return listener_name_;
  }
  p::Ref<home::TV> self(const p::Current& current) override {
    return current.communicator->reference<home::TV>("/tv");
  }

  p::StreamRef record(std::int32_t chunks, const p::Current& current) override {
    auto out = p::OutputStream::create(*current.communicator);
    asio::co_spawn(current.communicator->executor(), write_chunks(out, chunks), asio::detached);
    return out->ref();
  }
  void play(std::shared_ptr<p::InputStream> sound, const p::Current&) override { drain(sound); }
  std::int64_t played(const p::Current&) override {
    std::lock_guard lock(mutex_);
    return played_;
  }

 private:
  static asio::awaitable<void> write_chunks(std::shared_ptr<p::OutputStream> out, int chunks) {
    try {
      for (int i = 0; i < chunks; ++i) {
        co_await out->async_write(chunk_of(1000, i), asio::use_awaitable);
      }
      out->close();
    } catch (const std::exception&) {
      // The reader went away; nothing left to do.
    }
  }
  void drain(std::shared_ptr<p::InputStream> in) {
    in->async_read([this, in](std::exception_ptr error, std::vector<std::byte> chunk) {
      if (error || chunk.empty()) return;
      {
        std::lock_guard lock(mutex_);
        played_ += static_cast<std::int64_t>(chunk.size());
      }
      drain(in);
    });
  }

  std::mutex mutex_;
  std::vector<std::string> logged_;
  std::string listener_name_;
  std::int64_t played_ = 0;
};

// Lives in the caller's communicator.
class Listener final : public home::ListenerServant {
 public:
  void heard(const SoundEvent& e, const p::Current&) override {
    std::lock_guard lock(mutex_);
    heard_.push_back(e);
  }
  std::string name(const p::Current&) override { return "living-room listener"; }
  std::vector<SoundEvent> heard_events() {
    std::lock_guard lock(mutex_);
    return heard_;
  }

 private:
  std::mutex mutex_;
  std::vector<SoundEvent> heard_;
};

p::CommunicatorOptions named(std::string name) {
  p::CommunicatorOptions options;
  options.name = std::move(name);
  return options;
}

class GeneratedRmi : public ::testing::Test {
 protected:
  void SetUp() override {
    server_.adapter().add("/tv", tv_servant_);
    peer_ = client_.connect("127.0.0.1", server_.listen("127.0.0.1", 0));
    ASSERT_TRUE(peer_->wait_connected(20s)) << peer_->last_error();
  }
  home::TVPrx tv() { return home::TVPrx(client_, peer_, "/tv"); }

  std::shared_ptr<TV> tv_servant_ = std::make_shared<TV>();
  p::Communicator server_{named("server")};
  p::Communicator client_{named("client")};
  std::shared_ptr<p::Peer> peer_;
};

TEST_F(GeneratedRmi, EveryOperationSynchronously) {
  const home::TVPrx tv = this->tv();
  EXPECT_EQ(tv.id(), "tv-1");  // inherited from Device
  EXPECT_EQ(tv.set_channel(42), 42);
  EXPECT_NO_THROW(tv.power(true));
  EXPECT_TRUE(tv.echo_bool(true));
  EXPECT_EQ(tv.echo_byte(200), 200);
  EXPECT_EQ(tv.echo_short(-300), -300);
  EXPECT_EQ(tv.echo_long(1LL << 40), 1LL << 40);
  EXPECT_EQ(tv.echo_float(0.25f), 0.25f);
  EXPECT_EQ(tv.echo_double(-1e-300), -1e-300);
  const p::Binary blob{{std::byte{1}, std::byte{2}, std::byte{3}}};
  EXPECT_EQ(tv.echo_binary(blob), blob);
  Everything everything;
  everything.text = "everything";
  everything.cube = {{{1}}};
  everything.sounds = {SoundEvent{1, 2, "s"}};
  EXPECT_EQ(tv.echo(everything), everything);
  const nav::Route route{{nav::Waypoint{Pose{1, 2, 3}, nav::Mode::docking, "dock"}},
                         geo::Point{4, 5},
                         geo::Unit::millimeter};
  EXPECT_EQ(tv.echo_route(route), route);
  EXPECT_EQ(tv.reverse({Pose{1, 0, 0}, Pose{2, 0, 0}}),
            (std::vector<Pose>{Pose{2, 0, 0}, Pose{1, 0, 0}}));
  const Detection d = tv.detect(Color::green, nav::Mode::driving, geo::Point{3, 4});
  EXPECT_EQ(d.color, Color::green);
  EXPECT_EQ(d.where.mode, nav::Mode::driving);
  EXPECT_EQ(d.outline, (std::vector<geo::Point>{geo::Point{3, 4}}));
  EXPECT_EQ(tv.transpose({{1, 2}, {3, 4}}),
            (std::vector<std::vector<std::int32_t>>{{1, 3}, {2, 4}}));
}

TEST_F(GeneratedRmi, RaisedExceptionsArriveAsTheirGeneratedClasses) {
  try {
    tv().set_channel(100);
    FAIL() << "expected NoSuchChannel";
  } catch (const NoSuchChannel& e) {
    EXPECT_EQ(e.channel(), 100);
    EXPECT_EQ(e.remote_message(), "there is no channel 100");
    EXPECT_EQ(e.type_id(), NoSuchChannel::static_type_id);
  }
  try {
    tv().power(false);
    FAIL() << "expected Busy";
  } catch (const Busy& e) {
    EXPECT_EQ(e.who(), "kitchen");
    EXPECT_EQ(e.retry_ms(), 250);
    EXPECT_EQ(e.color(), Color::blue);
    EXPECT_EQ(e.poses(), (std::vector<Pose>{Pose{1, 2, 3}}));
  }
  EXPECT_THROW(tv().set_channel_async(-1, asio::use_future).get(), NoSuchChannel);
  std::promise<std::exception_ptr> raised;
  tv().power_async(false, [&](std::exception_ptr e) { raised.set_value(e); });
  EXPECT_THROW(std::rethrow_exception(raised.get_future().get()), Busy);
}

TEST_F(GeneratedRmi, AsynchronousCallsWithCallbacksAndFutures) {
  std::promise<std::int32_t> channel;
  tv().set_channel_async(7, [&](std::exception_ptr e, std::int32_t c) {
    EXPECT_FALSE(e);
    channel.set_value(c);
  });
  EXPECT_EQ(channel.get_future().get(), 7);
  std::promise<void> powered;
  tv().power_async(true, [&](std::exception_ptr e) {
    EXPECT_FALSE(e);
    powered.set_value();
  });
  powered.get_future().get();
  EXPECT_EQ(tv().id_async(asio::use_future).get(), "tv-1");
  Everything everything;
  everything.big = -1;
  EXPECT_EQ(tv().echo_async(everything, asio::use_future).get(), everything);
  EXPECT_EQ(tv().reverse_async({Pose{1, 2, 3}}, asio::use_future).get(),
            (std::vector<Pose>{Pose{1, 2, 3}}));
}

TEST_F(GeneratedRmi, OnewayCallArrives) {
  tv().log("hello");
  tv().log("world");
  EXPECT_TRUE(wait_until([&] { return tv().logged().size() == 2; }));
  EXPECT_EQ(tv().logged(), (std::vector<std::string>{"hello", "world"}));
}

TEST_F(GeneratedRmi, ListenerPassedByReferenceIsCalledBack) {
  auto listener = std::make_shared<Listener>();
  client_.adapter().add("/listener", listener);
  tv().subscribe(client_.reference<home::Listener>("/listener"), "kitchen");
  EXPECT_TRUE(wait_until([&] { return listener->heard_events().size() == 1; }));
  EXPECT_EQ(listener->heard_events().at(0), (SoundEvent{90, 0.75, "kitchen"}));
  EXPECT_TRUE(wait_until([&] { return tv().listener_name() == "living-room listener"; }));
}

TEST_F(GeneratedRmi, InterfaceResultIsABoundProxy) {
  const home::TVPrx self = tv().self();
  EXPECT_EQ(self.path(), "/tv");
  EXPECT_EQ(self.ref().object().type_id, "fixture::home::TV");
  EXPECT_EQ(self.set_channel(3), 3);
  const home::TVPrx again = tv().self_async(asio::use_future).get();
  EXPECT_EQ(again.id(), "tv-1");
  std::promise<std::string> id;
  tv().self_async([&](std::exception_ptr e, home::TVPrx bound) {
    if (e) return id.set_exception(e);
    bound.id_async([&](std::exception_ptr e2, std::string value) {
      if (e2) return id.set_exception(e2);
      id.set_value(value);
    });
  });
  EXPECT_EQ(id.get_future().get(), "tv-1");
}

TEST_F(GeneratedRmi, StreamResultIsReadToTheEnd) {
  const std::shared_ptr<p::InputStream> in = tv().record(5);
  std::vector<std::byte> all;
  for (auto chunk = in->read(); !chunk.empty(); chunk = in->read()) {
    all.insert(all.end(), chunk.begin(), chunk.end());
  }
  ASSERT_EQ(all.size(), 5000u);
  EXPECT_EQ(all.front(), std::byte{0});
  EXPECT_EQ(all.back(), std::byte{4});
  const auto async_in = tv().record_async(2, asio::use_future).get();
  std::size_t total = 0;
  for (auto chunk = async_in->read(); !chunk.empty(); chunk = async_in->read())
    total += chunk.size();
  EXPECT_EQ(total, 2000u);
}

TEST_F(GeneratedRmi, StreamParameterIsReadByTheServant) {
  const auto out = p::OutputStream::create(client_);
  tv().play(out->ref());
  out->write(chunk_of(6000, 1));
  out->write(chunk_of(4000, 2));
  out->close();
  EXPECT_TRUE(wait_until([&] { return tv().played() == 10000; }));
}

}  // namespace
}  // namespace fixture
