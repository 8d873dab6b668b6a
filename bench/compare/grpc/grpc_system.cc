// gRPC as a compared system (../system.h): the Bench service of bench.proto, written as a gRPC
// user would. The server uses the callback API (a reactor per call, so 100 long-lived Subscribe
// streams hold no thread each); clients use the sync stub for single calls, the callback stub
// for pipelining, and a ClientReadReactor per subscriber stream. Channel and server settings are
// gRPC's defaults except the message size limits (the default receive limit is 4 MiB), that each
// channel owns its connection (see open_channel) and that the server does not share its port.
// "grpc-tls" is the same over gRPC's TLS credentials (ChannelSecurity, server_credentials).
#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <fstream>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <unordered_set>
#include <utility>
#include <vector>

#include "../system.h"
#include "bench.grpc.pb.h"

namespace icars::bench {
namespace {

namespace pb = ::icars::compare;

using Clock = std::chrono::steady_clock;

// gRPC's "no limit" for GRPC_ARG_MAX_{RECEIVE,SEND}_MESSAGE_LENGTH; the defaults are 4 MiB for
// receiving and no limit for sending, on both clients and servers.
constexpr int kNoMessageSizeLimit = -1;

std::string describe(const grpc::Status& status) {
  // clang-format off
  static constexpr std::array<const char*, 17> kNames = {
      "OK", "CANCELLED", "UNKNOWN", "INVALID_ARGUMENT", "DEADLINE_EXCEEDED", "NOT_FOUND",
      "ALREADY_EXISTS", "PERMISSION_DENIED", "RESOURCE_EXHAUSTED", "FAILED_PRECONDITION",
      "ABORTED", "OUT_OF_RANGE", "UNIMPLEMENTED", "INTERNAL", "UNAVAILABLE", "DATA_LOSS",
      "UNAUTHENTICATED"};
  // clang-format on
  const auto code = static_cast<std::size_t>(status.error_code());
  const std::string name = code < kNames.size() ? kNames[code] : std::to_string(code);
  return name + ": " + status.error_message();
}

void check(const char* method, const grpc::Status& status) {
  if (!status.ok()) {
    throw std::runtime_error(std::string("grpc ") + method + " failed: " + describe(status));
  }
}

std::string address(const std::string& host, std::uint16_t port) {
  return host + ":" + std::to_string(port);
}

// The whole of a PEM file, as gRPC's TLS credentials take it.
std::string read_pem(const std::string& file) {
  std::ifstream in(file);
  std::ostringstream text;
  if (!(in && text << in.rdbuf())) {
    throw std::runtime_error("grpc-tls: cannot read '" + file +
                             "' (make it with scripts/make-certs.sh DIR, pass --certs DIR)");
  }
  return text.str();
}

// What a client's channels connect with: plaintext, or TLS checking the server's certificate
// against the CA and the target host (gRPC's default check; 127.0.0.1 is a name server.pem
// carries). No client certificate is presented.
struct ChannelSecurity {
  std::shared_ptr<grpc::ChannelCredentials> credentials;
  bool tls = false;

