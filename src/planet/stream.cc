#include "icars/planet/stream.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <asio/dispatch.hpp>
#include <future>

#include "icars/planet/communicator.h"
#include "stream_table.h"

namespace icars::planet {

namespace detail {

namespace {
Error cancelled_error(const std::string& who, const std::string& reason) {
  return Error(ErrorKind::failed, fmt::format("stream {}: {}", who, reason));
}
}  // namespace

// --- OutputChannel ---------------------------------------------------------------------------

OutputChannel::OutputChannel(StreamTable& table, std::uint32_t id, StreamOptions options)
    : table_(table), id_(id), options_(options) {}

void OutputChannel::write(std::vector<std::byte> data, WriteDone done) {
  if (error_) {
    done(std::make_exception_ptr(*error_));
    return;
  }
  if (done_ || closing_) {
    done(std::make_exception_ptr(Error(
        ErrorKind::failed, done_ ? fmt::format("stream {}: a write is already pending", id_)
                                 : fmt::format("stream {}: write after close", id_))));
    return;
  }
  pending_ = std::move(data);
  offset_ = 0;
  done_ = std::move(done);
  pump();
}

void OutputChannel::close() {
  if (closing_ || error_) return;
  closing_ = true;
  pump();
}

void OutputChannel::abort(const std::string& reason) {
  if (finished_ || error_) return;
  fail(cancelled_error("aborted by the writer", reason), true);
}

void OutputChannel::on_pull(const std::shared_ptr<Connection>& from, std::uint32_t credit) {
  if (error_ || finished_) return;
  if (!connection_) {
    connection_ = from;
  } else if (connection_ != from) {
    table_.send_reason(*from, id_, StreamOp::abort,
                       "the stream is already being read over another connection");
    return;
  }
  credit_ += credit;
  pump();
}

void OutputChannel::on_cancel(const std::string& reason) {
  fail(cancelled_error("cancelled by the reader", reason), false);
}

void OutputChannel::on_connection_closed(const Error& reason) {
  fail(Error(ErrorKind::disconnected,
             fmt::format("stream {}: the reader's connection closed: {}", id_, reason.message())),
       false);
}

void OutputChannel::check_bind_deadline(std::chrono::steady_clock::time_point now) {
  if (connection_ || error_ || finished_) return;
  if (now - created_ < options_.bind_timeout) return;
  fail(Error(ErrorKind::timeout, fmt::format("stream {}: no reader opened it within {} ms", id_,
                                             options_.bind_timeout.count())),
       false);
}

void OutputChannel::pump() {
  if (!connection_ || error_) return;
  while (done_ && credit_ > 0 && offset_ < pending_.size()) {
    const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(
        {credit_, pending_.size() - offset_, options_.chunk_size}));
    if (!table_.send(*connection_, id_, StreamOp::data,
                     std::span(pending_).subspan(offset_, n))) {
      fail(Error(ErrorKind::disconnected,
                 fmt::format("stream {}: the reader's connection is gone", id_)),
           false);
      return;
    }
    credit_ -= n;
    offset_ += n;
  }
  if (done_ && offset_ == pending_.size()) {
    auto done = std::move(done_);
    done_ = {};
    pending_.clear();
    pending_.shrink_to_fit();
    done(nullptr);
  }
  if (closing_ && !done_ && !finished_) {
    table_.send(*connection_, id_, StreamOp::end, {});
    finish();
  }
}

void OutputChannel::fail(const Error& error, bool tell_reader) {
  if (error_ || finished_) return;
  error_ = error;
  if (tell_reader && connection_) table_.send_reason(*connection_, id_, StreamOp::abort, error.message());
  if (done_) {
    auto done = std::move(done_);
    done_ = {};
    done(std::make_exception_ptr(error));
  }
  finish();
}

void OutputChannel::finish() {
  finished_ = true;
  pending_.clear();
  table_.remove_output(id_);
}

// --- InputChannel ----------------------------------------------------------------------------

InputChannel::InputChannel(StreamTable& table, std::shared_ptr<Connection> connection,
                           std::uint32_t id, StreamOptions options)
    : table_(table), connection_(std::move(connection)), id_(id), options_(options) {}

void InputChannel::start() {
  if (!connection_ || !connection_->is_open()) {
    fail(Error(ErrorKind::disconnected,
               fmt::format("stream {}: the writer's connection is down", id_)));
    return;
  }
  table_.add_input(connection_->id(), id_, shared_from_this());
  registered_ = true;
  std::vector<std::byte> body;
  Writer w(body);
  w.u32(static_cast<std::uint32_t>(options_.window));
  outstanding_ = options_.window;
  if (!table_.send(*connection_, id_, StreamOp::pull, body)) {
    fail(Error(ErrorKind::disconnected, fmt::format("stream {}: the writer's connection is down", id_)));
  }
}

void InputChannel::read(ReadDone done) {
  if (done_) {
    done(std::make_exception_ptr(
             Error(ErrorKind::failed, fmt::format("stream {}: a read is already pending", id_))),
         {});
    return;
  }
  done_ = std::move(done);
  deliver();
}

void InputChannel::cancel(const std::string& reason) {
  if (error_ || (ended_ && chunks_.empty())) return;
  if (connection_ && registered_ && !ended_) {
    table_.send_reason(*connection_, id_, StreamOp::cancel, reason);
  }
  chunks_.clear();
  buffered_ = 0;
  error_ = cancelled_error("cancelled by the reader", reason);
  unregister();
  deliver();
}

void InputChannel::on_data(std::span<const std::byte> bytes) {
  if (error_ || ended_) return;
  if (bytes.size() > outstanding_) {
    const std::string reason = fmt::format("the writer sent {} bytes with only {} bytes of credit",
                                           bytes.size(), outstanding_);
    table_.send_reason(*connection_, id_, StreamOp::cancel, reason);
    fail(Error(ErrorKind::bad_data, fmt::format("stream {}: {}", id_, reason)));
    return;
  }
  outstanding_ -= bytes.size();
  if (bytes.empty()) return;
  chunks_.emplace_back(bytes.begin(), bytes.end());
  buffered_ += bytes.size();
  deliver();
}

void InputChannel::on_end() {
  if (error_ || ended_) return;
  ended_ = true;
  unregister();
  deliver();
}

void InputChannel::on_abort(const std::string& reason) {
  fail(cancelled_error("aborted by the writer", reason));
}

void InputChannel::on_connection_closed(const Error& reason) {
  fail(Error(ErrorKind::disconnected,
             fmt::format("stream {}: the writer's connection closed: {}", id_, reason.message())));
}

void InputChannel::deliver() {
  if (!done_) return;
  if (!chunks_.empty()) {
    // Hand over everything buffered (up to a quarter window) at once: one completion per
    // batch of DATA messages, not one per 16 KiB.
    std::vector<std::byte> chunk = std::move(chunks_.front());
    chunks_.pop_front();
    const std::size_t batch = std::max<std::size_t>(options_.window / 4, kMaxStreamChunk);
    while (!chunks_.empty() && chunk.size() + chunks_.front().size() <= batch) {
      chunk.insert(chunk.end(), chunks_.front().begin(), chunks_.front().end());
      chunks_.pop_front();
    }
    buffered_ -= chunk.size();
    consumed_ += chunk.size();
    // Grant the consumed bytes back once half the window is free: few PULLs, steady flow.
    if (!ended_ && !error_ && consumed_ >= options_.window / 2) {
      std::vector<std::byte> body;
      Writer w(body);
      w.u32(static_cast<std::uint32_t>(consumed_));
      outstanding_ += consumed_;
      consumed_ = 0;
      table_.send(*connection_, id_, StreamOp::pull, body);
    }
    auto done = std::move(done_);
    done_ = {};
    done(nullptr, std::move(chunk));
    return;
  }
  if (error_) {
    auto done = std::move(done_);
    done_ = {};
    done(std::make_exception_ptr(*error_), {});
  } else if (ended_) {
    auto done = std::move(done_);
    done_ = {};
    done(nullptr, {});
  }
}

void InputChannel::fail(const Error& error) {
  if (error_) return;
  if (ended_ && chunks_.empty()) return;
  error_ = error;
  unregister();
  deliver();
}

void InputChannel::unregister() {
  if (!registered_) return;
  registered_ = false;
  table_.remove_input(connection_->id(), id_);
}

// --- StreamTable -----------------------------------------------------------------------------

std::uint32_t StreamTable::allocate_id() {
  std::lock_guard lock(mutex_);
  std::uint32_t id = 0;
  do {
    id = next_id_++;
  } while (id == 0 || outputs_.contains(id));
  return id;
}

void StreamTable::add_output(std::uint32_t id, std::shared_ptr<OutputChannel> channel) {
  std::lock_guard lock(mutex_);
  outputs_[id] = std::move(channel);
}

void StreamTable::remove_output(std::uint32_t id) {
  std::lock_guard lock(mutex_);
  outputs_.erase(id);
}

void StreamTable::add_input(std::uint64_t connection_id, std::uint32_t id,
                            std::shared_ptr<InputChannel> channel) {
  std::lock_guard lock(mutex_);
  inputs_[{connection_id, id}] = std::move(channel);
}

void StreamTable::remove_input(std::uint64_t connection_id, std::uint32_t id) {
  std::lock_guard lock(mutex_);
  inputs_.erase({connection_id, id});
}

std::size_t StreamTable::size() const {
  std::lock_guard lock(mutex_);
  return outputs_.size() + inputs_.size();
}

void StreamTable::on_message(const std::shared_ptr<Connection>& from, Reader& r) {
  const std::uint32_t id = r.u32();
  const auto op = static_cast<StreamOp>(r.u8());
  std::shared_ptr<OutputChannel> output;
  std::shared_ptr<InputChannel> input;
  {
    std::lock_guard lock(mutex_);
    if (op == StreamOp::pull || op == StreamOp::cancel) {
      if (auto it = outputs_.find(id); it != outputs_.end()) output = it->second;
    } else {
      if (auto it = inputs_.find({from->id(), id}); it != inputs_.end()) input = it->second;
    }
  }
  switch (op) {
    case StreamOp::pull: {
      const std::uint32_t credit = r.u32();
      if (output) {
        output->on_pull(from, credit);
      } else {
        send_reason(*from, id, StreamOp::abort, "no such stream");
      }
      return;
    }
    case StreamOp::cancel: {
      const std::string reason = r.str();
      if (output && output->bound_to(from->id())) output->on_cancel(reason);
      return;
    }
    case StreamOp::data: {
      const std::size_t n = r.count(1, "stream data");
      auto bytes = r.raw(n);
      if (input) {
        input->on_data(bytes);
      } else {
        // The reader is gone (cancelled, destroyed): tell the writer to stop.
        send_reason(*from, id, StreamOp::cancel, "no reader for this stream");
      }
      return;
    }
    case StreamOp::end:
      if (input) input->on_end();
      return;
    case StreamOp::abort: {
      const std::string reason = r.str();
      if (input) input->on_abort(reason);
      return;
    }
  }
  log_.warn("STREAM message with unknown operation {} for stream {} from {} dropped",
            static_cast<unsigned>(op), id, from->describe());
}

void StreamTable::on_close(const Connection& connection, const Error& reason) {
  std::vector<std::shared_ptr<OutputChannel>> outputs;
  std::vector<std::shared_ptr<InputChannel>> inputs;
  {
    std::lock_guard lock(mutex_);
    for (const auto& [id, channel] : outputs_) {
      if (channel->bound_to(connection.id())) outputs.push_back(channel);
    }
    for (auto it = inputs_.lower_bound({connection.id(), 0});
         it != inputs_.end() && it->first.first == connection.id(); ++it) {
      inputs.push_back(it->second);
    }
  }
  for (auto& c : outputs) c->on_connection_closed(reason);
  for (auto& c : inputs) c->on_connection_closed(reason);
}

void StreamTable::sweep(std::chrono::steady_clock::time_point now) {
  std::vector<std::shared_ptr<OutputChannel>> outputs;
  {
    std::lock_guard lock(mutex_);
    for (const auto& [id, channel] : outputs_) outputs.push_back(channel);
  }
  for (auto& c : outputs) c->check_bind_deadline(now);
}

bool StreamTable::send(Connection& to, std::uint32_t id, StreamOp op,
                       std::span<const std::byte> body) {
  std::vector<std::byte> message;
  message.reserve(10 + body.size());
  Writer w(message);
  w.u8(static_cast<std::uint8_t>(RmiCode::stream));
  w.u32(id);
  w.u8(static_cast<std::uint8_t>(op));
  if (op == StreamOp::data) w.length(body.size());
  w.raw(body);
  try {
    to.send(std::move(message));
    return true;
  } catch (const Error& e) {
    log_.debug("STREAM {} for stream {} not sent to {}: {}", static_cast<unsigned>(op), id,
               to.describe(), e.what());
    return false;
  }
}

bool StreamTable::send_reason(Connection& to, std::uint32_t id, StreamOp op,
                              const std::string& reason) {
  std::vector<std::byte> body;
  Writer w(body);
  w.str(reason);
  return send(to, id, op, body);
}

}  // namespace detail

