// ICARS Device Framework (DF): devices as sets of capabilities (ICARS paper 3.2, 4.2, Fig. 9).
//
// A device provider models a device — a TV, a lamp, a robot's wheels, a speech engine — as a
// Device with Capabilities. Each capability is a remote interface written in PLANET IDL
// (`idl/home.idl`) and implemented by a servant (the generated `...Servant` base); sensing
// capabilities also publish events. A DeviceManager (device_manager.h) serves the capabilities
// of its devices over PLANET and registers the devices with the mediating server.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "device.planet.h"
#include "icars/planet/servant.h"

namespace icars::device {

struct Capability {
  std::string name;                         // its role in the device: "tv_control"
  std::shared_ptr<planet::Servant> servant;  // implements the remote interface
  std::string interface_id() const { return servant->type_id(); }
};

class Device {
 public:
  // `room` is where a static device stands; `carrier` the robot that carries a mobile one.
  Device(std::string id, std::string type, std::string room = {}, std::string carrier = {});

  // Adds a capability; throws std::invalid_argument on a duplicate or malformed name.
  Device& add(std::string name, std::shared_ptr<planet::Servant> servant);

  const std::string& id() const { return id_; }
  const std::string& type() const { return type_; }
  const std::string& room() const { return room_; }
  const std::string& carrier() const { return carrier_; }
  const std::vector<Capability>& capabilities() const { return capabilities_; }

  // Where a capability is served: "/devices/<id>/<capability>".
  std::string path_of(const Capability& capability) const;
  // The description the device registry receives.
  df::DeviceInfo info() const;

 private:
  std::string id_;
  std::string type_;
  std::string room_;
  std::string carrier_;
  std::vector<Capability> capabilities_;
};

}  // namespace icars::device
