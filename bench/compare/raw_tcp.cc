// Raw TCP: the floor every middleware is measured against. Blocking POSIX sockets with
// TCP_NODELAY, one server thread per connection, and the least protocol that can carry the
// workloads: a request is `op u8 | length u64 | payload`, a reply or event `length u64 | payload`.
// It has no multiplexing (one request at a time per connection, so the head-of-line workload has
// no small calls for it), no reconnection beyond "connect again", no heartbeats, no types.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <condition_variable>
#include <cstring>
#include <memory>
#include <mutex>
#include <span>
#include <stdexcept>
#include <system_error>
#include <thread>

#include "../bench_util.h"
#include "system.h"

namespace icars::bench {
namespace {

enum class Op : std::uint8_t { echo_int = 1, size_of = 2, echo = 3, subscribe = 4, publish = 5 };

void set_nodelay(int fd) {
  const int one = 1;
  ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
}

bool write_request(int fd, Op op, const void* payload, std::size_t n) {
  std::byte head[9];
  head[0] = static_cast<std::byte>(op);
  const std::uint64_t length = n;
  std::memcpy(head + 1, &length, sizeof length);
  return write_all(fd, head, sizeof head) && (n == 0 || write_all(fd, payload, n));
}

bool write_reply(int fd, const void* payload, std::size_t n) {
  const std::uint64_t length = n;
  return write_all(fd, &length, sizeof length) && (n == 0 || write_all(fd, payload, n));
}

bool read_reply(int fd, Bytes& out) {
  std::uint64_t length = 0;
  if (!read_exact(fd, &length, sizeof length)) return false;
  out.resize(length);
  return length == 0 || read_exact(fd, out.data(), length);
}

int connect_to(const std::string& host, std::uint16_t port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) throw_errno("socket");
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(port);
  if (::inet_pton(AF_INET, host.c_str(), &addr.sin_addr) != 1) {
    ::close(fd);
    throw std::invalid_argument("raw-tcp: not an IPv4 address: " + host);
  }
  if (::connect(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    const int saved = errno;
    ::close(fd);
    errno = saved;
    return -1;
  }
  set_nodelay(fd);
  return fd;
}

// --- Server ----------------------------------------------------------------------------------

// Reads requests into a buffer and answers every complete request of one read with one write,
// as a tuned server would; a request too large for the buffer is read straight into its own.
// The buffer is allocated untouched (as PLANET's read buffer is), so an idle connection costs
// the pages it has used, not 256 KiB.
class Server {
 public:
  void serve_connection(int fd) {
    const auto in = std::make_unique_for_overwrite<std::byte[]>(kBuffer);
    std::size_t have = 0;
    std::vector<std::byte> out;
    Bytes large;
    for (;;) {
      std::size_t at = 0;
      bool ok = true;
      while (ok && have - at >= kHeader) {
        const auto op = static_cast<Op>(in[at]);
        std::uint64_t length = 0;
        std::memcpy(&length, in.get() + at + 1, sizeof length);
        if (length <= kBuffer - kHeader) {
          if (have - at - kHeader < length) break;  // the rest of it is still to come
          ok = handle(fd, op, std::span(in.get() + at + kHeader, length), out);
          at += kHeader + length;
          if (op == Op::subscribe) return;  // the socket now belongs to the publisher
          continue;
        }
        large.assign(in.get() + at + kHeader, in.get() + have);
        const std::size_t got = large.size();
        large.resize(length);
        ok = read_exact(fd, large.data() + got, length - got) &&
             (out.empty() || write_all(fd, out.data(), out.size()));
        out.clear();
        at = have;
        ok = ok && handle(fd, op, large, out);
      }
      if (!ok || (!out.empty() && !write_all(fd, out.data(), out.size()))) break;
      out.clear();
      std::memmove(in.get(), in.get() + at, have - at);
      have -= at;
      const ssize_t got = ::recv(fd, in.get() + have, kBuffer - have, 0);
      if (got <= 0) {
        if (got < 0 && errno == EINTR) continue;
        break;
      }
      have += static_cast<std::size_t>(got);
    }
    ::close(fd);
  }