// --- Handles ---------------------------------------------------------------------------------

std::shared_ptr<OutputStream> OutputStream::create(Communicator& communicator,
                                                   StreamOptions options) {
  options.chunk_size = std::clamp<std::size_t>(options.chunk_size, 1, kMaxStreamChunk);
  auto& table = communicator.stream_table();
  const std::uint32_t id = table.allocate_id();
  auto channel = std::make_shared<detail::OutputChannel>(table, id, options);
  table.add_output(id, channel);
  return std::shared_ptr<OutputStream>(new OutputStream(communicator, channel, StreamRef{id}));
}

OutputStream::OutputStream(Communicator& communicator,
                           std::shared_ptr<detail::OutputChannel> channel, StreamRef ref)
    : communicator_(&communicator), io_(communicator.shared_io()), channel_(std::move(channel)), ref_(ref) {}

OutputStream::~OutputStream() {
  asio::dispatch(*io_,
                 [channel = channel_] { channel->abort("the writer dropped the stream"); });
}

asio::any_io_executor OutputStream::executor() const { return communicator_->executor(); }

void OutputStream::start_write(std::vector<std::byte> data,
                               detail::UniqueFunction<void(std::exception_ptr)> done) {
  asio::dispatch(communicator_->io(),
                 [channel = channel_, data = std::move(data), done = std::move(done)]() mutable {
                   channel->write(std::move(data), std::move(done));
                 });
}

