// PLANET demo: a mediating server and a device client in two processes.
//
//   planet_demo            starts a server process, then runs the client against it
//   planet_demo server     runs only the server (prints "READY <port>")
//   planet_demo client P   runs only the client against 127.0.0.1:P
//
// The interfaces are written in PLANET IDL (home.idl) and compiled by planet-idl into the typed
// stubs and servant bases used here. The client calls the server, subscribes a listener object
// of its own and receives sound events on it (the server calls back over the client's
// connection), pulls a second of audio from a stream, then uploads a 16 MiB camera image while
// small calls keep flowing on the same connection.
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <asio/co_spawn.hpp>
#include <asio/detached.hpp>
#include <asio/steady_timer.hpp>
#include <asio/use_awaitable.hpp>
#include <asio/use_future.hpp>
#include <atomic>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <future>
#include <iostream>
#include <numeric>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "home.planet.h"
#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"
#include "icars/planet/stream.h"

extern char** environ;

namespace planet = icars::planet;
using namespace std::chrono_literals;

namespace demo {

std::shared_ptr<spdlog::logger> quiet_logger(const std::string& name) {
  auto log = std::make_shared<spdlog::logger>(
      name, std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
  log->set_level(spdlog::level::warn);
  return log;
}

// Sends `count` sound events to the subscriber, one every 20 ms, over the subscriber's link.
asio::awaitable<void> publish(planet::Communicator& comm, SoundListenerPrx listener,
                              std::int32_t count) {
  asio::steady_timer timer(comm.io());
  for (std::int32_t i = 0; i < count; ++i) {
    try {
      listener.on_sound(SoundEvent{i, 30.0 * i, 40 + (i * 7) % 30});
    } catch (const planet::Error& err) {
      std::printf("[server] subscriber gone: %s\n", err.what());
      co_return;
    }
    timer.expires_after(20ms);
    co_await timer.async_wait(asio::use_awaitable);
  }
}

// Writes `milliseconds` of a 440 Hz tone as 16 kHz 16-bit PCM, 100 ms at a time, in real time.
asio::awaitable<void> record(planet::Communicator& comm, std::shared_ptr<planet::OutputStream> out,
                             std::int32_t milliseconds) {
  asio::steady_timer timer(comm.io());
  std::int64_t sample = 0;
  try {
    for (std::int32_t done = 0; done < milliseconds; done += 100) {
      std::vector<std::byte> block(2 * 16 * static_cast<std::size_t>(std::min(100, milliseconds - done)));
      for (std::size_t i = 0; i < block.size(); i += 2, ++sample) {
        const auto v = static_cast<std::int16_t>(8000 * std::sin(2 * 3.14159265 * 440 *
                                                                 static_cast<double>(sample) / 16000));
        block[i] = static_cast<std::byte>(static_cast<std::uint16_t>(v) & 0xFF);
        block[i + 1] = static_cast<std::byte>(static_cast<std::uint16_t>(v) >> 8);
      }
      co_await out->async_write(std::move(block), asio::use_awaitable);
      timer.expires_after(100ms);
      co_await timer.async_wait(asio::use_awaitable);
    }
    out->close();
  } catch (const planet::Error& err) {
    std::printf("[server] recording stopped: %s\n", err.what());
  }
}

class HomeObject final : public HomeServant {
 public:
  explicit HomeObject(planet::Communicator& comm) : comm_(comm) {}

  std::string hello(const std::string& who, const planet::Current& c) override {
    std::printf("[server] hello from %s (link %s)\n", who.c_str(), c.connection->describe().c_str());
    std::fflush(stdout);
    return "welcome home, " + who;
  }
  std::int32_t subscribe(SoundListenerPrx listener, std::int32_t count,
                         const planet::Current& c) override {
    std::printf("[server] %s subscribed %s for %d sound events\n", c.connection->peer_pun().c_str(),
                listener.path().c_str(), count);
    std::fflush(stdout);
    asio::co_spawn(comm_.io(), publish(comm_, std::move(listener), count), asio::detached);
    return count;
  }
  std::int64_t upload_image(const planet::Binary& image, const planet::Current&) override {
    std::int64_t sum = 0;
    for (auto b : image.bytes) sum += std::to_integer<std::int64_t>(b);
    std::printf("[server] received a %zu-byte image, checksum %lld\n", image.bytes.size(),
                static_cast<long long>(sum));
    std::fflush(stdout);
    return sum;
  }
  std::int64_t uptime_ms(const planet::Current&) override {
    return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() -
                                                                 started_)
        .count();
  }
  planet::StreamRef listen(std::int32_t milliseconds, const planet::Current&) override {
    auto out = planet::OutputStream::create(comm_);
    asio::co_spawn(comm_.io(), record(comm_, out, milliseconds), asio::detached);
    return out->ref();
  }

 private:
  planet::Communicator& comm_;
  const std::chrono::steady_clock::time_point started_ = std::chrono::steady_clock::now();
};

int run_server(std::uint16_t port) {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGTERM);
  sigaddset(&set, SIGINT);
  pthread_sigmask(SIG_BLOCK, &set, nullptr);

