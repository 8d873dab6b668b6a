#include "fault_proxy.h"

#include <asio/co_spawn.hpp>
#include <asio/detached.hpp>
#include <asio/executor_work_guard.hpp>
#include <asio/io_context.hpp>
#include <asio/ip/tcp.hpp>
#include <asio/post.hpp>
#include <asio/redirect_error.hpp>
#include <asio/steady_timer.hpp>
#include <asio/use_awaitable.hpp>
#include <asio/write.hpp>
#include <array>
#include <atomic>
#include <deque>
#include <functional>
#include <future>
#include <limits>
#include <mutex>
#include <optional>
#include <set>
#include <stdexcept>
#include <thread>
#include <vector>

namespace planet_test {

using asio::ip::tcp;
using Clock = std::chrono::steady_clock;

namespace detail {

struct Fault {
  FaultKind kind = FaultKind::pass;
  std::chrono::milliseconds delay{0};
  std::size_t bytes = 0;         // truncate: the budget of each connection
  std::uint64_t generation = 0;  // distinguishes successive truncate() calls
};

struct Session;

struct FaultProxyState {
  asio::io_context io;  // declared first: destroyed after every socket and timer
  tcp::acceptor acceptor{io};
  tcp::endpoint target;
  std::optional<asio::executor_work_guard<asio::io_context::executor_type>> work;
  std::thread thread;
  std::atomic<bool> stopped_running{false};

  mutable std::mutex mutex;
  std::array<Fault, 2> faults;
  std::uint64_t generation = 0;
  bool refusing = false;

  std::atomic<std::uint64_t> accepted{0};
  std::array<std::atomic<std::uint64_t>, 2> forwarded{};
  std::array<std::atomic<std::uint64_t>, 2> dropped{};
  std::atomic<std::size_t> open{0};
  std::set<std::shared_ptr<Session>> sessions;  // io thread only

  Fault fault_of(std::size_t d) const {
    std::lock_guard lock(mutex);
    return faults[d];
  }
  void set(Direction d, Fault f);
  void wake_all();
  // Runs `fn` on the io thread and waits for it (bounded: the io thread never blocks).
  void run_on_io(std::function<void()> fn);
  asio::awaitable<void> accept_loop();
};

// Waits on `timer` until `until`, or until someone cancels it (a wake-up).
asio::awaitable<void> wait_on(asio::steady_timer& timer, Clock::time_point until) {
  timer.expires_at(until);
  std::error_code ec;
  co_await timer.async_wait(asio::redirect_error(asio::use_awaitable, ec));
}

// One proxied connection: the accepted client socket, the socket to the target, and per
// direction a queue of chunks read and not yet written. Lives on the io thread.
struct Session : std::enable_shared_from_this<Session> {
  struct Chunk {
    std::vector<std::byte> bytes;
    Clock::time_point due;
    bool last = false;  // a truncation ends here: close the session once it is written
  };
  struct Pipe {
    tcp::socket* from = nullptr;
    tcp::socket* to = nullptr;
    std::deque<Chunk> queue;
    asio::steady_timer reader_wake;
    asio::steady_timer writer_wake;
    bool reader_done = false;  // EOF read (or a truncation ended it)
    bool finished = false;     // everything read was written and `to` was shut down
    std::uint64_t truncate_generation = 0;
    std::size_t budget = 0;
    explicit Pipe(asio::io_context& io) : reader_wake(io), writer_wake(io) {}
  };

  Session(FaultProxyState& s, tcp::socket accepted)
      : state(s), client(std::move(accepted)), server(s.io), pipes{Pipe(s.io), Pipe(s.io)} {
    pipes[0].from = &client;
    pipes[0].to = &server;
    pipes[1].from = &server;
    pipes[1].to = &client;
  }

  asio::awaitable<void> start() {
    auto self = shared_from_this();
    std::error_code ec;
    co_await server.async_connect(state.target, asio::redirect_error(asio::use_awaitable, ec));
    if (closed) co_return;
    if (ec) {
      close(false);
      co_return;
    }
    server.set_option(tcp::no_delay(true), ec);
    client.set_option(tcp::no_delay(true), ec);
    for (std::size_t d = 0; d < 2; ++d) {
      asio::co_spawn(state.io, read_loop(self, d), asio::detached);
      asio::co_spawn(state.io, write_loop(self, d), asio::detached);
    }
  }

  // A truncate() newer than this pipe has seen starts a fresh budget.
  void take_budget(Pipe& p, const Fault& f) {
    if (f.kind == FaultKind::truncate && p.truncate_generation != f.generation) {
      p.truncate_generation = f.generation;
      p.budget = f.bytes;
    }
  }

