#include "icars/service/shared_directory.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <asio/use_awaitable.hpp>
#include <algorithm>
#include <atomic>
#include <variant>

#include "icars/planet/proxy.h"
#include "icars/planet/remote.h"

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
                     "a stream cannot be passed through another server: open it on the server the device registered on");
    }
    const auto before = r.rest();
    p::skip_value(r, descriptor);
    w.raw(before.first(before.size() - r.rest().size()));
  }
  w.raw(r.rest());
  return out;
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

  // The registry's adaptor of a service id ("<device>.<capability>"; a device id may hold dots).
  std::shared_ptr<Adaptor> adaptor(const std::string& service_id) const {
    for (auto cut = service_id.rfind('.'); cut != std::string::npos && cut > 0;
         cut = service_id.rfind('.', cut - 1)) {
      if (auto view = registry.view(service_id.substr(0, cut))) {
        for (const auto& s : view->services) {
          if (s->id() == service_id) return s;
        }
      }
    }
    return nullptr;
  }

  // Relays for the device's services while it is registered; none after.
  void update_relays(const std::string& device_id);
  void device_changed(const std::string& device_id);
  void connection_closed(std::uint64_t connection);
  p::ObjectRef relay_listener(const p::ForwardedCall& call, const p::ObjectRef& ref, const std::string& service,
                              std::vector<std::string>& used);
  void keep_subscription(const std::vector<std::string>& used, const std::vector<std::byte>& args);
  void drop_listeners(const std::vector<std::string>& used);

  static p::Servant::AsyncResult relay(std::weak_ptr<State> weak, std::string service, p::ForwardedCall call);
  static p::Servant::AsyncResult to_caller(std::weak_ptr<State> weak, std::string path, p::ForwardedCall call);
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
      servant->forward_others([weak = weak_from_this(), id = s->id()](p::ForwardedCall call) {
        return relay(weak, id, std::move(call));
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
    auto target = adaptor(l.service);
    const auto link = target ? target->bound_link() : nullptr;
    if (!link || l.subscription.empty()) continue;
    p::Proxy proxy(communicator, link, target->path());
    proxy.async_call_raw("unsubscribe", std::move(l.subscription), p::CallMode::idempotent,
                         [](std::exception_ptr, std::vector<std::byte>) {});
  }
}

