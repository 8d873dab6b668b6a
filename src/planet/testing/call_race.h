// Synchronous callers racing the io thread on one link, for the tests of the direct paths
// (rmi_call_test.cc over plaintext, security_test.cc over TLS): `threads` callers make `calls`
// calls each to the Echo servant at /echo; caller 0 has the server call this client back
// (`callback`, a Callback at the client) every 20th call, caller 1 adds an async call per call
// (replies nobody waits for on a thread), and with `large` caller 2 sends a message of about
// 1 MiB every 30th call (many frames, on the io thread's path). Every reply is checked.
#pragma once

#include <atomic>
#include <cstddef>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "child_process.h"
#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"
#include "test_interfaces.h"

namespace planet_test {

struct CallRace {
  int wrong = 0;       // replies that were not the echo of their call
  int async_ok = 0;    // async calls answered right
  bool async_all_done = false;
};

inline CallRace race_calls(icars::planet::Communicator& client, const std::shared_ptr<icars::planet::Peer>& peer,
                           const icars::planet::Ref<Callback>& callback, int threads, int calls, bool large) {
  namespace p = icars::planet;
  std::atomic<int> wrong{0};
  std::atomic<int> async_done{0};
  std::atomic<int> async_ok{0};
  std::vector<std::thread> callers;
  for (int t = 0; t < threads; ++t) {
    callers.emplace_back([&, t] {
      p::Proxy echo(client, peer, "/echo");
      for (int i = 0; i < calls; ++i) {
        const std::string text = std::to_string(t) + ":" + std::to_string(i);
        if (t == 0 && i % 20 == 0) {
          if (echo.call(Echo::call_back, callback, text) != "heard " + text) ++wrong;
        } else if (large && t == 2 && i % 30 == 0) {
          p::Binary big{std::vector<std::byte>((std::size_t{1} << 20) + static_cast<std::size_t>(i), std::byte{0})};
          for (std::size_t k = 0; k < big.bytes.size(); k += 4093) {
            big.bytes[k] = static_cast<std::byte>(k + static_cast<std::size_t>(i));
          }
          if (echo.call(Echo::echo_binary, big) != big) ++wrong;
        } else if (echo.call(Echo::echo_string, text) != text) {
          ++wrong;
        }
        if (t == 1) {
          echo.async_call(Echo::echo_int, {i}, [&, i](std::exception_ptr e, std::int32_t v) {
            if (!e && v == i) ++async_ok;
            ++async_done;
          });
        }
      }
    });
  }
  for (auto& c : callers) c.join();
  CallRace result;
  result.async_all_done = wait_until([&] { return async_done.load() == calls; }, std::chrono::seconds(30));
  result.wrong = wrong.load();
  result.async_ok = async_ok.load();
  return result;
}

}  // namespace planet_test