  asio::awaitable<void> read_loop(std::shared_ptr<Session> /*keeps it alive*/, std::size_t d) {
    auto& p = pipes[d];
    std::vector<std::byte> buffer(64 * 1024);
    while (!closed) {
      Fault f = state.fault_of(d);
      take_budget(p, f);
      if (f.kind == FaultKind::blackhole) {
        co_await wait_on(p.reader_wake, Clock::time_point::max());
        continue;
      }
      if (f.kind == FaultKind::truncate && p.budget == 0) {
        p.queue.push_back(Chunk{{}, Clock::now(), true});
        p.reader_done = true;
        p.writer_wake.cancel();
        break;
      }
      std::error_code ec;
      const std::size_t n = co_await p.from->async_read_some(
          asio::buffer(buffer), asio::redirect_error(asio::use_awaitable, ec));
      if (closed) break;
      if (ec) {
        if (ec != asio::error::eof) {
          close(false);  // reset or aborted: the connection is gone
          break;
        }
        p.reader_done = true;
        p.writer_wake.cancel();
        break;
      }
      f = state.fault_of(d);  // the fault when the bytes arrived
      take_budget(p, f);
      Chunk chunk{std::vector<std::byte>(buffer.begin(), buffer.begin() + static_cast<std::ptrdiff_t>(n)),
                  Clock::now(), false};
      switch (f.kind) {
        case FaultKind::drop:
          state.dropped[d] += n;
          continue;
        case FaultKind::delay:
          chunk.due += f.delay;
          break;
        case FaultKind::truncate: {
          const std::size_t take = std::min(n, p.budget);
          chunk.bytes.resize(take);
          p.budget -= take;
          chunk.last = p.budget == 0;
          break;
        }
        case FaultKind::pass:
        case FaultKind::blackhole:  // set while reading: held until it is lifted
          break;
      }
      const bool last = chunk.last;
      p.queue.push_back(std::move(chunk));
      p.writer_wake.cancel();
      if (last) {
        p.reader_done = true;
        break;
      }
    }
  }

  asio::awaitable<void> write_loop(std::shared_ptr<Session> /*keeps it alive*/, std::size_t d) {
    auto& p = pipes[d];
    while (!closed) {
      if (p.queue.empty()) {
        if (p.reader_done) {
          // The sender closed its side: pass the FIN on once everything before it is written.
          std::error_code ec;
          p.to->shutdown(tcp::socket::shutdown_send, ec);
          p.finished = true;
          if (pipes[0].finished && pipes[1].finished) close(false);
          break;
        }
        co_await wait_on(p.writer_wake, Clock::time_point::max());
        continue;
      }
      if (state.fault_of(d).kind == FaultKind::blackhole) {
        co_await wait_on(p.writer_wake, Clock::time_point::max());
        continue;
      }
      if (p.queue.front().due > Clock::now()) {
        co_await wait_on(p.writer_wake, p.queue.front().due);
        continue;
      }
      std::error_code ec;
      const std::size_t n = co_await asio::async_write(
          *p.to, asio::buffer(p.queue.front().bytes), asio::redirect_error(asio::use_awaitable, ec));
      if (closed) break;
      if (ec) {
        close(false);
        break;
      }
      state.forwarded[d] += n;
      const bool last = p.queue.front().last;
      p.queue.pop_front();
      if (last) {
        close(false);
        break;
      }
    }
  }

  void wake() {
    for (auto& p : pipes) {
      p.reader_wake.cancel();
      p.writer_wake.cancel();
    }
  }

  void close(bool reset) {
    if (closed) return;
    closed = true;
    std::error_code ec;
    for (auto* s : {&client, &server}) {
      if (!s->is_open()) continue;
      if (reset) s->set_option(asio::socket_base::linger(true, 0), ec);
      s->close(ec);
    }
    wake();
    --state.open;
    state.sessions.erase(shared_from_this());
  }