 private:
  static constexpr std::size_t kHeader = 9;
  static constexpr std::size_t kBuffer = 256 * 1024;

  static void append_reply(std::vector<std::byte>& out, std::span<const std::byte> payload) {
    const std::uint64_t length = payload.size();
    const auto* head = reinterpret_cast<const std::byte*>(&length);
    out.insert(out.end(), head, head + sizeof length);
    out.insert(out.end(), payload.begin(), payload.end());
  }

  // Small replies are appended to `out`; a large one is written at once.
  bool handle(int fd, Op op, std::span<const std::byte> payload, std::vector<std::byte>& out) {
    switch (op) {
      case Op::echo_int:
        append_reply(out, payload);
        return true;
      case Op::echo:
        if (payload.size() > kBuffer) {
          return (out.empty() || write_all(fd, out.data(), out.size())) &&
                 (out.clear(), write_reply(fd, payload.data(), payload.size()));
        }
        append_reply(out, payload);
        return true;
      case Op::size_of: {
        const std::uint64_t size = payload.size();
        append_reply(out, std::as_bytes(std::span(&size, 1)));
        return true;
      }
      case Op::subscribe: {
        std::lock_guard lock(mutex_);
        subscribers_.push_back(fd);
        return write_reply(fd, nullptr, 0);
      }
      case Op::publish: {
        std::uint32_t spec[2] = {0, 0};  // count, payload size
        if (payload.size() != sizeof spec) return false;
        std::memcpy(spec, payload.data(), sizeof spec);
        // Every subscriber's events leave in one write per subscriber.
        std::vector<std::byte> events;
        const Bytes event(spec[1], std::byte{0x5A});
        for (std::uint32_t i = 0; i < spec[0]; ++i) append_reply(events, event);
        {
          std::lock_guard lock(mutex_);
          for (const int s : subscribers_) write_all(s, events.data(), events.size());
        }
        append_reply(out, {});
        return true;
      }
    }
    return false;
  }

  std::mutex mutex_;
  std::vector<int> subscribers_;
};

// --- Client ----------------------------------------------------------------------------------

class RawClient final : public Client {
 public:
  RawClient(std::string host, std::uint16_t port) : host_(std::move(host)), port_(port) {
    fd_ = connect_to(host_, port_);
    if (fd_ < 0) throw_errno("raw-tcp connect");
  }
  ~RawClient() override {
    if (fd_ >= 0) ::close(fd_);
  }

  std::int32_t call(std::int32_t x) override {
    std::lock_guard lock(mutex_);
    std::int32_t y = 0;
    if (!write_request(fd_, Op::echo_int, &x, sizeof x) || !read_reply(fd_, reply_) ||
        reply_.size() != sizeof y) {
      throw std::runtime_error("raw-tcp: echo_int failed");
    }
    std::memcpy(&y, reply_.data(), sizeof y);
    return y;
  }

  std::uint64_t upload(const Bytes& data) override {
    std::lock_guard lock(mutex_);
    std::uint64_t size = 0;
    if (!write_request(fd_, Op::size_of, data.data(), data.size()) || !read_reply(fd_, reply_) ||
        reply_.size() != sizeof size) {
      throw std::runtime_error("raw-tcp: size_of failed");
    }
    std::memcpy(&size, reply_.data(), sizeof size);
    return size;
  }

  Bytes echo(const Bytes& data) override {
    std::lock_guard lock(mutex_);
    Bytes out;
    if (!write_request(fd_, Op::echo, data.data(), data.size()) || !read_reply(fd_, out)) {
      throw std::runtime_error("raw-tcp: echo failed");
    }
    return out;
  }