  planet::CommunicatorOptions options;
  options.logger = quiet_logger("server");
  options.pun = "home-server";
  planet::Communicator comm(options);
  comm.adapter().add("/home", std::make_shared<HomeObject>(comm));
  const auto bound = comm.listen("127.0.0.1", port);
  std::printf("READY %u\n", bound);
  std::fflush(stdout);
  int sig = 0;
  sigwait(&set, &sig);
  std::printf("[server] stopping\n");
  return 0;
}

class Listener final : public SoundListenerServant {
 public:
  explicit Listener(int expected) : expected_(expected) {}
  void on_sound(const SoundEvent& e, const planet::Current&) override {
    std::printf("[client] SoundEvent #%d: direction %.0f deg, level %d dB\n", e.seq,
                e.direction_deg, e.level_db);
    if (++received_ == expected_) all_.set_value();
  }
  bool wait_all(std::chrono::seconds timeout) {
    return all_.get_future().wait_for(timeout) == std::future_status::ready;
  }
  int received() const { return received_.load(); }

 private:
  const int expected_;
  std::atomic<int> received_{0};
  std::promise<void> all_;
};

int run_client(std::uint16_t port) {
  planet::CommunicatorOptions options;
  options.logger = quiet_logger("client");
  options.pun = "living-room-robot";
  planet::Communicator comm(options);

  // The object the server will call back: our sound listener.
  constexpr int kEvents = 10;
  auto listener = std::make_shared<Listener>(kEvents);
  comm.adapter().add("/robot/sound-listener", listener);

  auto peer = comm.connect("127.0.0.1", port);
  if (!peer->wait_connected(10s)) {
    std::fprintf(stderr, "cannot connect to 127.0.0.1:%u: %s\n", port, peer->last_error().c_str());
    return 1;
  }
  std::printf("[client] connected to %s\n", peer->connection()->describe().c_str());
  HomePrx home(comm, peer, "/home");

  const auto t0 = std::chrono::steady_clock::now();
  const std::string greeting = home.hello("living-room-robot");
  const auto rtt = std::chrono::steady_clock::now() - t0;
  std::printf("[client] hello -> \"%s\" (%lld us)\n", greeting.c_str(),
              static_cast<long long>(std::chrono::duration_cast<std::chrono::microseconds>(rtt).count()));

  home.subscribe(comm.reference<SoundListener>("/robot/sound-listener"), kEvents);
  if (!listener->wait_all(10s)) {
    std::fprintf(stderr, "[client] only %d of %d events arrived\n", listener->received(), kEvents);
    return 1;
  }

  auto audio = home.listen(1000);
  std::size_t audio_bytes = 0;
  for (auto chunk = audio->read(); !chunk.empty(); chunk = audio->read()) audio_bytes += chunk.size();
  std::printf("[client] streamed %zu bytes of audio (1 s of 16 kHz 16-bit PCM)\n", audio_bytes);

  planet::Binary image;
  image.bytes.resize(16u << 20);
  std::int64_t expected = 0;
  for (std::size_t i = 0; i < image.bytes.size(); ++i) {
    image.bytes[i] = std::byte(i % 251);
    expected += static_cast<std::int64_t>(i % 251);
  }
  const auto upload_start = std::chrono::steady_clock::now();
  HomePrx patient = home;
  patient.set_timeout(60s);
  auto upload = patient.upload_image_async(std::move(image), asio::use_future);
  int small_calls = 0;
  while (upload.wait_for(0s) != std::future_status::ready) {
    (void)home.uptime_ms();
    ++small_calls;
  }
  const std::int64_t checksum = upload.get();
  const auto upload_ms = std::chrono::duration_cast<std::chrono::milliseconds>(
                             std::chrono::steady_clock::now() - upload_start)
                             .count();
  std::printf("[client] uploaded 16 MiB image in %lld ms, checksum %s; %d small calls completed "
              "during the upload\n",
              static_cast<long long>(upload_ms), checksum == expected ? "ok" : "MISMATCH",
              small_calls);

  try {
    HomePrx(comm, peer, "/garage").uptime_ms();
  } catch (const planet::Error& e) {
    std::printf("[client] calling a missing object fails clearly: %s\n", e.what());
  }
  const auto stats = peer->connection()->stats();
  std::printf("[client] done: %llu messages / %llu frames sent, %llu messages received\n",
              static_cast<unsigned long long>(stats.messages_sent),
              static_cast<unsigned long long>(stats.frames_sent),
              static_cast<unsigned long long>(stats.messages_received));
  return checksum == expected && audio_bytes == 32000 ? 0 : 1;
}