  static ChannelSecurity of(const std::optional<TlsFiles>& tls) {
    if (!tls) return {grpc::InsecureChannelCredentials(), false};
    grpc::SslCredentialsOptions options;
    options.pem_root_certs = read_pem(tls->ca());
    return {grpc::SslCredentials(options), true};
  }
};

// The server's: plaintext, or TLS presenting server.pem and asking for no client certificate.
std::shared_ptr<grpc::ServerCredentials> server_credentials(const std::optional<TlsFiles>& tls) {
  if (!tls) return grpc::InsecureServerCredentials();
  grpc::SslServerCredentialsOptions options(GRPC_SSL_DONT_REQUEST_CLIENT_CERTIFICATE);
  options.pem_key_cert_pairs.push_back(
      {read_pem(tls->private_key()), read_pem(tls->certificate())});
  return grpc::SslServerCredentials(options);
}

// One channel = one HTTP/2 connection. gRPC otherwise shares a connection (subchannel) among all
// channels of a process with the same target and arguments; a local subchannel pool gives this
// channel its own. Reconnection is gRPC's default: after a lost connection the channel goes IDLE
// and the next call connects; failed connection attempts back off 1 s, then x1.6 each time
// (+-20% jitter) up to 120 s, with a 20 s minimum connect timeout.
std::shared_ptr<grpc::Channel> open_channel(const std::string& host, std::uint16_t port,
                                            const ChannelSecurity& security) {
  grpc::ChannelArguments arguments;
  arguments.SetMaxReceiveMessageSize(kNoMessageSizeLimit);
  arguments.SetMaxSendMessageSize(kNoMessageSizeLimit);
  arguments.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  return grpc::CreateCustomChannel(address(host, port), security.credentials, arguments);
}

// Connects now rather than at the first call, so that connecting is not timed as a call.
void wait_connected(grpc::Channel& channel, const std::string& host, std::uint16_t port,
                    const ChannelSecurity& security) {
  if (!channel.WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(10))) {
    throw std::runtime_error(
        "grpc: cannot connect to " + address(host, port) + " within 10 s (is the server running?" +
        (security.tls ? " Is its certificate signed by the CA, for " + host + "?)" : ")"));
  }
}

pb::Blob to_blob(const Bytes& data) {
  pb::Blob blob;
  blob.set_data(data.data(), data.size());
  return blob;
}

// ---------------------------------------------------------------------------------------------
// Server

class EventHub;

// One Subscribe stream at the server: writes its queued events one at a time (the callback API
// allows one write in flight), then Finishes once the client cancels or a write fails.
class SubscriberStream final : public grpc::ServerWriteReactor<pb::Event> {
 public:
  SubscriberStream(EventHub& hub, std::shared_ptr<const pb::Event> hello);

  // Queues `events`; returns the event whose write the caller must start (start_write) after
  // releasing its own locks, or nullptr. The stream stays alive until that write completes.
  const pb::Event* post(const std::vector<std::shared_ptr<const pb::Event>>& events);
  void start_write(const pb::Event* event) { StartWrite(event); }

  void OnWriteDone(bool ok) override;
  void OnCancel() override;
  void OnDone() override;

 private:
  void finish_if_idle_locked(bool& finish);

  EventHub& hub_;
  std::mutex mutex_;
  std::deque<std::shared_ptr<const pb::Event>> queue_;
  std::shared_ptr<const pb::Event> writing_;  // the event of the write in flight, or null
  bool closing_ = false;                      // cancelled or a write failed: write no more
  bool finished_ = false;                     // Finish called (exactly once)
};

// The open Subscribe streams; Publish queues the same immutable events on each of them.
class EventHub {
 public:
  void add(SubscriberStream* stream) {
    const std::lock_guard lock(mutex_);
    streams_.insert(stream);
  }
  void remove(SubscriberStream* stream) {
    const std::lock_guard lock(mutex_);
    streams_.erase(stream);
  }

  void publish(std::int32_t count, std::uint64_t payload_size) {
    std::vector<std::shared_ptr<const pb::Event>> events;
    events.reserve(static_cast<std::size_t>(count));
    const std::string payload(payload_size, '\x5a');
    const std::uint64_t first = next_seq_.fetch_add(static_cast<std::uint64_t>(count));
    for (std::int32_t i = 0; i < count; ++i) {
      auto event = std::make_shared<pb::Event>();
      event->set_seq(first + static_cast<std::uint64_t>(i));
      event->set_payload(payload);
      events.push_back(std::move(event));
    }
    // Writes start outside the lock: a stream with a write in flight cannot finish.
    std::vector<std::pair<SubscriberStream*, const pb::Event*>> to_start;
    {
      const std::lock_guard lock(mutex_);
      for (SubscriberStream* stream : streams_) {
        if (const pb::Event* first_event = stream->post(events)) {
          to_start.emplace_back(stream, first_event);
        }
      }
    }
    for (auto [stream, event] : to_start) stream->start_write(event);
  }

