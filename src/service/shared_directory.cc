#include "icars/service/shared_directory.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <asio/co_spawn.hpp>
#include <asio/detached.hpp>
#include <asio/use_awaitable.hpp>
#include <algorithm>

#include "icars/planet/proxy.h"
#include "icars/planet/remote.h"
#include "icars/planet/stream.h"

namespace icars::service {

namespace p = icars::planet;

namespace {

// Deadline of a relayed call: the caller keeps its own, shorter one; this only bounds what the
// relay waits for when the caller gave up.
constexpr auto kRelayTimeout = std::chrono::minutes(2);

std::string relay_path(const std::string& service_id) { return std::string(kRelayPrefix) + service_id; }

// The arguments of a forwarded call with every remote reference among its top-level arguments
// replaced by `replace(ref)`. A reference after a `valued` argument is left as it is: a struct
// cannot be stepped over without its definition (listeners are passed alone: subscribe(listener)).
template <class F>
std::vector<std::byte> rewrite_references(std::span<const std::byte> args, F replace) {
  p::Reader r(args);
  std::vector<std::byte> out;
  out.reserve(args.size() + 64);
  p::Writer w(out);
  const std::uint8_t argc = r.u8();
  w.u8(argc);
  for (std::uint8_t i = 0; i < argc; ++i) {
    const auto descriptor = p::read_descriptor(r);
    w.raw(descriptor);
    const auto code = static_cast<p::TypeCode>(std::to_integer<std::uint8_t>(descriptor.front()));
    if (code == p::TypeCode::remote) {
      p::Codec<p::ObjectRef>::encode(w, replace(p::Codec<p::ObjectRef>::decode(r)));
      continue;
    }
    if (code == p::TypeCode::valued) break;
    if (code == p::TypeCode::stream) {
      throw p::Error(p::ErrorKind::unimplemented,
                     "a stream argument cannot be passed through another server (a stream result can)");
    }
    const auto before = r.rest();
    p::skip_value(r, descriptor);
    w.raw(before.first(before.size() - r.rest().size()));
  }
  w.raw(r.rest());
  return out;
}

// Copies what the device's stream carries to a stream of this server, as fast as the caller
// reads (each side's window bounds what waits here); the end, the device's abort and the
// caller's cancel each end the other side too.
asio::awaitable<void> pump(std::shared_ptr<p::InputStream> from, std::shared_ptr<p::OutputStream> to) {
  for (;;) {
    std::vector<std::byte> chunk;
    try {
      chunk = co_await from->async_read(asio::use_awaitable);
    } catch (const std::exception& e) {
      to->abort(fmt::format("the device's stream broke: {}", e.what()));
      co_return;
    }
    if (chunk.empty()) {
      to->close();
      co_return;
    }
    try {
      co_await to->async_write(std::move(chunk), asio::use_awaitable);
    } catch (const std::exception& e) {
      from->cancel(fmt::format("the reader on the other server stopped: {}", e.what()));
      co_return;
    }
  }
}

// The tagged result naming a stream of this server that relays `from_device` (opened over `link`).
std::vector<std::byte> relay_stream(p::Communicator& communicator, const std::shared_ptr<p::Link>& link,
                                    p::StreamRef from_device) {
  auto in = p::InputStream::open(communicator, link, from_device);
  auto out = p::OutputStream::create(communicator);
  std::vector<std::byte> tagged;
  p::Writer w(tagged);
  p::encode_tagged(w, out->ref());
  asio::co_spawn(communicator.executor(), pump(std::move(in), std::move(out)), asio::detached);
  return tagged;
}

df::SharedDevice shared(const DeviceRegistry::DeviceView& view) {
  df::SharedDevice s;
  s.device = view.info;
  for (auto& c : s.device.capabilities) c.path = relay_path(view.info.id + "." + c.name);
  s.link = static_cast<std::int64_t>(view.connection_id);
  return s;
}

}  // namespace

// --- The sharing side ------------------------------------------------------------------------

struct SharedDirectory::State : std::enable_shared_from_this<State> {
  State(p::Communicator& c, DeviceRegistry& r) : communicator(c), registry(r) {}

  struct Watcher {
    std::uint64_t connection;
    df::DirectoryWatcherPrx proxy;
  };
  // A listener of a caller, subscribed to a device through a relay.
  struct Listener {
    std::string path;                       // the relay listener's, on this server
    std::weak_ptr<p::Connection> caller;    // where its events go
    std::string caller_path;                // the caller's listener
    std::string service;                    // the service it was subscribed to
    std::weak_ptr<Adaptor> target;          // that service's adaptor here
    std::vector<std::byte> subscription;    // the rewritten arguments (for unsubscribe)
    const p::Servant* servant = nullptr;
  };

