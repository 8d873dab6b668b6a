// Private: the stream channels of one communicator and the STREAM messages between them.
//
// Every channel's state lives on the communicator's io thread; the table's maps are guarded by a
// mutex because handles register channels from any thread. Writers are keyed by the stream id
// they allocated; readers by (connection id, stream id), since ids are only unique per writer.
#pragma once

#include <chrono>
#include <cstdint>
#include <deque>
#include <exception>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "icars/planet/connection.h"
#include "icars/planet/detail/unique_function.h"
#include "icars/planet/error.h"
#include "icars/planet/rmi_message.h"
#include "icars/planet/serializer.h"
#include "icars/planet/stream.h"

namespace spdlog {
class logger;
}

namespace icars::planet::detail {

using WriteDone = UniqueFunction<void(std::exception_ptr)>;
using ReadDone = UniqueFunction<void(std::exception_ptr, std::vector<std::byte>)>;

class StreamTable;

// The writer end (io thread only).
class OutputChannel : public std::enable_shared_from_this<OutputChannel> {
 public:
  OutputChannel(StreamTable& table, std::uint32_t id, StreamOptions options);

  void write(std::vector<std::byte> data, WriteDone done);
  void close();
  void abort(const std::string& reason);
  void on_pull(const std::shared_ptr<Connection>& from, std::uint32_t credit);
  void on_cancel(const std::string& reason);
  void on_connection_closed(const Error& reason);
  void check_bind_deadline(std::chrono::steady_clock::time_point now);
  bool bound_to(std::uint64_t connection_id) const {
    return connection_ && connection_->id() == connection_id;
  }

 private:
  void pump();
  void fail(const Error& error, bool tell_reader);
  void finish();

  StreamTable& table_;
  std::uint32_t id_;
  StreamOptions options_;
  std::chrono::steady_clock::time_point created_ = std::chrono::steady_clock::now();
  std::shared_ptr<Connection> connection_;  // set by the first PULL
  std::uint64_t credit_ = 0;
  std::vector<std::byte> pending_;
  std::size_t offset_ = 0;
  WriteDone done_;
  bool closing_ = false;
  bool finished_ = false;
  std::optional<Error> error_;
};

// The reader end (io thread only).
class InputChannel : public std::enable_shared_from_this<InputChannel> {
 public:
  InputChannel(StreamTable& table, std::shared_ptr<Connection> connection, std::uint32_t id,
               StreamOptions options);

  void start();  // registers and grants the first window, or fails if the link is down
  void read(ReadDone done);
  void cancel(const std::string& reason);
  void on_data(std::span<const std::byte> bytes);
  void on_end();
  void on_abort(const std::string& reason);
  void on_connection_closed(const Error& reason);
  std::size_t buffered() const { return buffered_.load(); }

 private:
  void deliver();
  void fail(const Error& error);
  void unregister();

  StreamTable& table_;
  std::shared_ptr<Connection> connection_;
  std::uint32_t id_;
  StreamOptions options_;
  std::deque<std::vector<std::byte>> chunks_;
  std::atomic<std::size_t> buffered_{0};
  std::uint64_t outstanding_ = 0;  // credit granted and not yet used by the writer
  std::uint64_t consumed_ = 0;     // bytes read since the last grant
  ReadDone done_;
  bool ended_ = false;
  bool registered_ = false;
  std::optional<Error> error_;
};

class StreamTable {
 public:
  explicit StreamTable(spdlog::logger& log) : log_(log) {}

  std::uint32_t allocate_id();
  void add_output(std::uint32_t id, std::shared_ptr<OutputChannel> channel);
  void remove_output(std::uint32_t id);
  void add_input(std::uint64_t connection_id, std::uint32_t id,
                 std::shared_ptr<InputChannel> channel);
  void remove_input(std::uint64_t connection_id, std::uint32_t id);

  // A STREAM message (the reader is positioned after the RMI code). Io thread.
  void on_message(const std::shared_ptr<Connection>& from, Reader& r);
  void on_close(const Connection& connection, const Error& reason);
  void sweep(std::chrono::steady_clock::time_point now);

  // Sends one STREAM operation; false (and logged) when the connection cannot take it.
  bool send(Connection& to, std::uint32_t id, StreamOp op, std::span<const std::byte> body);
  bool send_reason(Connection& to, std::uint32_t id, StreamOp op, const std::string& reason);
  spdlog::logger& log() { return log_; }

  std::size_t size() const;

 private:
  spdlog::logger& log_;
  mutable std::mutex mutex_;
  std::uint32_t next_id_ = 1;
  std::unordered_map<std::uint32_t, std::shared_ptr<OutputChannel>> outputs_;
  std::map<std::pair<std::uint64_t, std::uint32_t>, std::shared_ptr<InputChannel>> inputs_;
};

}  // namespace icars::planet::detail