p::ObjectRef SharedDirectory::State::relay_listener(const p::ForwardedCall& call, const p::ObjectRef& ref,
                                                    const std::string& service, std::vector<std::string>& used) {
  std::lock_guard lock(mutex);
  const auto key = std::make_tuple(call.connection->id(), ref.path, service);
  auto it = listeners.find(key);
  if (it == listeners.end()) {
    Listener l;
    l.path = fmt::format("{}{}/{}", kRelayListenerPrefix, call.connection->id(), next_listener++);
    l.caller = call.connection;
    l.caller_path = ref.path;
    l.service = service;
    auto servant = std::make_shared<p::Servant>(ref.type_id);
    servant->forward_others([weak = weak_from_this(), path = l.path](p::ForwardedCall c) {
      return to_caller(weak, path, std::move(c));
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
p::Servant::AsyncResult SharedDirectory::State::relay(std::weak_ptr<State> weak, std::string service,
                                                      p::ForwardedCall call) {
  auto state = weak.lock();
  if (!state) throw p::Error(p::ErrorKind::disconnected, "the directory is closing");
  auto target = state->adaptor(service);
  if (!target) throw p::Error(p::ErrorKind::unimplemented, fmt::format("service {} is gone", service));
  auto link = target->bound_link();
  if (!link) {
    throw p::Error(p::ErrorKind::disconnected,
                   fmt::format("device {} is not connected to this server", target->device_id()));
  }
  // References among the arguments name the caller's objects (a listener): the device gets a
  // relay listener here instead, which forwards to the caller.
  std::vector<std::string> used;
  auto args = rewrite_references(call.args, [&](const p::ObjectRef& ref) {
    return state->relay_listener(call, ref, service, used);
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
  const std::string method = call.method;
  auto result = co_await proxy.async_call_raw(call.method, std::move(args), p::CallMode::at_most_once,
                                              asio::use_awaitable);
  // A stream the device opened belongs to this server's link, not to the caller's.
  if (!result.empty() && std::to_integer<std::uint8_t>(result.front()) == static_cast<std::uint8_t>(p::TypeCode::stream)) {
    throw p::Error(p::ErrorKind::unimplemented,
                   fmt::format("{} returns a stream, which cannot be passed through another server: use {} on "
                               "the server it registered on",
                               method, service));
  }
  if (unsubscribing && !used.empty()) {
    if (auto again = weak.lock()) again->drop_listeners(used);
  }
  co_return result;
}

// An event (or any call) of a device to a relay listener: forwarded to the caller's listener.
p::Servant::AsyncResult SharedDirectory::State::to_caller(std::weak_ptr<State> weak, std::string path,
                                                          p::ForwardedCall call) {
  auto state = weak.lock();
  if (!state) throw p::Error(p::ErrorKind::disconnected, "the directory is closing");
  std::shared_ptr<p::Connection> caller;
  std::string caller_path;
  std::string service;
  {
    std::lock_guard lock(state->mutex);
    for (const auto& [key, l] : state->listeners) {
      if (l.path != path) continue;
      caller = l.caller.lock();
      caller_path = l.caller_path;
      service = l.service;
    }
  }
  auto target = state->adaptor(service);
  // Only the device's own manager speaks for it, as to the adaptor's own listener.
  if (!target || target->bound_connection() == 0 || !call.connection ||
      call.connection->id() != target->bound_connection()) {
    throw p::Error(p::ErrorKind::denied,
                   fmt::format("only the device behind {} may deliver its events", service));
  }
  if (!caller || !caller->is_open()) throw p::Error(p::ErrorKind::disconnected, "the subscriber's link is down");
  p::Proxy proxy(*call.communicator, caller, caller_path);
  if (call.oneway) {
    proxy.notify_raw(call.method, call.args);
    co_return std::vector<std::byte>{};
  }
  state.reset();
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

// --- The mirroring side ----------------------------------------------------------------------

struct DirectoryMirror::State : std::enable_shared_from_this<State> {
  State(p::Communicator& c, ServiceContainer& s, AdaptorFactory f, std::shared_ptr<p::Peer> l, std::string n)
      : communicator(c), container(s), factory(std::move(f)), link(std::move(l)), name(std::move(n)) {}

  struct Mirrored {
    df::DeviceInfo info;
    std::vector<std::shared_ptr<Adaptor>> services;
    std::int64_t link = 0;   // the device's link on the sharing server when last bound; 0: unbound
    bool lost = false;       // it was bound before and went down
  };

  p::Communicator& communicator;
  ServiceContainer& container;
  AdaptorFactory factory;
  std::shared_ptr<p::Peer> link;
  std::string name;
  std::string watcher_path;
  mutable std::mutex mutex;
  mutable std::condition_variable synced_changed;
  std::map<std::string, Mirrored> devices;
  std::set<std::string> refused;          // ids a local service holds: not mirrored
  std::uint64_t synced_over = 0;          // the connection the directory was read over; 0: not synced
  // Changes that arrived over the current link before the directory's reply was handled (the
  // reply's handler is posted, the next message is not): applied after it, in order.
  std::uint64_t early_over = 0;
  std::vector<std::variant<df::SharedDevice, std::string>> early;
  std::uint64_t connection_listener = 0;
  std::shared_ptr<p::CallObserver> observer;

  void sync();
  // A change told by the directory over `connection`: applied, kept for after the directory's
  // reply, or dropped (an old link's).
  void told(std::uint64_t connection, std::variant<df::SharedDevice, std::string> change);
  void change(const std::variant<df::SharedDevice, std::string>& change) {
    if (const auto* d = std::get_if<df::SharedDevice>(&change)) {
      apply(*d);
    } else {
      remove(std::get<std::string>(change), true);
    }
  }
  void apply(const df::SharedDevice& shared);
  void remove(const std::string& id, bool forgotten);
  void link_down(const std::string& reason);
  void emit(std::string type, const std::string& device, std::string reason = {}) {
    p::Event e(std::move(type));
    e.set("device", device);
    if (!reason.empty()) e.set("reason", std::move(reason));
    container.publish_device_event(e);
  }
  std::uint64_t current_connection() const {
    const auto c = link->connection();
    return c ? c->id() : 0;
  }
};

void DirectoryMirror::State::sync() {
  const auto over = current_connection();
  if (over == 0) return;
  df::ServiceDirectoryPrx directory(communicator, link, std::string(kDirectoryPath));
  const auto ref = communicator.reference<df::DirectoryWatcher>(watcher_path);
  directory.watch_async(ref, [weak = weak_from_this(), over](std::exception_ptr e, std::vector<df::SharedDevice> all) {
    auto self = weak.lock();
    if (!self) return;
    if (e) {
      self->communicator.log().warn("cannot read the service directory of {}: {}", self->name, p::describe(e));
      return;  // the next reconnection tries again
    }
    if (self->current_connection() != over) return;  // that link is gone already
    std::set<std::string> listed;
    for (const auto& d : all) {
      listed.insert(d.device.id);
      self->apply(d);
    }
    std::vector<std::string> stale;
    {
      std::lock_guard lock(self->mutex);
      for (const auto& [id, m] : self->devices) {
        if (!listed.contains(id)) stale.push_back(id);
      }
    }
    for (const auto& id : stale) self->remove(id, true);
    std::vector<std::variant<df::SharedDevice, std::string>> later;
    {
      std::lock_guard lock(self->mutex);
      self->synced_over = over;
      if (self->early_over == over) later = std::move(self->early);
      self->early.clear();
      self->early_over = 0;
    }
    for (const auto& change : later) self->change(change);
    self->synced_changed.notify_all();
    self->communicator.log().info("service directory of {}: {} devices", self->name, all.size());
  });
}

void DirectoryMirror::State::told(std::uint64_t connection, std::variant<df::SharedDevice, std::string> c) {
  {
    std::lock_guard lock(mutex);
    if (connection != synced_over) {
      if (connection != current_connection()) return;
      if (early_over != connection) {
        early.clear();
        early_over = connection;
      }
      early.push_back(std::move(c));
      return;
    }
  }
  change(c);
}

// On the io thread, as every change: one at a time.
void DirectoryMirror::State::apply(const df::SharedDevice& shared) {
  const auto& info = shared.device;
  std::vector<std::shared_ptr<Adaptor>> replaced;
  bool known = false;
  {
    std::lock_guard lock(mutex);
    if (refused.contains(info.id)) return;
    auto it = devices.find(info.id);
    if (it != devices.end()) {
      const auto& had = it->second.info.capabilities;
      known = had.size() == info.capabilities.size() &&
              std::equal(had.begin(), had.end(), info.capabilities.begin(), [](const auto& x, const auto& y) {
                return x.name == y.name && x.interface_id == y.interface_id && x.path == y.path;
              });
      if (!known) {
        replaced = std::move(it->second.services);
        devices.erase(it);
      }
    }
  }
  for (const auto& s : replaced) {
    s->unbind();
    s->retire();
    container.remove(s->id());
  }
  if (!known) {
    Mirrored m;
    m.info = info;
    for (const auto& c : info.capabilities) {
      auto adaptor = factory.make(info, c);
      {
        std::lock_guard lock(mutex);
        adaptor->set_call_observer(observer);
      }
      m.services.push_back(std::move(adaptor));
    }
    // A local device (or another mirror's) holds the id: this server keeps its own.
    for (std::size_t i = 0; i < m.services.size(); ++i) {
      try {
        container.add(m.services[i]);
      } catch (const std::invalid_argument& e) {
        for (std::size_t j = 0; j < i; ++j) container.remove(m.services[j]->id());
        std::lock_guard lock(mutex);
        refused.insert(info.id);
        communicator.log().warn("device {} of {} is not mirrored: {}", info.id, name, e.what());
        return;
      }
    }
    std::lock_guard lock(mutex);
    devices.emplace(info.id, std::move(m));
  }
  std::vector<std::shared_ptr<Adaptor>> to_bind, to_unbind;
  bool back = false;
  {
    std::lock_guard lock(mutex);
    auto& m = devices.at(info.id);
    if (shared.link != 0 && shared.link != m.link) {
      back = m.lost;
      m.lost = false;
      m.link = shared.link;
      to_bind = m.services;
    } else if (shared.link == 0 && m.link != 0) {
      m.lost = true;
      m.link = 0;
      to_unbind = m.services;
    }
  }
  for (const auto& s : to_bind) s->bind(communicator, link);
  for (const auto& s : to_unbind) s->unbind();
  if (back) emit("DeviceBack", info.id);
  if (!to_unbind.empty()) emit("DeviceLost", info.id, fmt::format("it lost its link to server {}", name));
}

void DirectoryMirror::State::remove(const std::string& id, bool forgotten) {
  Mirrored m;
  {
    std::lock_guard lock(mutex);
    refused.erase(id);
    auto it = devices.find(id);
    if (it == devices.end()) return;
    m = std::move(it->second);
    devices.erase(it);
  }
  for (const auto& s : m.services) {
    s->unbind();
    s->retire();
    container.remove(s->id());
  }
  if (forgotten) emit("DeviceForgotten", id);
}

void DirectoryMirror::State::link_down(const std::string& reason) {
  std::vector<std::pair<std::string, std::vector<std::shared_ptr<Adaptor>>>> down;
  {
    std::lock_guard lock(mutex);
    synced_over = 0;
    for (auto& [id, m] : devices) {
      if (m.link == 0) continue;
      m.link = 0;
      m.lost = true;
      down.emplace_back(id, m.services);
    }
  }
  synced_changed.notify_all();
  for (const auto& [id, services] : down) {
    for (const auto& s : services) s->unbind();
    emit("DeviceLost", id, fmt::format("the link to server {} closed: {}", name, reason));
  }
}

DirectoryMirror::DirectoryMirror(p::Communicator& communicator, ServiceContainer& container, AdaptorFactory factory,
                                 std::shared_ptr<p::Peer> link, std::string name)
    : state_(std::make_shared<State>(communicator, container, std::move(factory), std::move(link), std::move(name))) {
  static std::atomic<std::uint64_t> mirrors{0};
  state_->watcher_path = fmt::format("/sf/mirror/{}", ++mirrors);
  std::weak_ptr<State> weak = state_;
  auto watcher = std::make_shared<p::Servant>(std::string(df::DirectoryWatcher::type_id));
  watcher->implement(df::DirectoryWatcher::changed, [weak](const df::SharedDevice& d, const p::Current& c) {
    if (auto state = weak.lock(); state && c.connection) state->told(c.connection->id(), d);
  });
  watcher->implement(df::DirectoryWatcher::removed, [weak](const std::string& id, const p::Current& c) {
    if (auto state = weak.lock(); state && c.connection) state->told(c.connection->id(), id);
  });
  communicator.adapter().add(state_->watcher_path, watcher);
  state_->connection_listener = communicator.connections().add_listener([weak](const p::ConnectionEvent& e) {
    auto state = weak.lock();
    if (!state || e.peer != state->link) return;
    if (e.kind == p::LinkEventKind::connected) {
      state->sync();
    } else if (e.kind == p::LinkEventKind::disconnected) {
      state->link_down(e.reason);
    }
  });
  // Already connected: read it now (the listener sees only later connections).
  asio::post(communicator.io(), [weak] {
    auto state = weak.lock();
    if (!state) return;
    bool synced = false;
    {
      std::lock_guard lock(state->mutex);
      synced = state->synced_over != 0;
    }
    if (!synced) state->sync();
  });
}

DirectoryMirror::~DirectoryMirror() {
  state_->communicator.connections().remove_listener(state_->connection_listener);
  state_->communicator.adapter().remove(state_->watcher_path);
  std::vector<std::string> ids;
  {
    std::lock_guard lock(state_->mutex);
    for (const auto& [id, m] : state_->devices) ids.push_back(id);
  }
  for (const auto& id : ids) state_->remove(id, false);
}

const std::string& DirectoryMirror::name() const { return state_->name; }

std::size_t DirectoryMirror::devices() const {
  std::lock_guard lock(state_->mutex);
  return state_->devices.size();
}

bool DirectoryMirror::synced() const {
  std::lock_guard lock(state_->mutex);
  return state_->synced_over != 0;
}

bool DirectoryMirror::wait_synced(std::chrono::milliseconds timeout) const {
  std::unique_lock lock(state_->mutex);
  return state_->synced_changed.wait_for(lock, timeout, [&] { return state_->synced_over != 0; });
}

void DirectoryMirror::set_call_observer(std::shared_ptr<p::CallObserver> observer) {
  std::lock_guard lock(state_->mutex);
  state_->observer = std::move(observer);
}

}  // namespace icars::service
