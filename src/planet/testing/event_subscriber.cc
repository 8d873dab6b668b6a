// A subscriber process for the publish/subscribe tests: connects to a TickSource, subscribes a
// TickListener it hosts, prints "SUBSCRIBED", counts the ticks and, on the tick with seq -1,
// prints "DONE <ticks received> <1 if they came in order, else 0>" and exits.
#include <CLI/CLI.hpp>
#include <future>
#include <iostream>

#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"
#include "test_interfaces.h"

namespace p = icars::planet;
using planet_test::Tick;
using planet_test::TickListener;
using planet_test::TickSource;

int main(int argc, char** argv) {
  CLI::App app{"PLANET test subscriber"};
  std::uint16_t port = 0;
  app.add_option("--port", port, "port of the publisher")->required();
  CLI11_PARSE(app, argc, argv);

  p::CommunicatorOptions options;
  options.name = "subscriber";
  options.connection.heartbeat_timeout = std::chrono::seconds(60);
  p::Communicator communicator(options);

  std::int64_t received = 0;
  std::int64_t next = 0;
  bool in_order = true;
  std::promise<void> done;
  auto listener = std::make_shared<p::Servant>(std::string(TickListener::type_id));
  listener->implement(TickListener::on_tick, [&](const Tick& tick) {
    if (tick.seq < 0) {
      std::cout << "DONE " << received << ' ' << (in_order ? 1 : 0) << std::endl;
      done.set_value();
      return;
    }
    in_order = in_order && tick.seq == next;
    next = tick.seq + 1;
    ++received;
  });
  communicator.adapter().add("/listener", listener);

  auto peer = communicator.connect("127.0.0.1", port);
  if (!peer->wait_connected(std::chrono::seconds(60))) {
    std::cerr << "cannot reach the publisher: " << peer->last_error() << std::endl;
    return 1;
  }
  p::Proxy source(communicator, peer, "/ticks");
  source.call(TickSource::subscribe, communicator.reference<TickListener>("/listener"));
  std::cout << "SUBSCRIBED" << std::endl;
  done.get_future().wait();
  return 0;
}
