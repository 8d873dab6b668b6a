// The mirroring side of one service directory over several servers (shared_directory.h).
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <asio/post.hpp>
#include <algorithm>
#include <atomic>
#include <set>
#include <variant>

#include "icars/planet/proxy.h"
#include "icars/planet/remote.h"
#include "icars/service/shared_directory.h"

namespace icars::service {

namespace p = icars::planet;

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
  std::set<std::string> refused;          // ids another holder has: not mirrored now
  std::function<bool(const std::string&)> make_room;
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
  // Services that leave the container for good (their device left, or gave way).
  void retire(const std::vector<std::shared_ptr<Adaptor>>& services) {
    for (const auto& s : services) {
      s->unbind();
      s->retire();
      container.remove(s->id());
    }
  }
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
    // Given up to another holder: taken back when told of it connected and the id is free.
    if (refused.contains(info.id) && shared.link == 0) return;
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
  retire(replaced);
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
    // Another mirror holding the id gives it up if its device is gone and this one's is here (a
    // device manager that moved to this mirror's server); a device registered on this server
    // keeps it.
    std::function<bool(const std::string&)> room;
    {
      std::lock_guard lock(mutex);
      room = make_room;
    }
    const bool taken = std::any_of(m.services.begin(), m.services.end(),
                                   [&](const auto& s) { return container.get(s->id()) != nullptr; });
    if (taken && shared.link != 0 && room) room(info.id);
    for (std::size_t i = 0; i < m.services.size(); ++i) {
      try {
        container.add(m.services[i]);
      } catch (const std::invalid_argument& e) {
        for (std::size_t j = 0; j < i; ++j) container.remove(m.services[j]->id());
        std::lock_guard lock(mutex);
        if (refused.insert(info.id).second) {
          communicator.log().warn("device {} of {} is not mirrored: {}", info.id, name, e.what());
        }
        return;
      }
    }
    std::lock_guard lock(mutex);
    refused.erase(info.id);
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
  retire(m.services);
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
    // A reconnection reads the directory again: what changed while the link was down.
    if (e.kind == p::LinkEventKind::connected || e.kind == p::LinkEventKind::reconnected) {
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

bool DirectoryMirror::yield(const std::string& device_id, bool only_if_disconnected) {
  State::Mirrored m;
  {
    std::lock_guard lock(state_->mutex);
    auto it = state_->devices.find(device_id);
    if (it == state_->devices.end()) return false;
    if (only_if_disconnected && it->second.link != 0) return false;
    m = std::move(it->second);
    state_->devices.erase(it);
    state_->refused.insert(device_id);
  }
  state_->retire(m.services);
  state_->communicator.log().info("device {} of {} gives way to another holder", device_id, state_->name);
  return true;
}

void DirectoryMirror::set_make_room(std::function<bool(const std::string&)> fn) {
  std::lock_guard lock(state_->mutex);
  state_->make_room = std::move(fn);
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
