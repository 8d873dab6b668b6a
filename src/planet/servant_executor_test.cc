// A servant whose operations block runs them on an executor of its own (Servant::run_on): while
// one of its calls waits (for a disk, for hardware), the io thread goes on answering the other
// servants of the process; its own calls still run one at a time, in the order they came, with
// replies, exceptions and one-way calls as on the io thread, and remove() still waits for them.
#include <gtest/gtest.h>

#include <asio/strand.hpp>
#include <asio/thread_pool.hpp>
#include <asio/use_future.hpp>
#include <atomic>
#include <future>
#include <mutex>
#include <thread>
#include <vector>

#include "child_process.h"
#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"

namespace icars::planet {
namespace {

using namespace std::chrono_literals;

struct Gate {
  static constexpr std::string_view type_id = "test::Gate";
  // Waits until the test opens the gate, then returns its argument.
  static constexpr Operation<std::int32_t(std::int32_t)> pass{"pass"};
  // Returns its argument at once (after the calls before it on this servant).
  static constexpr Operation<std::int32_t(std::int32_t)> echo{"echo"};
  static constexpr Operation<void(std::string)> refuse{"refuse"};
  static constexpr OneWay<std::int32_t> note{"note"};
};

struct Other {
  static constexpr std::string_view type_id = "test::Other";
  static constexpr Operation<std::int32_t()> ping{"ping"};
};

// The gate's state, shared by its servant and the test.
struct GateState {
  std::promise<void> open;
  std::shared_future<void> opened = open.get_future().share();
  std::atomic<int> waiting{0};
  std::mutex mutex;
  std::vector<std::int32_t> order;  // arguments in the order the calls ran
  std::vector<std::thread::id> threads;
  void ran(std::int32_t v) {
    std::lock_guard lock(mutex);
    order.push_back(v);
    threads.push_back(std::this_thread::get_id());
  }
};

class ServantExecutor : public ::testing::Test {
 protected:
  void SetUp() override {
    auto gate = std::make_shared<Servant>(std::string(Gate::type_id));
    gate->implement(Gate::pass, [s = state_](std::int32_t v) {
      ++s->waiting;
      s->opened.wait();  // blocks the thread it runs on
      s->ran(v);
      return v;
    });
    gate->implement(Gate::echo, [s = state_](std::int32_t v) {
      s->ran(v);
      return v;
    });
    gate->implement(Gate::refuse, [](const std::string& why) -> void {
      throw RemoteException("test::Refused", why);
    });
    gate->implement(Gate::note, [s = state_](std::int32_t v) { s->ran(v); });
    gate->run_on(asio::make_strand(pool_.get_executor()));
    server_.adapter().add("/gate", gate);
    auto other = std::make_shared<Servant>(std::string(Other::type_id));
    other->implement(Other::ping, [] { return 7; });
    server_.adapter().add("/other", other);
    peer_ = client_.connect("127.0.0.1", server_.listen("127.0.0.1", 0));
    ASSERT_TRUE(peer_->wait_connected(20s)) << peer_->last_error();
  }
  void TearDown() override {
    open();
    server_.adapter().remove("/gate");
  }
  void open() {
    if (!opened_) state_->open.set_value();
    opened_ = true;
  }
  Proxy gate() { return Proxy(client_, peer_, "/gate").with_timeout(60s); }
  Proxy other() { return Proxy(client_, peer_, "/other").with_timeout(60s); }

  std::shared_ptr<GateState> state_ = std::make_shared<GateState>();
  bool opened_ = false;
  asio::thread_pool pool_{2};  // outlives the server's calls (declared before it)
  Communicator server_;
  Communicator client_;
  std::shared_ptr<Peer> peer_;
};

TEST_F(ServantExecutor, ABlockedCallHoldsUpNeitherTheIoThreadNorOtherServants) {
  auto blocked = gate().async_call(Gate::pass, {1}, asio::use_future);
  ASSERT_TRUE(planet_test::wait_until([&] { return state_->waiting == 1; }, 30s));
  // The same connection, the same server process: answered while the gate's call waits.
  for (int i = 0; i < 50; ++i) EXPECT_EQ(other().call(Other::ping), 7);
  EXPECT_EQ(blocked.wait_for(0s), std::future_status::timeout);
  open();
  ASSERT_EQ(blocked.wait_for(60s), std::future_status::ready);
  EXPECT_EQ(blocked.get(), 1);
  std::lock_guard lock(state_->mutex);
  ASSERT_EQ(state_->threads.size(), 1u);
  EXPECT_NE(state_->threads[0], std::this_thread::get_id());
}

TEST_F(ServantExecutor, TheServantsOwnCallsRunOneAtATimeInTheirOrder) {
  auto first = gate().async_call(Gate::pass, {1}, asio::use_future);
  ASSERT_TRUE(planet_test::wait_until([&] { return state_->waiting == 1; }, 30s));
  std::vector<std::future<std::int32_t>> later;
  for (std::int32_t v = 2; v <= 20; ++v) {
    if (v % 5 == 0) {
      gate().notify(Gate::note, v);
    } else {
      later.push_back(gate().async_call(Gate::echo, {v}, asio::use_future));
    }
  }
  EXPECT_EQ(other().call(Other::ping), 7);
  for (auto& f : later) EXPECT_EQ(f.wait_for(0s), std::future_status::timeout) << "overtook the call before it";
  open();
  EXPECT_EQ(first.get(), 1);
  for (auto& f : later) ASSERT_EQ(f.wait_for(60s), std::future_status::ready);
  ASSERT_TRUE(planet_test::wait_until([&] {
    std::lock_guard lock(state_->mutex);
    return state_->order.size() == 20u;
  }, 30s));
  std::lock_guard lock(state_->mutex);
  for (std::int32_t v = 1; v <= 20; ++v) EXPECT_EQ(state_->order[static_cast<std::size_t>(v - 1)], v);
}

TEST_F(ServantExecutor, ExceptionsAndBadArgumentsArriveAsFromTheIoThread) {
  open();
  try {
    gate().call(Gate::refuse, std::string("not now"));
    ADD_FAILURE() << "refuse must throw";
  } catch (const RemoteException& e) {
    EXPECT_EQ(e.type_id(), "test::Refused");
    EXPECT_EQ(e.remote_message(), "not now");
  }
  // Arguments of the wrong type: decoded on the executor, refused with bad_data.
  static constexpr Operation<std::int32_t(std::string)> wrong{"echo"};
  try {
    gate().call(wrong, std::string("seven"));
    ADD_FAILURE() << "wrong arguments must be refused";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_data) << e.what();
  }
  EXPECT_EQ(gate().call(Gate::echo, 3), 3);  // and the servant still serves
}

TEST_F(ServantExecutor, RemoveWaitsForACallRunningOnTheExecutor) {
  auto blocked = gate().async_call(Gate::pass, {9}, asio::use_future);
  ASSERT_TRUE(planet_test::wait_until([&] { return state_->waiting == 1; }, 30s));
  std::thread opener([&] {
    std::this_thread::sleep_for(100ms);  // remove() below must be waiting by then or later
    open();
  });
  EXPECT_TRUE(server_.adapter().remove("/gate"));
  {
    std::lock_guard lock(state_->mutex);
    EXPECT_EQ(state_->order, std::vector<std::int32_t>{9}) << "remove() returned while the call was running";
  }
  opener.join();
  ASSERT_EQ(blocked.wait_for(60s), std::future_status::ready);
  EXPECT_EQ(blocked.get(), 9);
}

}  // namespace
}  // namespace icars::planet