  p::Communicator& communicator;
  DeviceRegistry& registry;
  mutable std::mutex mutex;
  std::vector<Watcher> watchers;
  std::map<std::string, const p::Servant*> relays;  // service id -> its relay
  // (caller connection, caller's path, service id) -> relay listener
  std::map<std::tuple<std::uint64_t, std::string, std::string>, Listener> listeners;
  std::uint64_t next_listener = 1;
  std::uint64_t registry_watch = 0;
  std::uint64_t connection_listener = 0;

  // Relays for the device's services while it is registered; none after.
  void update_relays(const std::string& device_id);
  void device_changed(const std::string& device_id);
  void connection_closed(std::uint64_t connection);
  p::ObjectRef relay_listener(const p::ForwardedCall& call, const p::ObjectRef& ref,
                              const std::shared_ptr<Adaptor>& target, std::vector<std::string>& used);
  void keep_subscription(const std::vector<std::string>& used, const std::vector<std::byte>& args);
  void drop_listeners(const std::vector<std::string>& used);

  // The relay's and a relay listener's work. Each servant holds what it forwards to, so a call or
  // an event finds its adaptor and its caller without a lookup.
  static p::Servant::AsyncResult relay(std::weak_ptr<State> weak, std::weak_ptr<Adaptor> service,
                                       p::ForwardedCall call);
  struct Caller {
    std::weak_ptr<p::Connection> connection;
    std::string path;
    std::weak_ptr<Adaptor> target;  // the device whose events it takes
    std::string service;
  };
  static p::Servant::AsyncResult to_caller(Caller caller, p::ForwardedCall call);
};

class SharedDirectory::Directory final : public df::ServiceDirectoryServant {
 public:
  explicit Directory(std::weak_ptr<State> state) : state_(std::move(state)) {}

  std::vector<df::SharedDevice> watch(df::DirectoryWatcherPrx watcher, const p::Current& current) override {
    auto state = state_.lock();
    if (!state) throw p::Error(p::ErrorKind::disconnected, "the directory is closing");
    // The watcher is the caller's object: called back over the link this call came on.
    df::DirectoryWatcherPrx proxy(*current.communicator, current.connection, watcher.path());
    std::vector<df::SharedDevice> out;
    std::lock_guard lock(state->mutex);
    std::erase_if(state->watchers, [&](const State::Watcher& w) {
      return w.connection == current.connection->id() && w.proxy.path() == proxy.path();
    });
    state->watchers.push_back({current.connection->id(), std::move(proxy)});
    for (const auto& view : state->registry.views()) out.push_back(shared(view));
    return out;
  }

  void unwatch(df::DirectoryWatcherPrx watcher, const p::Current& current) override {
    auto state = state_.lock();
    if (!state) return;
    std::lock_guard lock(state->mutex);
    std::erase_if(state->watchers, [&](const State::Watcher& w) {
      return w.connection == current.connection->id() && w.proxy.path() == watcher.path();
    });
  }