 private:
  std::mutex mutex_;
  std::unordered_set<SubscriberStream*> streams_;
  std::atomic<std::uint64_t> next_seq_{1};  // seq 0 is the hello
};

SubscriberStream::SubscriberStream(EventHub& hub, std::shared_ptr<const pb::Event> hello)
    : hub_(hub), writing_(std::move(hello)) {
  // Registered before the hello is written, so a client that has the hello gets every event
  // published after it.
  hub_.add(this);
  StartWrite(writing_.get());
}

const pb::Event* SubscriberStream::post(
    const std::vector<std::shared_ptr<const pb::Event>>& events) {
  const std::lock_guard lock(mutex_);
  if (closing_ || events.empty()) return nullptr;
  queue_.insert(queue_.end(), events.begin(), events.end());
  if (writing_) return nullptr;
  writing_ = std::move(queue_.front());
  queue_.pop_front();
  return writing_.get();
}

void SubscriberStream::OnWriteDone(bool ok) {
  const pb::Event* next = nullptr;
  bool finish = false;
  {
    const std::lock_guard lock(mutex_);
    writing_.reset();
    if (!ok) closing_ = true;
    if (!closing_ && !queue_.empty()) {
      writing_ = std::move(queue_.front());
      queue_.pop_front();
      next = writing_.get();
    }
    finish_if_idle_locked(finish);
  }
  if (next) StartWrite(next);
  if (finish) Finish(grpc::Status::CANCELLED);
}

void SubscriberStream::OnCancel() {
  bool finish = false;
  {
    const std::lock_guard lock(mutex_);
    closing_ = true;
    finish_if_idle_locked(finish);
  }
  if (finish) Finish(grpc::Status::CANCELLED);
}

void SubscriberStream::finish_if_idle_locked(bool& finish) {
  if (closing_ && !writing_ && !finished_) {
    queue_.clear();
    finished_ = true;
    finish = true;
  }
}

void SubscriberStream::OnDone() {
  hub_.remove(this);
  delete this;
}

grpc::ServerUnaryReactor* finish(grpc::CallbackServerContext* context, const grpc::Status& status) {
  grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
  reactor->Finish(status);
  return reactor;
}

class BenchService final : public pb::Bench::CallbackService {
 public:
  BenchService() {
    auto hello = std::make_shared<pb::Event>();
    hello->set_seq(0);
    hello_ = std::move(hello);
  }

  grpc::ServerUnaryReactor* EchoInt(grpc::CallbackServerContext* context, const pb::Int32* request,
                                    pb::Int32* response) override {
    response->set_value(request->value());
    return finish(context, grpc::Status::OK);
  }

  grpc::ServerUnaryReactor* SizeOf(grpc::CallbackServerContext* context, const pb::Blob* request,
                                   pb::UInt64* response) override {
    response->set_value(request->data().size());
    return finish(context, grpc::Status::OK);
  }

  grpc::ServerUnaryReactor* EchoBytes(grpc::CallbackServerContext* context, const pb::Blob* request,
                                      pb::Blob* response) override {
    response->set_data(request->data());
    return finish(context, grpc::Status::OK);
  }

  grpc::ServerUnaryReactor* Publish(grpc::CallbackServerContext* context,
                                    const pb::PublishRequest* request, pb::Empty*) override {
    if (request->count() < 0) {
      return finish(context,
                    grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "negative event count"));
    }
    hub_.publish(request->count(), request->payload_size());
    return finish(context, grpc::Status::OK);
  }

  grpc::ServerWriteReactor<pb::Event>* Subscribe(grpc::CallbackServerContext*,
                                                 const pb::SubscribeRequest*) override {
    return new SubscriberStream(hub_, hello_);  // deletes itself in OnDone
  }

 private:
  EventHub hub_;
  std::shared_ptr<const pb::Event> hello_;
};

// ---------------------------------------------------------------------------------------------
// Client

// `count` EchoInt calls through the callback stub, at most `window` in flight: each answer
// starts the next call from gRPC's callback thread.
class Pipeline : public std::enable_shared_from_this<Pipeline> {
 public:
  Pipeline(pb::Bench::Stub& stub, std::int64_t count) : stub_(stub), count_(count) {}