  // Keeps up to `window` requests on the wire: every send carries all the requests the window
  // allows at that moment, every receive takes all the replies the kernel has.
  void pipeline(std::int64_t count, int window) override {
    std::lock_guard lock(mutex_);
    constexpr std::size_t kRequest = 9 + sizeof(std::int32_t);
    constexpr std::size_t kReply = 8 + sizeof(std::int32_t);
    std::vector<std::byte> out;
    std::vector<std::byte> in(64 * 1024);
    std::size_t buffered = 0;
    std::int64_t sent = 0;
    std::int64_t answered = 0;
    while (answered < count) {
      out.clear();
      while (sent < count && sent - answered < window) {
        std::byte request[kRequest];
        request[0] = static_cast<std::byte>(Op::echo_int);
        const std::uint64_t length = sizeof(std::int32_t);
        const auto value = static_cast<std::int32_t>(sent);
        std::memcpy(request + 1, &length, sizeof length);
        std::memcpy(request + 9, &value, sizeof value);
        out.insert(out.end(), request, request + kRequest);
        ++sent;
      }
      if (!out.empty() && !write_all(fd_, out.data(), out.size())) {
        throw std::runtime_error("raw-tcp: pipeline send failed");
      }
      const ssize_t got = ::recv(fd_, in.data() + buffered, in.size() - buffered, 0);
      if (got <= 0) {
        if (got < 0 && errno == EINTR) continue;
        throw std::runtime_error("raw-tcp: pipeline receive failed");
      }
      buffered += static_cast<std::size_t>(got);
      std::size_t at = 0;
      for (; buffered - at >= kReply; at += kReply) {
        std::int32_t value = 0;
        std::memcpy(&value, in.data() + at + 8, sizeof value);
        if (value != static_cast<std::int32_t>(answered)) {
          throw std::runtime_error("raw-tcp: pipeline answer out of order");
        }
        ++answered;
      }
      std::memmove(in.data(), in.data() + at, buffered - at);
      buffered -= at;
    }
  }

  bool try_call() noexcept override {
    std::lock_guard lock(mutex_);
    if (fd_ < 0) {
      fd_ = connect_to(host_, port_);
      if (fd_ < 0) return false;
      timeval tv{1, 0};
      ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    }
    const std::int32_t x = 7;
    if (write_request(fd_, Op::echo_int, &x, sizeof x) && read_reply(fd_, reply_) &&
        reply_.size() == sizeof x) {
      return true;
    }
    ::close(fd_);
    fd_ = -1;
    return false;
  }

 private:
  std::mutex mutex_;
  std::string host_;
  std::uint16_t port_;
  int fd_ = -1;
  Bytes reply_;
};

// `count` subscriber sockets read by one thread with poll().
class RawSubscribers final : public Subscribers {
 public:
  RawSubscribers(const std::string& host, std::uint16_t port, int count)
      : publisher_(host, port), buffers_(static_cast<std::size_t>(count)) {
    for (int i = 0; i < count; ++i) {
      const int fd = connect_to(host, port);
      if (fd < 0) throw_errno("raw-tcp subscriber connect");
      fds_.push_back(fd);
      Bytes ack;
      if (!write_request(fd, Op::subscribe, nullptr, 0) || !read_reply(fd, ack)) {
        throw std::runtime_error("raw-tcp: subscribe failed");
      }
    }
    counts_.assign(fds_.size(), 0);
    reader_ = std::thread([this] { read_loop(); });
  }
  ~RawSubscribers() override {
    stop_ = true;
    reader_.join();
    for (const int fd : fds_) ::close(fd);
  }

  void publish_and_wait(int events, std::size_t payload,
                        std::chrono::milliseconds timeout) override {
    std::unique_lock lock(mutex_);
    target_ = events;
    std::fill(counts_.begin(), counts_.end(), 0);
    complete_ = 0;
    lock.unlock();
    const std::uint32_t spec[2] = {static_cast<std::uint32_t>(events),
                                   static_cast<std::uint32_t>(payload)};
    Bytes spec_bytes(sizeof spec);
    std::memcpy(spec_bytes.data(), spec, sizeof spec);
    publisher_.publish(spec_bytes);
    lock.lock();
    if (!done_.wait_for(lock, timeout, [this] { return complete_ == fds_.size(); })) {
      throw std::runtime_error("raw-tcp: not every subscriber received every event");
    }
  }

