// PLANET streams: remote input-stream channels with pull-based backpressure (PLANET `stream`).
//
// The side that owns data (a microphone's device, a file server) creates an OutputStream and
// passes its `ref()` as an argument or result of a call. The receiver of that value opens an
// InputStream on the connection the value arrived over and pulls: it grants the writer credit
// (PULL, at most `window` bytes ahead of what it has consumed), the writer sends DATA only
// within that credit, and END when it is done. Memory is therefore bounded on both sides:
// the reader buffers at most `window` bytes, the writer's connection queue holds at most the
// reader's credit, and `OutputStream::async_write` completes only as the reader makes room.
// Either side may stop early: the reader with `InputStream::cancel`, the writer with
// `OutputStream::abort`; the other side's pending operation then fails with Error(failed)
// carrying the reason. A peer dying mid-stream fails the other side with Error(disconnected).
// Destroying a handle before the end cancels (reader) or aborts (writer) the stream.
//
// Asynchronous operations follow asio's completion-token model: the handler runs exactly once,
// on its associated executor (the communicator's io thread by default), never inside the
// initiating call. One read and one write may be outstanding per stream at a time.
#pragma once

#include <asio/any_io_executor.hpp>
#include <asio/associated_executor.hpp>
#include <asio/async_result.hpp>
#include <asio/executor_work_guard.hpp>
#include <asio/io_context.hpp>
#include <asio/post.hpp>
#include <chrono>
#include <cstddef>
#include <exception>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "icars/planet/detail/unique_function.h"
#include "icars/planet/frame.h"
#include "icars/planet/serializer.h"

namespace icars::planet {

class Communicator;
class Link;

namespace detail {
class OutputChannel;
class InputChannel;
}  // namespace detail

inline constexpr std::size_t kMaxStreamChunk = kMaxFramePayload - 10;  // 10: STREAM DATA header

struct StreamOptions {
  std::size_t window = 1u << 20;      // reader: bytes it lets the writer send ahead of it
  // writer: most data bytes per DATA message. Each STREAM message fits in one transport frame,
  // so the stream's messages arrive in the order sent; larger values are clamped to that.
  std::size_t chunk_size = kMaxStreamChunk;
  std::chrono::milliseconds bind_timeout{30000};  // writer: no reader pulled by then -> fails
};

class OutputStream {
 public:
  // A new stream whose reader is whoever receives `ref()`. Thread-safe.
  static std::shared_ptr<OutputStream> create(Communicator& communicator,
                                              StreamOptions options = {});
  ~OutputStream();  // aborts the stream unless it was closed or already ended
  OutputStream(const OutputStream&) = delete;
  OutputStream& operator=(const OutputStream&) = delete;

  StreamRef ref() const { return ref_; }

  // Appends `data` to the stream. Completion signature void(std::exception_ptr): null once all
  // of `data` has been handed to the reader's connection, which happens only as fast as the
  // reader grants credit; Error(failed) if the reader cancelled, Error(disconnected) if it died,
  // Error(timeout) if nobody opened the stream within bind_timeout.
  template <class Token>
  auto async_write(std::vector<std::byte> data, Token&& token) {
    return asio::async_initiate<Token, void(std::exception_ptr)>(
        [this](auto handler, std::vector<std::byte> bytes) {
          auto work = asio::make_work_guard(asio::get_associated_executor(handler, executor()));
          start_write(std::move(bytes),
                      [handler = std::move(handler), work = std::move(work)](
                          std::exception_ptr e) mutable {
                        auto ex = work.get_executor();
                        asio::post(ex, [handler = std::move(handler), e,
                                        work = std::move(work)]() mutable {
                          std::move(handler)(e);
                        });
                      });
        },
        token, std::move(data));
  }
  // Blocking form of async_write; throws the error. Not on the communicator's io thread.
  void write(std::span<const std::byte> data);
  // Ends the stream after everything written so far (END). Thread-safe, idempotent.
  void close();
  // Abandons the stream; the reader's pending and later reads fail with `reason`.
  void abort(const std::string& reason);

 private:
  OutputStream(Communicator& communicator, std::shared_ptr<detail::OutputChannel> channel,
               StreamRef ref);
  asio::any_io_executor executor() const;
  void start_write(std::vector<std::byte> data,
                   detail::UniqueFunction<void(std::exception_ptr)> done);

  Communicator* communicator_;
  std::shared_ptr<asio::io_context> io_;  // outlives the communicator if the handle does
  std::shared_ptr<detail::OutputChannel> channel_;
  StreamRef ref_;
};

class InputStream {
 public:
  // Opens the stream `ref` that arrived over `via` and starts pulling. Thread-safe.
  static std::shared_ptr<InputStream> open(Communicator& communicator,
                                           const std::shared_ptr<Link>& via, StreamRef ref,
                                           StreamOptions options = {});
  ~InputStream();  // cancels the stream unless it ended
  InputStream(const InputStream&) = delete;
  InputStream& operator=(const InputStream&) = delete;

  StreamRef ref() const { return ref_; }

  // Reads what has arrived (at least one DATA message, at most a quarter of the window, in
  // order). Completion signature void(std::exception_ptr, std::vector<std::byte>): the
  // non-empty data, an empty vector at the end of the stream, or the error (data that arrived
  // before an error is delivered first).
  template <class Token>
  auto async_read(Token&& token) {
    return asio::async_initiate<Token, void(std::exception_ptr, std::vector<std::byte>)>(
        [this](auto handler) {
          auto work = asio::make_work_guard(asio::get_associated_executor(handler, executor()));
          start_read([handler = std::move(handler), work = std::move(work)](
                         std::exception_ptr e, std::vector<std::byte> chunk) mutable {
            auto ex = work.get_executor();
            asio::post(ex, [handler = std::move(handler), e, chunk = std::move(chunk),
                            work = std::move(work)]() mutable {
              std::move(handler)(e, std::move(chunk));
            });
          });
        },
        token);
  }
  // Blocking form of async_read; throws the error. Not on the communicator's io thread.
  std::vector<std::byte> read();
  // Tells the writer to stop (CANCEL); pending and later reads fail with Error(failed).
  void cancel(const std::string& reason);

  // Bytes received and not yet read; never more than the window.
  std::size_t buffered() const;

 private:
  InputStream(Communicator& communicator, std::shared_ptr<detail::InputChannel> channel,
              StreamRef ref);
  asio::any_io_executor executor() const;
  void start_read(detail::UniqueFunction<void(std::exception_ptr, std::vector<std::byte>)> done);

  Communicator* communicator_;
  std::shared_ptr<asio::io_context> io_;  // outlives the communicator if the handle does
  std::shared_ptr<detail::InputChannel> channel_;
  StreamRef ref_;
};

}  // namespace icars::planet