  void run(int window) {
    std::int64_t first_batch = 0;
    {
      const std::lock_guard lock(mutex_);
      first_batch = std::min<std::int64_t>(window, count_);
      issued_ = first_batch;
      outstanding_ = first_batch;
    }
    for (std::int64_t i = 0; i < first_batch; ++i) start(i);
    std::unique_lock lock(mutex_);
    done_.wait(lock, [&] { return outstanding_ == 0 && (issued_ == count_ || !error_.empty()); });
    if (!error_.empty()) throw std::runtime_error(error_);
  }

 private:
  struct Call {
    grpc::ClientContext context;
    pb::Int32 request;
    pb::Int32 response;
  };

  void start(std::int64_t index) {
    auto* call = new Call;
    call->request.set_value(
        static_cast<std::int32_t>(index % std::numeric_limits<std::int32_t>::max()));
    stub_.async()->EchoInt(&call->context, &call->request, &call->response,
                           [self = shared_from_this(), call](grpc::Status status) {
                             self->on_answer(std::unique_ptr<Call>(call), status);
                           });
  }

  void on_answer(std::unique_ptr<Call> call, const grpc::Status& status) {
    std::string error;
    if (!status.ok()) {
      error = "grpc EchoInt (pipelined) failed: " + describe(status);
    } else if (call->response.value() != call->request.value()) {
      error = "grpc EchoInt (pipelined) answered " + std::to_string(call->response.value()) +
              " to " + std::to_string(call->request.value());
    }
    call.reset();
    std::int64_t next = -1;
    {
      const std::lock_guard lock(mutex_);
      --outstanding_;
      if (!error.empty() && error_.empty()) error_ = std::move(error);
      if (error_.empty() && issued_ < count_) {
        next = issued_++;
        ++outstanding_;
      }
      if (outstanding_ == 0) done_.notify_all();
    }
    if (next >= 0) start(next);
  }

  pb::Bench::Stub& stub_;
  const std::int64_t count_;
  std::mutex mutex_;
  std::condition_variable done_;
  std::int64_t issued_ = 0;
  std::int64_t outstanding_ = 0;
  std::string error_;  // the first failure; no call starts after it
};

class GrpcClient final : public Client {
 public:
  GrpcClient(const ChannelSecurity& security, const std::string& host, std::uint16_t port)
      : channel_(open_channel(host, port, security)), stub_(pb::Bench::NewStub(channel_)) {
    wait_connected(*channel_, host, port, security);
  }

  std::int32_t call(std::int32_t x) override {
    grpc::ClientContext context;
    pb::Int32 request;
    pb::Int32 response;
    request.set_value(x);
    check("EchoInt", stub_->EchoInt(&context, request, &response));
    return response.value();
  }

  std::uint64_t upload(const Bytes& data) override {
    grpc::ClientContext context;
    pb::UInt64 response;
    check("SizeOf", stub_->SizeOf(&context, to_blob(data), &response));
    return response.value();
  }

  Bytes echo(const Bytes& data) override {
    grpc::ClientContext context;
    pb::Blob response;
    check("EchoBytes", stub_->EchoBytes(&context, to_blob(data), &response));
    const auto* begin = reinterpret_cast<const std::byte*>(response.data().data());
    return Bytes(begin, begin + response.data().size());
  }

  void pipeline(std::int64_t count, int window) override {
    if (count < 0 || window < 1) {
      throw std::invalid_argument("grpc pipeline: count must be >= 0 and window >= 1");
    }
    std::make_shared<Pipeline>(*stub_, count)->run(window);
  }

  bool try_call() noexcept override {
    try {
      grpc::ClientContext context;
      context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(1));
      // Wait (up to the deadline) for the channel to reconnect instead of failing at once while
      // it is in TRANSIENT_FAILURE; this does not change when gRPC attempts to reconnect.
      context.set_wait_for_ready(true);
      pb::Int32 request;
      pb::Int32 response;
      request.set_value(17);
      return stub_->EchoInt(&context, request, &response).ok() && response.value() == 17;
    } catch (...) {
      return false;
    }
  }

 private:
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<pb::Bench::Stub> stub_;
};

