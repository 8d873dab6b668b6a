#include "icars/control/remote_tree.h"

#include <fmt/format.h>

#include <algorithm>
#include <stdexcept>

#include "icars/control/policy.h"
#include "icars/control/tree_builder.h"

namespace icars::control {

namespace b = icars::behavior;
namespace p = icars::planet;

namespace {

constexpr std::size_t kMaxEnded = 1024;     // statuses of ended subtrees kept for status()
constexpr std::size_t kMaxEarly = 256;      // subtrees heard from before their node knew them
constexpr std::size_t kMaxEarlyEvents = 64;  // events kept per such subtree
constexpr std::size_t kMaxDown = 1024;       // closed host links remembered

bool disconnected(std::exception_ptr e) {
  try {
    std::rethrow_exception(e);
  } catch (const p::Error& error) {
    return error.kind() == p::ErrorKind::disconnected;
  } catch (...) {
    return false;
  }
}

}  // namespace

NodeSpec parse_subtree(const std::string& xml, const b::BehaviorRegistry& registry) {
  const std::string policy = "<policy name=\"subtree\"><task name=\"Subtree\">" + xml +
                             "</task><statechart initial=\"Run\"><state name=\"Run\" task=\"Subtree\"/>"
                             "</statechart></policy>";
  const auto parsed = parse_policy(policy, "subtree", registry);
  const auto* task = parsed.policy.task("Subtree");
  if (task == nullptr || parsed.policy.tasks.size() != 1) {
    throw PolicyError({Diagnostic{"subtree", 1, false, "a subtree is one node of a task, as a policy task holds it", 0}});
  }
  return task->root;
}

remote::TreeEvent encode_tree_event(const b::Event& e) {
  remote::TreeEvent out;
  p::Writer w(out.encoded.bytes);
  p::Codec<p::Event>::encode(w, e);
  return out;
}

b::Event decode_tree_event(const remote::TreeEvent& e) {
  p::Reader r(e.encoded.bytes);
  auto event = p::Codec<p::Event>::decode(r);
  if (r.remaining() != 0) r.fail("tree event: trailing bytes after the event");
  return event;
}

// --- SubtreeHost ---------------------------------------------------------------------------

// One subtree and the parent it reports to; the subtree's owner. Runtime thread only, except
// the fields set before it starts.
class SubtreeHost::Hosted final : public b::Owner {
 public:
  Hosted(SubtreeHost& host, std::int64_t id, std::uint64_t connection, remote::SubtreeParentPrx parent,
         std::unique_ptr<b::Behavior> root)
      : host_(host), id_(id), connection_(connection), parent_(std::move(parent)), root_(std::move(root)) {}
  ~Hosted() override {
    if (root_ && root_->running()) root_->halt();
  }

  std::int64_t id() const { return id_; }
  std::uint64_t connection() const { return connection_; }
  b::Behavior& root() { return *root_; }
  // Readable from any thread: "running" until the root completed or was halted.
  std::string status() const {
    std::lock_guard lock(mutex_);
    return status_;
  }
  void halt() {
    root_->halt();
    set_status("halted");
  }

 protected:
  void child_event(b::Behavior&, const b::Event& event) override {
    try {
      parent_.propagated(id_, encode_tree_event(event));
    } catch (const p::Error&) {
      // The parent's link is gone: the host halts the subtree when it sees the link close.
    }
  }
  void child_done(b::Behavior& child) override {
    const bool succeeded = child.status() == b::Status::succeeded;
    set_status(succeeded ? "succeeded" : "failed");
    try {
      parent_.completed(id_, succeeded, child.failure_reason());
    } catch (const p::Error&) {
    }
    host_.end(id_);
  }

 private:
  void set_status(std::string s) {
    std::lock_guard lock(mutex_);
    status_ = std::move(s);
  }

