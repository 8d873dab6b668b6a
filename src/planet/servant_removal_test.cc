// ObjectAdapter::remove drains the calls in progress on the servant it removes: called from a
// thread of the application it returns only once they have finished (on the bulk thread or as a
// suspended coroutine), so the owner may destroy what the servant uses right after. Called on
// the io thread or from inside a servant call it returns at once, without deadlocking.
#include <gtest/gtest.h>

#include <asio/steady_timer.hpp>
#include <asio/use_awaitable.hpp>
#include <asio/use_future.hpp>
#include <atomic>
#include <future>
#include <thread>

#include "child_process.h"
#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"

namespace icars::planet {
namespace {

using namespace std::chrono_literals;

struct Holder {
  static constexpr std::string_view type_id = "test::Holder";
  // Holds the thread it runs on for 300 ms; a large argument puts it on the bulk thread.
  static constexpr Operation<std::int64_t(Binary)> hold{"hold"};
  // Waits `ms` on a timer (a coroutine suspended on the io thread).
  static constexpr Operation<std::int32_t(std::int32_t)> hold_async{"hold_async"};
  // Removes its own path from inside the call; a large argument runs it on the bulk thread.
  static constexpr Operation<bool(Binary)> remove_self{"remove_self"};
};

struct Progress {
  std::atomic<int> started{0};
  std::atomic<int> finished{0};
};

std::shared_ptr<Servant> make_holder(Communicator& communicator, std::shared_ptr<Progress> p) {
  auto s = std::make_shared<Servant>(std::string(Holder::type_id));
  s->implement(Holder::hold, [p](const Binary& b) {
    ++p->started;
    std::this_thread::sleep_for(300ms);
    ++p->finished;
    return static_cast<std::int64_t>(b.bytes.size());
  });
  s->implement(Holder::hold_async,
               [p, &communicator](std::int32_t ms) -> asio::awaitable<std::int32_t> {
                 ++p->started;
                 asio::steady_timer timer(communicator.io());
                 timer.expires_after(std::chrono::milliseconds(ms));
                 co_await timer.async_wait(asio::use_awaitable);
                 ++p->finished;
                 co_return ms;
               });
  s->implement(Holder::remove_self, [&communicator](const Binary&) {
    return communicator.adapter().remove("/holder");
  });
  return s;
}

struct Served {
  Served() {
    server.adapter().add("/holder", make_holder(server, progress));
    const std::uint16_t port = server.listen("127.0.0.1", 0);
    peer = client.connect("127.0.0.1", port);
    EXPECT_TRUE(peer->wait_connected(20s));
  }
  Proxy holder() { return Proxy(client, peer, "/holder").with_timeout(20s); }

  std::shared_ptr<Progress> progress = std::make_shared<Progress>();
  Communicator server;
  Communicator client;
  std::shared_ptr<Peer> peer;
};

Binary large() {
  Binary b;
  b.bytes.resize(2u << 20);  // over 1 MiB: decoded and dispatched on the bulk thread
  return b;
}

TEST(ServantRemoval, WaitsForACallRunningOnTheBulkThread) {
  Served s;
  auto call = s.holder().async_call(Holder::hold, {large()}, asio::use_future);
  ASSERT_TRUE(planet_test::wait_until([&] { return s.progress->started == 1; }));
  EXPECT_TRUE(s.server.adapter().remove("/holder"));
  EXPECT_EQ(s.progress->finished, 1) << "remove() returned while the call was still running";
  ASSERT_EQ(call.wait_for(20s), std::future_status::ready);
  EXPECT_EQ(call.get(), 2 << 20);
}

TEST(ServantRemoval, WaitsForASuspendedAsynchronousCall) {
  Served s;
  auto call = s.holder().async_call(Holder::hold_async, {300}, asio::use_future);
  ASSERT_TRUE(planet_test::wait_until([&] { return s.progress->started == 1; }));
  const auto start = std::chrono::steady_clock::now();
  EXPECT_TRUE(s.server.adapter().remove("/holder"));
  EXPECT_EQ(s.progress->finished, 1) << "remove() returned while the coroutine was suspended";
  EXPECT_LT(std::chrono::steady_clock::now() - start, 5s);
  ASSERT_EQ(call.wait_for(20s), std::future_status::ready);
  EXPECT_EQ(call.get(), 300);
  // No call starts on a removed servant.
  auto later = s.holder().async_call(Holder::hold_async, {0}, asio::use_future);
  ASSERT_EQ(later.wait_for(20s), std::future_status::ready);
  try {
    later.get();
    ADD_FAILURE() << "a call on a removed servant must fail";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::unimplemented) << e.what();
  }
  EXPECT_EQ(s.progress->started, 1);
}

TEST(ServantRemoval, ReturnsAtOnceWhenNoCallIsInProgress) {
  Served s;
  EXPECT_EQ(s.holder().call(Holder::hold_async, 0), 0);
  const auto start = std::chrono::steady_clock::now();
  EXPECT_TRUE(s.server.adapter().remove("/holder"));
  EXPECT_FALSE(s.server.adapter().remove("/holder"));
  EXPECT_LT(std::chrono::steady_clock::now() - start, 1s);
}

TEST(ServantRemoval, FromInsideItsOwnCallDoesNotDeadlock) {
  {
    Served s;  // on the io thread
    EXPECT_TRUE(s.holder().call(Holder::remove_self, Binary{}));
    EXPECT_TRUE(s.server.adapter().paths().empty());
  }
  {
    Served s;  // on the bulk thread
    EXPECT_TRUE(s.holder().call(Holder::remove_self, large()));
    EXPECT_TRUE(s.server.adapter().paths().empty());
  }
}

TEST(ServantRemoval, OnTheIoThreadReturnsAtOnceWhileACallIsSuspended) {
  Served s;
  auto call = s.holder().async_call(Holder::hold_async, {300}, asio::use_future);
  ASSERT_TRUE(planet_test::wait_until([&] { return s.progress->started == 1; }));
  std::promise<bool> removed;
  asio::post(s.server.io(), [&] { removed.set_value(s.server.adapter().remove("/holder")); });
  auto result = removed.get_future();
  ASSERT_EQ(result.wait_for(5s), std::future_status::ready) << "remove() on the io thread hung";
  EXPECT_TRUE(result.get());
  ASSERT_EQ(call.wait_for(20s), std::future_status::ready);
  EXPECT_EQ(call.get(), 300);  // the call in progress still ran to its end
}

}  // namespace
}  // namespace icars::planet