  FaultProxyState& state;
  tcp::socket client;
  tcp::socket server;
  std::array<Pipe, 2> pipes;
  bool closed = false;
};

void FaultProxyState::set(Direction d, Fault f) {
  {
    std::lock_guard lock(mutex);
    f.generation = ++generation;
    if (d == Direction::both || d == Direction::client_to_server) faults[0] = f;
    if (d == Direction::both || d == Direction::server_to_client) faults[1] = f;
  }
  wake_all();
}

void FaultProxyState::wake_all() {
  asio::post(io, [this] {
    for (const auto& s : sessions) s->wake();
  });
}

void FaultProxyState::run_on_io(std::function<void()> fn) {
  auto done = std::make_shared<std::promise<void>>();
  auto finished = done->get_future();
  asio::post(io, [fn = std::move(fn), done] {
    fn();
    done->set_value();
  });
  if (finished.wait_for(std::chrono::seconds(10)) != std::future_status::ready) {
    throw std::runtime_error("FaultProxy: the io thread did not respond within 10 s");
  }
}

asio::awaitable<void> FaultProxyState::accept_loop() {
  for (;;) {
    std::error_code ec;
    tcp::socket socket = co_await acceptor.async_accept(asio::redirect_error(asio::use_awaitable, ec));
    if (ec) {
      if (!acceptor.is_open()) co_return;
      continue;  // e.g. too many open files: try the next one
    }
    ++accepted;
    bool refuse_now = false;
    {
      std::lock_guard lock(mutex);
      refuse_now = refusing;
    }
    if (refuse_now) {
      socket.close(ec);
      continue;
    }
    auto session = std::make_shared<Session>(*this, std::move(socket));
    sessions.insert(session);
    ++open;
    asio::co_spawn(io, session->start(), asio::detached);
  }
}

std::size_t index_of(Direction d) { return d == Direction::server_to_client ? 1 : 0; }

}  // namespace detail

using detail::Fault;
using detail::index_of;

FaultProxy::FaultProxy(const std::string& target_host, std::uint16_t target_port)
    : state_(std::make_shared<detail::FaultProxyState>()) {
  auto& s = *state_;
  s.target = tcp::endpoint(asio::ip::make_address(target_host), target_port);
  const tcp::endpoint local(asio::ip::make_address("127.0.0.1"), 0);
  s.acceptor.open(local.protocol());
  s.acceptor.set_option(tcp::acceptor::reuse_address(true));
  s.acceptor.bind(local);
  s.acceptor.listen();
  port_ = s.acceptor.local_endpoint().port();
  asio::co_spawn(s.io, s.accept_loop(), asio::detached);
  s.work.emplace(s.io.get_executor());
  s.thread = std::thread([&s] {
    s.io.run();
    s.stopped_running = true;
  });
}

FaultProxy::~FaultProxy() {
  auto& s = *state_;
  // Close everything on the io thread; the work guard ends with run(), whose last handlers are
  // the coroutines finishing on their aborted operations.
  try {
    s.run_on_io([&s] {
      std::error_code ec;
      s.acceptor.close(ec);
      auto sessions = s.sessions;
      for (const auto& session : sessions) session->close(true);
    });
  } catch (const std::exception&) {
    // The io thread is stuck: stopped below.
  }
  s.work.reset();
  const auto deadline = Clock::now() + std::chrono::seconds(5);
  while (!s.stopped_running && Clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  s.io.stop();
  s.thread.join();
}

void FaultProxy::pass(Direction d) { state_->set(d, Fault{}); }

void FaultProxy::drop(Direction d) {
  Fault f;
  f.kind = FaultKind::drop;
  state_->set(d, f);
}

void FaultProxy::delay(std::chrono::milliseconds by, Direction d) {
  Fault f;
  f.kind = FaultKind::delay;
  f.delay = by;
  state_->set(d, f);
}

void FaultProxy::truncate(std::size_t bytes, Direction d) {
  Fault f;
  f.kind = FaultKind::truncate;
  f.bytes = bytes;
  state_->set(d, f);
}

void FaultProxy::blackhole(Direction d) {
  Fault f;
  f.kind = FaultKind::blackhole;
  state_->set(d, f);
}

void FaultProxy::cut(bool reset) {
  auto& s = *state_;
  s.run_on_io([&s, reset] {
    auto sessions = s.sessions;
    for (const auto& session : sessions) session->close(reset);
  });
}

void FaultProxy::refuse(bool on) {
  std::lock_guard lock(state_->mutex);
  state_->refusing = on;
}

FaultKind FaultProxy::fault(Direction d) const { return state_->fault_of(index_of(d)).kind; }

std::uint64_t FaultProxy::connections_accepted() const { return state_->accepted.load(); }

std::size_t FaultProxy::open_connections() const { return state_->open.load(); }

std::uint64_t FaultProxy::bytes_forwarded(Direction d) const {
  if (d == Direction::both) return state_->forwarded[0].load() + state_->forwarded[1].load();
  return state_->forwarded[index_of(d)].load();
}

std::uint64_t FaultProxy::bytes_dropped(Direction d) const {
  if (d == Direction::both) return state_->dropped[0].load() + state_->dropped[1].load();
  return state_->dropped[index_of(d)].load();
}

}  // namespace planet_test