 private:
  std::weak_ptr<State> state_;
};

void SharedDirectory::State::update_relays(const std::string& device_id) {
  const auto view = registry.view(device_id);
  std::vector<std::pair<std::string, const p::Servant*>> gone;
  {
    std::lock_guard lock(mutex);
    // Relays of services the device no longer has (it was removed), and their listeners.
    const std::string prefix = device_id + ".";
    for (auto it = relays.lower_bound(prefix); it != relays.end() && it->first.starts_with(prefix);) {
      const bool kept = view && std::any_of(view->services.begin(), view->services.end(),
                                            [&](const auto& s) { return s->id() == it->first; });
      if (kept) {
        ++it;
        continue;
      }
      gone.emplace_back(relay_path(it->first), it->second);
      for (auto l = listeners.begin(); l != listeners.end();) {
        if (l->second.service != it->first) {
          ++l;
          continue;
        }
        gone.emplace_back(l->second.path, l->second.servant);
        l = listeners.erase(l);
      }
      it = relays.erase(it);
    }
    for (const auto& s : view ? view->services : std::vector<std::shared_ptr<Adaptor>>{}) {
      if (relays.contains(s->id())) continue;
      auto servant = std::make_shared<p::Servant>(s->interface_id());
      servant->forward_others([weak = weak_from_this(), target = std::weak_ptr<Adaptor>(s)](p::ForwardedCall call) {
        return relay(weak, target, std::move(call));
      });
      try {
        communicator.adapter().add(relay_path(s->id()), servant);
        relays.emplace(s->id(), servant.get());
      } catch (const std::invalid_argument& e) {  // a device id no path can hold
        communicator.log().warn("device {} is not shared: {}", device_id, e.what());
      }
    }
  }
  for (const auto& [path, servant] : gone) communicator.adapter().remove(path, servant);
}

void SharedDirectory::State::device_changed(const std::string& device_id) {
  update_relays(device_id);
  const auto view = registry.view(device_id);
  std::vector<Watcher> to;
  {
    std::lock_guard lock(mutex);
    to = watchers;
  }
  for (const auto& w : to) {
    try {
      if (view) {
        w.proxy.notify(df::DirectoryWatcher::changed, shared(*view));
      } else {
        w.proxy.notify(df::DirectoryWatcher::removed, device_id);
      }
    } catch (const p::Error& e) {
      // A watcher whose link is down is dropped with it (connection_closed); one overloaded
      // reads the whole directory again when its link is back.
      communicator.log().warn("directory change of {} not sent to {}: {}", device_id, w.proxy.path(), e.what());
    }
  }
}

void SharedDirectory::State::connection_closed(std::uint64_t connection) {
  std::vector<Listener> gone;
  {
    std::lock_guard lock(mutex);
    std::erase_if(watchers, [&](const Watcher& w) { return w.connection == connection; });
    for (auto it = listeners.begin(); it != listeners.end();) {
      if (std::get<0>(it->first) != connection) {
        ++it;
        continue;
      }
      gone.push_back(std::move(it->second));
      it = listeners.erase(it);
    }
  }
  for (auto& l : gone) {
    communicator.adapter().remove(l.path, l.servant);
    // The device forgets the subscription too (subscribe's counterpart takes the same arguments).
    auto target = l.target.lock();
    const auto link = target ? target->bound_link() : nullptr;
    if (!link || l.subscription.empty()) continue;
    p::Proxy proxy(communicator, link, target->path());
    proxy.async_call_raw("unsubscribe", std::move(l.subscription), p::CallMode::idempotent,
                         [](std::exception_ptr, std::vector<std::byte>) {});
  }
}

p::ObjectRef SharedDirectory::State::relay_listener(const p::ForwardedCall& call, const p::ObjectRef& ref,
                                                    const std::shared_ptr<Adaptor>& target,
                                                    std::vector<std::string>& used) {
  std::lock_guard lock(mutex);
  const auto key = std::make_tuple(call.connection->id(), ref.path, target->id());
  auto it = listeners.find(key);
  if (it == listeners.end()) {
    Listener l;
    l.path = fmt::format("{}{}/{}", kRelayListenerPrefix, call.connection->id(), next_listener++);
    l.caller = call.connection;
    l.caller_path = ref.path;
    l.service = target->id();
    l.target = target;
    auto servant = std::make_shared<p::Servant>(ref.type_id);
    servant->forward_others([caller = Caller{call.connection, ref.path, target, target->id()}](p::ForwardedCall c) {
      return to_caller(caller, std::move(c));
    });
    communicator.adapter().add(l.path, servant);
    l.servant = servant.get();
    it = listeners.emplace(key, std::move(l)).first;
  }
  used.push_back(it->second.path);
  return p::ObjectRef{"", it->second.path, ref.type_id};
}

void SharedDirectory::State::keep_subscription(const std::vector<std::string>& used,
                                               const std::vector<std::byte>& args) {
  std::lock_guard lock(mutex);
  for (auto& [key, l] : listeners) {
    if (std::find(used.begin(), used.end(), l.path) != used.end()) l.subscription = args;
  }
}

void SharedDirectory::State::drop_listeners(const std::vector<std::string>& used) {
  std::vector<std::pair<std::string, const p::Servant*>> gone;
  {
    std::lock_guard lock(mutex);
    for (auto it = listeners.begin(); it != listeners.end();) {
      if (std::find(used.begin(), used.end(), it->second.path) == used.end()) {
        ++it;
        continue;
      }
      gone.emplace_back(it->second.path, it->second.servant);
      it = listeners.erase(it);
    }
  }
  for (const auto& [path, servant] : gone) communicator.adapter().remove(path, servant);
}

// A call of another server to a shared capability: forwarded to the device over its own link.
p::Servant::AsyncResult SharedDirectory::State::relay(std::weak_ptr<State> weak, std::weak_ptr<Adaptor> service,
                                                      p::ForwardedCall call) {
  auto state = weak.lock();
  if (!state) throw p::Error(p::ErrorKind::disconnected, "the directory is closing");
  auto target = service.lock();
  if (!target) throw p::Error(p::ErrorKind::unimplemented, fmt::format("the service at {} is gone", call.path));
  auto link = target->bound_link();
  if (!link) {
    throw p::Error(p::ErrorKind::disconnected,
                   fmt::format("device {} is not connected to this server", target->device_id()));
  }
  // References among the arguments name the caller's objects (a listener): the device gets a
  // relay listener here instead, which forwards to the caller.
  std::vector<std::string> used;
  auto args = rewrite_references(call.args, [&](const p::ObjectRef& ref) {
    return state->relay_listener(call, ref, target, used);
  });
  p::Proxy proxy(*call.communicator, link, target->path());
  proxy.set_timeout(kRelayTimeout);
  proxy.set_observer(target->call_observer());  // a command sent from elsewhere is acknowledged here too
  if (call.oneway) {
    proxy.notify_raw(call.method, args);
    co_return std::vector<std::byte>{};
  }
  const bool unsubscribing = call.method == "unsubscribe";
  if (!used.empty() && !unsubscribing) state->keep_subscription(used, args);
  state.reset();  // not held across the call
  auto result = co_await proxy.async_call_raw(call.method, std::move(args), p::CallMode::at_most_once,
                                              asio::use_awaitable);
  if (unsubscribing && !used.empty()) {
    if (auto again = weak.lock()) again->drop_listeners(used);
  }
  // A stream the device opened runs over this server's link: the caller gets a stream of this
  // server, fed from the device's (a microphone's capture).
  if (!result.empty() && std::to_integer<std::uint8_t>(result.front()) == static_cast<std::uint8_t>(p::TypeCode::stream)) {
    p::Reader r(result);
    co_return relay_stream(*call.communicator, link, p::decode_tagged<p::StreamRef>(r, "result"));
  }
  co_return result;
}

// An event (or any call) of a device to a relay listener: forwarded to the caller's listener.
p::Servant::AsyncResult SharedDirectory::State::to_caller(Caller caller, p::ForwardedCall call) {
  auto target = caller.target.lock();
  // Only the device's own manager speaks for it, as to the adaptor's own listener.
  if (!target || target->bound_connection() == 0 || !call.connection ||
      call.connection->id() != target->bound_connection()) {
    throw p::Error(p::ErrorKind::denied,
                   fmt::format("only the device behind {} may deliver its events", caller.service));
  }
  auto connection = caller.connection.lock();
  if (!connection || !connection->is_open()) throw p::Error(p::ErrorKind::disconnected, "the subscriber's link is down");
  p::Proxy proxy(*call.communicator, connection, caller.path);
  if (call.oneway) {
    proxy.notify_raw(call.method, call.args);
    co_return std::vector<std::byte>{};
  }
  co_return co_await proxy.async_call_raw(call.method, std::move(call.args), p::CallMode::at_most_once,
                                          asio::use_awaitable);
}

SharedDirectory::SharedDirectory(p::Communicator& communicator, DeviceRegistry& registry)
    : state_(std::make_shared<State>(communicator, registry)) {
  std::weak_ptr<State> weak = state_;
  communicator.adapter().add(std::string(kDirectoryPath), std::make_shared<Directory>(weak));
  state_->registry_watch = registry.watch_devices([weak](const std::string& device) {
    if (auto state = weak.lock()) state->device_changed(device);
  });
  state_->connection_listener = communicator.connections().add_listener([weak](const p::ConnectionEvent& e) {
    if (e.kind != p::LinkEventKind::disconnected || !e.connection) return;
    if (auto state = weak.lock()) state->connection_closed(e.connection->id());
  });
  for (const auto& view : registry.views()) state_->update_relays(view.info.id);
}

SharedDirectory::~SharedDirectory() {
  state_->registry.remove_device_watcher(state_->registry_watch);
  state_->communicator.connections().remove_listener(state_->connection_listener);
  auto& adapter = state_->communicator.adapter();
  adapter.remove(kDirectoryPath);
  std::vector<std::pair<std::string, const p::Servant*>> servants;
  {
    std::lock_guard lock(state_->mutex);
    for (const auto& [id, servant] : state_->relays) servants.emplace_back(relay_path(id), servant);
    for (const auto& [key, l] : state_->listeners) servants.emplace_back(l.path, l.servant);
  }
  // Waits for relayed calls in progress: each ends with its reply, its link or its deadline.
  for (const auto& [path, servant] : servants) adapter.remove(path, servant);
}

std::size_t SharedDirectory::watchers() const {
  std::lock_guard lock(state_->mutex);
  return state_->watchers.size();
}

std::size_t SharedDirectory::relay_listeners() const {
  std::lock_guard lock(state_->mutex);
  return state_->listeners.size();
}

}  // namespace icars::service