// ---------------------------------------------------------------------------------------------
// Subscribers

class GrpcSubscribers;

// One Subscribe stream at the client, always with one read pending, until OnDone.
class SubscriberReader final : public grpc::ClientReadReactor<pb::Event> {
 public:
  SubscriberReader(GrpcSubscribers& owner, std::size_t index) : owner_(owner), index_(index) {}

  void start(pb::Bench::Stub& stub) {
    stub.async()->Subscribe(&context_, &request_, this);
    StartRead(&event_);
    StartCall();
  }
  void cancel() { context_.TryCancel(); }

  void OnReadDone(bool ok) override;  // false: the stream ended, OnDone follows
  void OnDone(const grpc::Status& status) override;

 private:
  GrpcSubscribers& owner_;
  const std::size_t index_;
  grpc::ClientContext context_;
  pb::SubscribeRequest request_;
  pb::Event event_;
};

class GrpcSubscribers final : public Subscribers {
 public:
  GrpcSubscribers(const ChannelSecurity& security, const std::string& host, std::uint16_t port,
                  int count)
      : publisher_channel_(open_channel(host, port, security)),
        publisher_(pb::Bench::NewStub(publisher_channel_)),
        received_(static_cast<std::size_t>(count), 0) {
    wait_connected(*publisher_channel_, host, port, security);
    subscriptions_.reserve(static_cast<std::size_t>(count));
    for (std::size_t i = 0; i < static_cast<std::size_t>(count); ++i) {
      Subscription& s = subscriptions_.emplace_back();
      s.channel = open_channel(host, port, security);
      s.stub = pb::Bench::NewStub(s.channel);
      s.reader = std::make_unique<SubscriberReader>(*this, i);
    }
    for (Subscription& s : subscriptions_) {
      s.reader->start(*s.stub);
      ++started_;  // only this thread reads started_ (the destructor)
    }
  }

  // Cancels every stream and waits for its OnDone: returns even when the server is gone.
  ~GrpcSubscribers() override {
    for (Subscription& s : subscriptions_) s.reader->cancel();
    std::unique_lock lock(mutex_);
    changed_.wait(lock, [&] { return ended_ == started_; });
  }

  // Waits for the hello of every stream: the server has then registered all of them.
  void wait_established(std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    const bool established = changed_.wait_for(
        lock, timeout, [&] { return hellos_ == received_.size() || !error_.empty(); });
    if (!error_.empty()) throw std::runtime_error(error_);
    if (!established) {
      throw std::runtime_error(
          "grpc subscribe: " + std::to_string(hellos_) + " of " + std::to_string(received_.size()) +
          " subscriptions established after " + std::to_string(timeout.count()) + " ms");
    }
  }

  void publish_and_wait(int events, std::size_t payload,
                        std::chrono::milliseconds timeout) override {
    if (events < 0) throw std::invalid_argument("grpc publish: negative event count");
    const auto deadline = Clock::now() + timeout;
    {
      const std::lock_guard lock(mutex_);
      if (!error_.empty()) throw std::runtime_error(error_);
      target_ += events;
      reached_ = static_cast<std::size_t>(std::count_if(
          received_.begin(), received_.end(), [&](std::int64_t n) { return n >= target_; }));
    }
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + timeout);
    pb::PublishRequest request;
    request.set_count(events);
    request.set_payload_size(payload);
    pb::Empty response;
    check("Publish", publisher_->Publish(&context, request, &response));

