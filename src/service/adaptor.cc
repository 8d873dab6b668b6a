#include "icars/service/adaptor.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

namespace icars::service {

std::string describe_value(const planet::Value& value) {
  if (value.empty()) return "(none)";
  if (value.is<bool>()) return value.as<bool>() ? "true" : "false";
  if (value.is<std::int32_t>()) return std::to_string(value.as<std::int32_t>());
  if (value.is<std::int64_t>()) return std::to_string(value.as<std::int64_t>());
  if (value.is<double>()) return fmt::format("{:g}", value.as<double>());
  if (value.is<std::string>()) return fmt::format("\"{}\"", value.as<std::string>());
  return value.type_name();
}

std::string describe(const std::vector<StateDifference>& differences) {
  std::string out;
  for (const auto& d : differences) {
    if (!out.empty()) out += ", ";
    out += fmt::format("{} {} -> {}", d.name, describe_value(d.wanted), describe_value(d.found));
  }
  return out;
}

// Forwards to the registry's observer and, after each acknowledged command of a stateful
// capability, has the adaptor read the state the device now keeps.
class Adaptor::CommandTracker final : public planet::CallObserver {
 public:
  CommandTracker(std::weak_ptr<Adaptor> adaptor, std::shared_ptr<planet::CallObserver> next)
      : adaptor_(std::move(adaptor)), next_(std::move(next)) {}
  void sent(std::uint32_t request_id, const std::string& path, std::string_view method) override {
    if (next_) next_->sent(request_id, path, method);
  }
  void ended(std::uint32_t request_id, const std::string& path, std::string_view method,
             const std::exception_ptr& error) override {
    if (next_) next_->ended(request_id, path, method, error);
    if (error) return;
    if (auto adaptor = adaptor_.lock(); adaptor && adaptor->is_command(method)) {
      adaptor->command_acknowledged();
    }
  }

 private:
  std::weak_ptr<Adaptor> adaptor_;
  std::shared_ptr<planet::CallObserver> next_;
};

Adaptor::Adaptor(std::string type, const df::DeviceInfo& device, const df::CapabilityInfo& capability)
    : Service(device.id + "." + capability.name, std::move(type),
              ServiceAttributes{device.id, capability.name, device.room, device.carrier}),
      interface_id_(capability.interface_id),
      path_(capability.path),
      device_(device.id) {}

Adaptor::~Adaptor() = default;

void Adaptor::bind(planet::Communicator& communicator, const std::shared_ptr<planet::Link>& link) {
  const auto connection = link ? link->connection() : nullptr;
  bound_connection_ = connection ? connection->id() : 0;
  {
    std::lock_guard lock(observer_mutex_);
    bound_link_ = link;
  }
  on_bind(communicator, link);
  set_available(true);
}

void Adaptor::log_failure(planet::Communicator& communicator, std::string_view what,
                          std::exception_ptr error) const {
  communicator.log().warn("service {} {}: {}", id(), what, planet::describe(error));
}

void Adaptor::set_call_observer(std::shared_ptr<planet::CallObserver> observer) {
  std::lock_guard lock(observer_mutex_);
  call_observer_ = std::move(observer);
}

std::shared_ptr<planet::CallObserver> Adaptor::call_observer() {
  std::lock_guard lock(observer_mutex_);
  if (!keeps_state()) return call_observer_;
  return std::make_shared<CommandTracker>(
      std::static_pointer_cast<Adaptor>(shared_from_this()), call_observer_);
}

void Adaptor::check_own_link(const planet::Current& current) const {
  const auto bound = bound_connection();
  if (current.connection && current.connection->id() == bound) return;
  const auto principal = current.connection ? current.connection->principal() : nullptr;
  throw planet::Error(
      planet::ErrorKind::denied,
      fmt::format("{} may not deliver events of device '{}': {}",
                  principal ? fmt::format("principal '{}'", principal->name)
                            : (current.connection ? current.connection->describe() : "a peer"),
                  device_id(),
                  bound == 0 ? "the device is not connected"
                             : "only the link that registered the device may"));
}

DeviceState Adaptor::acknowledged_state() const {
  std::lock_guard lock(observer_mutex_);
  return acknowledged_;
}

void Adaptor::command_acknowledged() {
  std::uint64_t read = 0;
  {
    std::lock_guard lock(observer_mutex_);
    read = ++reads_started_;
  }
  read_state([weak = weak_from_this(), read](std::exception_ptr error, DeviceState state) {
    auto self = std::static_pointer_cast<Adaptor>(weak.lock());
    if (!self || error) return;  // the next command or the next restore reads it again
    std::lock_guard lock(self->observer_mutex_);
    if (read == self->reads_started_) self->acknowledged_ = std::move(state);
  });
}

void Adaptor::restore(bool reapply, std::function<void(Restoration)> done) {
  const DeviceState wanted = acknowledged_state();
  if (!keeps_state() || wanted.size() == 0) {
    done({});
    return;
  }
  read_state([weak = weak_from_this(), wanted, reapply, done = std::move(done)](
                 std::exception_ptr error, DeviceState found) mutable {
    auto self = std::static_pointer_cast<Adaptor>(weak.lock());
    Restoration result;
    if (!self) return;
    if (error) {
      result.error = error;
      done(std::move(result));
      return;
    }
    for (const auto& [name, value] : wanted.items()) {
      const planet::Value* now = found.has(name) ? &found.value(name) : nullptr;
      if (!now || !(*now == value)) {
        result.differences.push_back({name, value, now ? *now : planet::Value()});
      }
    }
    if (result.differences.empty() || !reapply) {
      done(std::move(result));
      return;
    }
    result.reapplied = true;
    self->apply_state(wanted, [result = std::move(result), done = std::move(done)](
                                  std::exception_ptr e) mutable {
      result.error = e;
      done(std::move(result));
    });
  });
}

std::shared_ptr<planet::Link> Adaptor::bound_link() const {
  std::lock_guard lock(observer_mutex_);
  return bound_connection_.load() == 0 ? nullptr : bound_link_.lock();
}

void Adaptor::unbind() {
  {
    std::lock_guard lock(observer_mutex_);
    bound_link_.reset();
  }
  bound_connection_ = 0;
  set_available(false);
  on_unbind();
}

}  // namespace icars::service