void OutputStream::write(std::span<const std::byte> data) {
  if (communicator_->in_io_thread()) {
    throw Error(ErrorKind::failed, "blocking stream write on the PLANET io thread would deadlock");
  }
  std::promise<void> done;
  auto result = done.get_future();
  start_write(std::vector<std::byte>(data.begin(), data.end()),
              [&done](std::exception_ptr e) {
                if (e) {
                  done.set_exception(e);
                } else {
                  done.set_value();
                }
              });
  result.get();
}

void OutputStream::close() {
  asio::dispatch(communicator_->io(), [channel = channel_] { channel->close(); });
}

void OutputStream::abort(const std::string& reason) {
  asio::dispatch(communicator_->io(), [channel = channel_, reason] { channel->abort(reason); });
}

std::shared_ptr<InputStream> InputStream::open(Communicator& communicator,
                                               const std::shared_ptr<Link>& via, StreamRef ref,
                                               StreamOptions options) {
  if (options.window == 0 || options.window > 0xFFFFFFFFu) {
    throw std::invalid_argument("StreamOptions::window must be between 1 and 4 GiB - 1");
  }
  auto channel = std::make_shared<detail::InputChannel>(
      communicator.stream_table(), via ? via->connection() : nullptr, ref.id, options);
  asio::dispatch(communicator.io(), [channel] { channel->start(); });
  return std::shared_ptr<InputStream>(new InputStream(communicator, channel, ref));
}

