// One service directory over several servers (docs/distribution.md): the devices that
// registered on one mediating server are services on the others too.
//
// The server the devices registered on shares them (SharedDirectory): it serves the
// df::ServiceDirectory at /sf/directory, which lists its devices and tells watchers of every
// change, and a relay per capability at /sf/relay/<service id>, which forwards other servers'
// calls to the device manager over the device's own link and, for a reference to the caller's
// object among the arguments (a listener passed to subscribe), hands the device manager a relay
// listener of its own that forwards the device's events back to the caller.
//
// A server that uses them mirrors the directory (DirectoryMirror): over its link to the sharing
// server it watches the directory and keeps, for each shared device, the adaptor services its
// own AdaptorFactory makes, bound to that link at the relay paths, in its own ServiceContainer.
// Behaviors there find and call them as they would a device registered locally; their services
// are unavailable while the device, or the link to the sharing server, is down.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include "device.planet.h"
#include "icars/planet/communicator.h"
#include "icars/service/device_registry.h"
#include "icars/service/service_container.h"

namespace icars::service {

inline constexpr std::string_view kDirectoryPath = "/sf/directory";
inline constexpr std::string_view kRelayPrefix = "/sf/relay/";
// Under /sf/listeners/, which device managers may call (docs/security.md).
inline constexpr std::string_view kRelayListenerPrefix = "/sf/listeners/relay/";

// Shares the devices of `registry` with other servers. Construct it on a communicator that
// serves the registry; it adds its servants to the communicator's adapter and removes them when
// destroyed (destroy it before the registry).
class SharedDirectory {
 public:
  SharedDirectory(planet::Communicator& communicator, DeviceRegistry& registry);
  ~SharedDirectory();
  SharedDirectory(const SharedDirectory&) = delete;
  SharedDirectory& operator=(const SharedDirectory&) = delete;

  std::size_t watchers() const;
  std::size_t relay_listeners() const;

 private:
  class Directory;
  class Relay;
  class RelayListener;
  struct State;
  std::shared_ptr<State> state_;
};

// Mirrors the devices another server shares (its SharedDirectory) into `container`, over
// `link` (a Peer to that server). `name` names that server in logs and events.
class DirectoryMirror {
 public:
  DirectoryMirror(planet::Communicator& communicator, ServiceContainer& container, AdaptorFactory factory,
                  std::shared_ptr<planet::Peer> link, std::string name);
  ~DirectoryMirror();
  DirectoryMirror(const DirectoryMirror&) = delete;
  DirectoryMirror& operator=(const DirectoryMirror&) = delete;

  const std::string& name() const;
  // Devices mirrored now, connected or not.
  std::size_t devices() const;
  // True once the directory has been read over the current link (again after a reconnection).
  bool synced() const;
  // Waits until synced(); false after `timeout`. Not on the io thread.
  bool wait_synced(std::chrono::milliseconds timeout) const;
  // The calls through the mirrored adaptors bound from now on are reported to `observer`.
  void set_call_observer(std::shared_ptr<planet::CallObserver> observer);

  // Gives up a mirrored device (its services leave the container) so that another holder of
  // its id takes its place: a device registering on this server, or (`only_if_disconnected`)
  // another mirror's whose device is connected while this one's is not (a device manager that
  // moved to another server). The mirror takes it back when it is told of it again and the id is
  // free. Returns whether it gave the device up. On the io thread.
  bool yield(const std::string& device_id, bool only_if_disconnected);
  // Asked when a shared device's ids are held here by another mirror: `fn(device_id)` makes
  // room (ServiceFramework asks the other mirrors to yield) and returns whether it did.
  void set_make_room(std::function<bool(const std::string&)> fn);

 private:
  struct State;
  std::shared_ptr<State> state_;
};

}  // namespace icars::service