  SubtreeHost& host_;
  std::int64_t id_;
  std::uint64_t connection_;
  remote::SubtreeParentPrx parent_;
  std::unique_ptr<b::Behavior> root_;
  mutable std::mutex mutex_;
  std::string status_ = "running";
};

SubtreeHost::SubtreeHost(b::Environment& env, const b::BehaviorRegistry& registry, p::Communicator& communicator,
                         SubtreeHostOptions options)
    : env_(env), registry_(registry), communicator_(communicator), options_(options) {
  listener_ = communicator_.connections().add_listener(
      [this, alive = std::weak_ptr<const char>(alive_)](const p::ConnectionEvent& e) {
        if (alive.expired() || e.kind != p::LinkEventKind::disconnected || !e.connection) return;
        std::vector<std::int64_t> orphans;
        {
          std::lock_guard lock(mutex_);
          for (const auto& [id, hosted] : hosted_) {
            if (hosted->connection() == e.connection->id()) orphans.push_back(id);
          }
        }
        for (const auto id : orphans) halt_later(id);
      });
}

SubtreeHost::~SubtreeHost() {
  communicator_.connections().remove_listener(listener_);
  alive_.reset();
  std::map<std::int64_t, std::shared_ptr<Hosted>> hosted;
  {
    std::lock_guard lock(mutex_);
    hosted.swap(hosted_);
  }
  // The trees are halted and destroyed on their runtime.
  env_.runtime.run([&hosted] { hosted.clear(); });
}

std::int64_t SubtreeHost::start(const std::string& path, const std::string& xml, const p::Current& current) {
  // The caller's SubtreeParent, over the link this call came on.
  remote::SubtreeParentPrx parent(communicator_, current.connection, std::string(kSubtreeParentPath));
  std::unique_ptr<b::Behavior> root;
  try {
    root = build_tree(parse_subtree(xml, registry_), registry_);
  } catch (const std::exception& e) {
    throw remote::SubtreeRefused(e.what(), e.what());
  }
  std::shared_ptr<Hosted> hosted;
  std::int64_t id = 0;
  {
    std::lock_guard lock(mutex_);
    if (hosted_.size() >= options_.max_subtrees) {
      const auto why = fmt::format("the host runs {} subtrees, its limit", hosted_.size());
      throw remote::SubtreeRefused(why, why);
    }
    id = next_id_++;
    hosted = std::make_shared<Hosted>(*this, id, current.connection->id(), std::move(parent), std::move(root));
    hosted_.emplace(id, hosted);
  }
  // Under the placing tree's path: its parent's path, then the subtree's own name.
  const auto slash = path.rfind('/');
  const std::string prefix = slash == std::string::npos ? std::string() : path.substr(0, slash);
  env_.runtime.post([this, alive = std::weak_ptr<const char>(alive_), hosted, prefix] {
    if (alive.expired()) return;
    hosted->root().attach(env_, *hosted, prefix);
    hosted->root().start();
  });
  return id;
}

void SubtreeHost::deliver(std::int64_t subtree, const remote::TreeEvent& event, const p::Current&) {
  auto e = decode_tree_event(event);
  env_.runtime.post([this, alive = std::weak_ptr<const char>(alive_), subtree, e = std::move(e)] {
    if (alive.expired()) return;
    if (auto hosted = find(subtree)) hosted->root().receive(e);
  });
}

void SubtreeHost::halt(std::int64_t subtree, const p::Current&) { halt_later(subtree); }

void SubtreeHost::halt_later(std::int64_t id) {
  env_.runtime.post([this, alive = std::weak_ptr<const char>(alive_), id] {
    if (alive.expired()) return;
    if (auto hosted = find(id)) {
      hosted->halt();
      end(id);
    }
  });
}

std::string SubtreeHost::status(std::int64_t subtree, const p::Current&) {
  if (auto hosted = find(subtree)) return hosted->status();
  std::lock_guard lock(mutex_);
  const auto it = ended_.find(subtree);
  return it == ended_.end() ? "unknown" : it->second;
}

std::size_t SubtreeHost::running() const {
  std::lock_guard lock(mutex_);
  return hosted_.size();
}

std::shared_ptr<SubtreeHost::Hosted> SubtreeHost::find(std::int64_t id) const {
  std::lock_guard lock(mutex_);
  const auto it = hosted_.find(id);
  return it == hosted_.end() ? nullptr : it->second;
}

void SubtreeHost::end(std::int64_t id) {
  // Destroyed after the handler that ended it: a child's completion runs inside its tree.
  env_.runtime.post([this, alive = std::weak_ptr<const char>(alive_), id] {
    if (alive.expired()) return;
    std::shared_ptr<Hosted> gone;
    std::lock_guard lock(mutex_);
    const auto it = hosted_.find(id);
    if (it == hosted_.end()) return;
    gone = it->second;
    hosted_.erase(it);
    if (ended_.size() >= kMaxEnded) ended_.erase(ended_.begin());
    ended_[id] = gone->status();
  });
}

// --- RemoteSubtree -------------------------------------------------------------------------

// Stands where the subtree's root would be; see the header.
class RemoteSubtree final : public b::Behavior {
 public:
  RemoteSubtree(RemoteHosts& hosts, std::string host, std::string xml)
      : hosts_(hosts), host_(std::move(host)), xml_(std::move(xml)) {}