int run_both(const char* self) {
  int out[2];
  if (::pipe(out) != 0) return 1;
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, out[1], STDOUT_FILENO);
  posix_spawn_file_actions_addclose(&actions, out[0]);
  char server_arg[] = "server";
  char* argv[] = {const_cast<char*>(self), server_arg, nullptr};
  pid_t pid = 0;
  if (posix_spawn(&pid, self, &actions, nullptr, argv, environ) != 0) {
    std::fprintf(stderr, "cannot start the server process\n");
    return 1;
  }
  posix_spawn_file_actions_destroy(&actions);
  ::close(out[1]);
  FILE* server_out = ::fdopen(out[0], "r");
  char line[256];
  unsigned port = 0;
  if (!std::fgets(line, sizeof line, server_out) || std::sscanf(line, "READY %u", &port) != 1) {
    std::fprintf(stderr, "the server did not start\n");
    ::kill(pid, SIGKILL);
    return 1;
  }
  std::printf("[demo] server process %d listening on 127.0.0.1:%u; client process %d\n", pid,
              port, getpid());
  std::fflush(stdout);
  std::thread relay([server_out] {  // the server's own output, as it happens
    char l[512];
    while (std::fgets(l, sizeof l, server_out)) {
      std::fputs(l, stdout);
      std::fflush(stdout);
    }
  });
  const int rc = run_client(static_cast<std::uint16_t>(port));
  ::kill(pid, SIGTERM);
  int status = 0;
  ::waitpid(pid, &status, 0);
  relay.join();
  std::fclose(server_out);
  return rc;
}

}  // namespace demo

int main(int argc, char** argv) {
  CLI::App app{"PLANET demo: a server and a client exchanging calls, events and a large binary"};
  std::uint16_t port = 0;
  auto* server = app.add_subcommand("server", "run the server only");
  server->add_option("--port", port, "port to listen on (0: any)");
  auto* client = app.add_subcommand("client", "run the client only");
  client->add_option("port", port, "server port")->required();
  CLI11_PARSE(app, argc, argv);
  if (*server) return demo::run_server(port);
  if (*client) return demo::run_client(port);
  return demo::run_both(argv[0]);
}