InputStream::InputStream(Communicator& communicator, std::shared_ptr<detail::InputChannel> channel,
                         StreamRef ref)
    : communicator_(&communicator), io_(communicator.shared_io()), channel_(std::move(channel)), ref_(ref) {}

InputStream::~InputStream() {
  asio::dispatch(*io_,
                 [channel = channel_] { channel->cancel("the reader dropped the stream"); });
}

asio::any_io_executor InputStream::executor() const { return communicator_->executor(); }

void InputStream::start_read(
    detail::UniqueFunction<void(std::exception_ptr, std::vector<std::byte>)> done) {
  asio::dispatch(communicator_->io(), [channel = channel_, done = std::move(done)]() mutable {
    channel->read(std::move(done));
  });
}

std::vector<std::byte> InputStream::read() {
  if (communicator_->in_io_thread()) {
    throw Error(ErrorKind::failed, "blocking stream read on the PLANET io thread would deadlock");
  }
  std::promise<std::vector<std::byte>> done;
  auto result = done.get_future();
  start_read([&done](std::exception_ptr e, std::vector<std::byte> chunk) {
    if (e) {
      done.set_exception(e);
    } else {
      done.set_value(std::move(chunk));
    }
  });
  return result.get();
}

void InputStream::cancel(const std::string& reason) {
  asio::dispatch(communicator_->io(), [channel = channel_, reason] { channel->cancel(reason); });
}

std::size_t InputStream::buffered() const { return channel_->buffered(); }

}  // namespace icars::planet