 protected:
  void entry() override {
    id_ = 0;
    completed_ = false;
    queued_.clear();
    peer_ = hosts_.peer(host_);
    const auto connection = peer_->connection();
    if (!connection) throw b::BehaviorError(fmt::format("disconnected: host {} is not connected", host_));
    connection_ = connection->id();
    auto host = host_proxy();
    auto started = guard([this](std::exception_ptr e, std::int64_t id) {
      if (e) {
        // The host went away before it answered: the same failure as after it answered.
        if (disconnected(e)) return fail(fmt::format("disconnected: host {}: {}", host_, describe(e)));
        return fail(fmt::format("host {} did not start {}: {}", host_, name(), describe(e)));
      }
      id_ = id;
      hosts_.attach(connection_, id_,
                    RemoteHosts::Listener{guard([this](b::Event event) { propagate(std::move(event)); }),
                                          guard([this](bool succeeded, std::string reason) {
                                            completed_ = true;
                                            if (succeeded) {
                                              succeed();
                                            } else {
                                              fail(std::move(reason));
                                            }
                                          }),
                                          guard([this](std::string reason) {
                                            fail(fmt::format("disconnected: host {}: {}", host_, reason));
                                          })});
      for (auto& event : queued_) send(event);
      queued_.clear();
    });
    // The host's answer settles the start: a node halted before it came leaves no subtree behind.
    start_ = std::make_shared<Start>();
    host.start_async(path(), xml_,
                     [started, start = start_, host](std::exception_ptr e, std::int64_t id = 0) mutable {
                       {
                         std::lock_guard lock(start->mutex);
                         if (start->abandoned) {
                           if (!e) host.halt_async(id, [](std::exception_ptr) {});
                           return;
                         }
                         start->answered = true;
                         if (!e) start->id = id;
                       }
                       started(e, id);
                     });
  }
  // A sibling's event: for the remote root.
  void handle_event(const b::Event& e) override {
    if (id_ == 0) {
      queued_.push_back(e);
    } else {
      send(e);
    }
  }
  void exit() override {
    std::int64_t id = 0;
    {
      std::lock_guard lock(start_->mutex);
      if (!start_->answered) {
        start_->abandoned = true;  // the answer halts what it started
        return;
      }
      id = start_->id;  // also when the node has not heard the answer yet
    }
    if (id == 0) return;  // the host refused it
    hosts_.detach(connection_, id);
    if (completed_) return;
    const auto connection = peer_->connection();
    if (!connection || connection->id() != connection_) return;  // its subtree went with the link
    host_proxy().halt_async(id, [](std::exception_ptr) {});
  }

 private:
  remote::BehaviorHostPrx host_proxy() const {
    return remote::BehaviorHostPrx(hosts_.communicator_, peer_, std::string(kBehaviorHostPath));
  }
  void send(const b::Event& e) {
    try {
      host_proxy().deliver(id_, encode_tree_event(e));
    } catch (const p::Error&) {
      // The link is down: the node fails when it sees it go.
    }
  }

  struct Start {
    std::mutex mutex;
    bool answered = false;   // the host answered start (and the node heard it, or will)
    bool abandoned = false;  // the node ended before the answer
    std::int64_t id = 0;     // the subtree's id on the host, once it answered
  };

  RemoteHosts& hosts_;
  std::string host_;
  std::string xml_;
  std::shared_ptr<Start> start_ = std::make_shared<Start>();
  std::shared_ptr<p::Peer> peer_;
  std::uint64_t connection_ = 0;
  std::int64_t id_ = 0;  // the host's id of the subtree, once it answered
  bool completed_ = false;
  std::vector<b::Event> queued_;  // siblings' events before the host answered
};

// --- RemoteHosts ---------------------------------------------------------------------------

class RemoteHosts::Parent final : public remote::SubtreeParentServant {
 public:
  explicit Parent(RemoteHosts& hosts) : hosts_(hosts) {}
  void propagated(std::int64_t subtree, const remote::TreeEvent& event, const p::Current& current) override {
    hosts_.propagated(current.connection->id(), subtree, decode_tree_event(event));
  }
  void completed(std::int64_t subtree, bool succeeded, const std::string& reason, const p::Current& current) override {
    hosts_.completed(current.connection->id(), subtree, succeeded, reason);
  }