 private:
  // A client whose only use is the publish request.
  class Publisher {
   public:
    Publisher(const std::string& host, std::uint16_t port) : fd_(connect_to(host, port)) {
      if (fd_ < 0) throw_errno("raw-tcp publisher connect");
    }
    ~Publisher() { ::close(fd_); }
    void publish(const Bytes& spec) {
      Bytes ack;
      if (!write_request(fd_, Op::publish, spec.data(), spec.size()) || !read_reply(fd_, ack)) {
        throw std::runtime_error("raw-tcp: publish failed");
      }
    }

   private:
    int fd_;
  };

  void read_loop() {
    std::vector<pollfd> polls;
    for (const int fd : fds_) polls.push_back({fd, POLLIN, 0});
    std::vector<std::byte> chunk(256 * 1024);
    while (!stop_) {
      if (::poll(polls.data(), polls.size(), 50) <= 0) continue;
      for (std::size_t i = 0; i < polls.size(); ++i) {
        if ((polls[i].revents & (POLLIN | POLLHUP | POLLERR)) == 0) continue;
        const ssize_t got = ::recv(polls[i].fd, chunk.data(), chunk.size(), MSG_DONTWAIT);
        if (got <= 0) {
          if (got == 0) polls[i].fd = -1;  // closed: stop polling it
          continue;
        }
        Bytes& buffer = buffers_[i];
        buffer.insert(buffer.end(), chunk.begin(), chunk.begin() + got);
        std::size_t at = 0;
        int events = 0;
        while (buffer.size() - at >= 8) {
          std::uint64_t length = 0;
          std::memcpy(&length, buffer.data() + at, sizeof length);
          if (buffer.size() - at - 8 < length) break;
          at += 8 + length;
          ++events;
        }
        buffer.erase(buffer.begin(), buffer.begin() + static_cast<std::ptrdiff_t>(at));
        if (events > 0) {
          std::lock_guard lock(mutex_);
          counts_[i] += events;
          if (counts_[i] == target_ && counts_[i] - events < target_) ++complete_;
          if (complete_ == fds_.size()) done_.notify_all();
        }
      }
    }
  }

  Publisher publisher_;
  std::vector<int> fds_;
  std::vector<Bytes> buffers_;
  std::thread reader_;
  std::atomic<bool> stop_{false};
  std::mutex mutex_;
  std::condition_variable done_;
  std::vector<int> counts_;
  int target_ = 0;
  std::size_t complete_ = 0;
};

class RawTcp final : public System {
 public:
  std::string name() const override { return "raw-tcp"; }

  void serve(std::uint16_t port, const std::function<void()>& ready) override {
    const int listener = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (listener < 0) throw_errno("socket");
    const int one = 1;
    ::setsockopt(listener, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(port);
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::bind(listener, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
      throw_errno("bind");
    }
    if (::listen(listener, 256) != 0) throw_errno("listen");
    ready();
    Server server;
    for (;;) {
      const int fd = ::accept4(listener, nullptr, nullptr, SOCK_CLOEXEC);
      if (fd < 0) {
        if (errno == EINTR || errno == ECONNABORTED) continue;
        throw_errno("accept");
      }
      set_nodelay(fd);
      std::thread([&server, fd] { server.serve_connection(fd); }).detach();
    }
  }

  std::unique_ptr<Client> connect(const std::string& host, std::uint16_t port) override {
    return std::make_unique<RawClient>(host, port);
  }

  std::unique_ptr<Subscribers> subscribe(const std::string& host, std::uint16_t port,
                                         int count) override {
    return std::make_unique<RawSubscribers>(host, port, count);
  }
};

}  // namespace

std::unique_ptr<System> make_raw_tcp() { return std::make_unique<RawTcp>(); }

}  // namespace icars::bench