    std::unique_lock lock(mutex_);
    const bool all = changed_.wait_until(
        lock, deadline, [&] { return reached_ == received_.size() || !error_.empty(); });
    if (!error_.empty()) throw std::runtime_error(error_);
    if (!all) {
      throw std::runtime_error(
          "grpc publish: " + std::to_string(reached_) + " of " + std::to_string(received_.size()) +
          " subscribers had all events after " + std::to_string(timeout.count()) + " ms");
    }
  }

  void on_hello() {
    const std::lock_guard lock(mutex_);
    if (++hellos_ == received_.size()) changed_.notify_all();
  }

  void on_event(std::size_t index) {
    const std::lock_guard lock(mutex_);
    if (++received_[index] == target_ && ++reached_ == received_.size()) changed_.notify_all();
  }

  void on_done(const grpc::Status& status) {
    const std::lock_guard lock(mutex_);
    ++ended_;
    if (error_.empty()) {
      error_ = "grpc Subscribe stream ended: " + describe(status);
    }
    changed_.notify_all();
  }

 private:
  struct Subscription {
    std::shared_ptr<grpc::Channel> channel;  // its own connection
    std::unique_ptr<pb::Bench::Stub> stub;
    std::unique_ptr<SubscriberReader> reader;
  };

  std::shared_ptr<grpc::Channel> publisher_channel_;
  std::unique_ptr<pb::Bench::Stub> publisher_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::vector<std::int64_t> received_;  // events (not hellos) per subscriber
  std::int64_t target_ = 0;             // events every subscriber must have received
  std::size_t reached_ = 0;             // subscribers that have target_ events
  std::size_t hellos_ = 0;
  std::size_t ended_ = 0;  // streams whose OnDone ran
  std::size_t started_ = 0;
  std::string error_;  // the first stream that ended
  std::vector<Subscription> subscriptions_;
};

void SubscriberReader::OnReadDone(bool ok) {
  if (!ok) return;
  if (event_.seq() == 0) {
    owner_.on_hello();
  } else {
    owner_.on_event(index_);
  }
  StartRead(&event_);
}

void SubscriberReader::OnDone(const grpc::Status& status) { owner_.on_done(status); }

// ---------------------------------------------------------------------------------------------

class GrpcSystem final : public System {
 public:
  explicit GrpcSystem(std::optional<TlsFiles> tls) : tls_(std::move(tls)) {}

  std::string name() const override { return tls_ ? "grpc-tls" : "grpc"; }

  void serve(std::uint16_t port, const std::function<void()>& ready) override {
    BenchService service;
    grpc::ServerBuilder builder;
    int bound_port = 0;
    builder.AddListeningPort(address("127.0.0.1", port), server_credentials(tls_), &bound_port);
    builder.RegisterService(&service);
    builder.SetMaxReceiveMessageSize(kNoMessageSizeLimit);
    builder.SetMaxSendMessageSize(kNoMessageSizeLimit);
    // gRPC sets SO_REUSEPORT by default, so a second server on a busy port would start and
    // share it silently; fail instead.
    builder.AddChannelArgument(GRPC_ARG_ALLOW_REUSEPORT, 0);
    const std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
    if (!server || bound_port == 0) {
      throw std::runtime_error("grpc: cannot listen on " + address("127.0.0.1", port) +
                               " (port in use?)");
    }
    ready();
    server->Wait();
    throw std::runtime_error("grpc server stopped");
  }

  std::unique_ptr<Client> connect(const std::string& host, std::uint16_t port) override {
    return std::make_unique<GrpcClient>(client_security(), host, port);
  }

  std::unique_ptr<Subscribers> subscribe(const std::string& host, std::uint16_t port,
                                         int count) override {
    if (count < 0) throw std::invalid_argument("grpc subscribe: negative subscriber count");
    auto subscribers = std::make_unique<GrpcSubscribers>(client_security(), host, port, count);
    subscribers->wait_established(std::chrono::seconds(30));
    return subscribers;
  }

 private:
  // Made at the first connection: a server process reads no CA.
  const ChannelSecurity& client_security() {
    std::call_once(security_made_, [this] { security_ = ChannelSecurity::of(tls_); });
    return security_;
  }

  std::optional<TlsFiles> tls_;
  std::once_flag security_made_;
  ChannelSecurity security_;
};

}  // namespace

std::unique_ptr<System> make_grpc(std::optional<TlsFiles> tls) {
  return std::make_unique<GrpcSystem>(std::move(tls));
}

}  // namespace icars::bench