 private:
  RemoteHosts& hosts_;
};

RemoteHosts::RemoteHosts(p::Communicator& communicator) : communicator_(communicator) {
  communicator_.adapter().add(std::string(kSubtreeParentPath), std::make_shared<Parent>(*this));
  listener_ = communicator_.connections().add_listener([this](const p::ConnectionEvent& e) {
    if (e.kind == p::LinkEventKind::disconnected && e.connection) link_down(e.connection->id(), e.reason);
  });
}

RemoteHosts::~RemoteHosts() {
  communicator_.connections().remove_listener(listener_);
  communicator_.adapter().remove(std::string(kSubtreeParentPath));
  std::map<std::string, std::shared_ptr<p::Peer>> hosts;
  {
    std::lock_guard lock(mutex_);
    hosts.swap(hosts_);
  }
  for (auto& [name, peer] : hosts) peer->stop();
}

void RemoteHosts::add(const std::string& name, const std::string& host, std::uint16_t port) {
  std::lock_guard lock(mutex_);
  if (hosts_.contains(name)) throw std::invalid_argument("behavior host '" + name + "' given twice");
  hosts_.emplace(name, communicator_.connect(host, port));
}

bool RemoteHosts::knows(const std::string& name) const {
  std::lock_guard lock(mutex_);
  return hosts_.contains(name);
}

bool RemoteHosts::wait_connected(const std::string& name, std::chrono::milliseconds timeout) const {
  const auto p = peer(name);
  return p->wait_connected(timeout);
}

bool RemoteHosts::wait_all_connected(std::chrono::milliseconds timeout) const {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::vector<std::shared_ptr<p::Peer>> peers;
  {
    std::lock_guard lock(mutex_);
    for (const auto& [name, peer] : hosts_) peers.push_back(peer);
  }
  for (const auto& peer : peers) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
    if (!peer->wait_connected(std::max(left, std::chrono::milliseconds(0)))) return false;
  }
  return true;
}

std::shared_ptr<p::Peer> RemoteHosts::peer(const std::string& name) const {
  std::lock_guard lock(mutex_);
  const auto it = hosts_.find(name);
  if (it == hosts_.end()) throw b::BehaviorError("no behavior host named '" + name + "'");
  return it->second;
}

std::unique_ptr<b::Behavior> RemoteHosts::make(const std::string& name, const std::string& node, const std::string& xml) {
  if (!knows(name)) throw std::invalid_argument("no behavior host named '" + name + "'");
  auto remote = std::make_unique<RemoteSubtree>(*this, name, xml);
  remote->set_identity("remote", node);
  return remote;
}

void RemoteHosts::attach(std::uint64_t connection, std::int64_t id, Listener listener) {
  Early early;
  std::optional<std::string> closed;
  {
    std::lock_guard lock(mutex_);
    const auto key = std::make_pair(connection, id);
    if (const auto it = early_.find(key); it != early_.end()) {
      early = std::move(it->second);
      early_.erase(it);
    }
    if (const auto down = down_.find(connection); down != down_.end()) {
      closed = down->second;  // the link closed between the host's answer and now
    } else {
      nodes_[key] = listener;
    }
  }
  for (auto& e : early.events) listener.propagated(std::move(e));
  if (early.completion) {
    listener.completed(early.completion->first, early.completion->second);
  } else if (closed) {
    listener.lost(*closed);  // the subtree went with the link
  }
}

void RemoteHosts::detach(std::uint64_t connection, std::int64_t id) {
  std::lock_guard lock(mutex_);
  nodes_.erase({connection, id});
  early_.erase({connection, id});
}

void RemoteHosts::propagated(std::uint64_t connection, std::int64_t id, b::Event e) {
  std::function<void(b::Event)> deliver;
  {
    std::lock_guard lock(mutex_);
    const auto key = std::make_pair(connection, id);
    if (const auto it = nodes_.find(key); it != nodes_.end()) {
      deliver = it->second.propagated;
    } else if (early_.size() < kMaxEarly || early_.contains(key)) {
      auto& early = early_[key];  // the host's reply to start() may come after this
      if (early.events.size() < kMaxEarlyEvents) early.events.push_back(std::move(e));
      return;
    } else {
      return;
    }
  }
  deliver(std::move(e));
}

void RemoteHosts::completed(std::uint64_t connection, std::int64_t id, bool succeeded, const std::string& reason) {
  std::function<void(bool, std::string)> deliver;
  {
    std::lock_guard lock(mutex_);
    const auto key = std::make_pair(connection, id);
    if (const auto it = nodes_.find(key); it != nodes_.end()) {
      deliver = it->second.completed;
    } else if (early_.size() < kMaxEarly || early_.contains(key)) {
      early_[key].completion = std::make_pair(succeeded, reason);
      return;
    } else {
      return;
    }
  }
  deliver(succeeded, reason);
}

void RemoteHosts::link_down(std::uint64_t connection, const std::string& reason) {
  std::vector<std::function<void(std::string)>> lost;
  {
    std::lock_guard lock(mutex_);
    for (auto it = nodes_.begin(); it != nodes_.end();) {
      if (it->first.first == connection) {
        lost.push_back(it->second.lost);
        it = nodes_.erase(it);
      } else {
        ++it;
      }
    }
    for (auto it = early_.begin(); it != early_.end();) {
      it = it->first.first == connection ? early_.erase(it) : std::next(it);
    }
    if (down_.size() >= kMaxDown) down_.erase(down_.begin());  // ids only grow: the oldest go
    down_[connection] = reason.empty() ? "the link closed" : reason;
  }
  for (auto& l : lost) l(reason.empty() ? "the link closed" : reason);
}

}  // namespace icars::control
