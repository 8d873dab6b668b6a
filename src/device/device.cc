#include "icars/device/device.h"

#include <algorithm>
#include <stdexcept>

namespace icars::device {

namespace {
bool valid_name(const std::string& name) {
  return !name.empty() && std::all_of(name.begin(), name.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' ||
           c == '-';
  });
}
}  // namespace

Device::Device(std::string id, std::string type, std::string room, std::string carrier)
    : id_(std::move(id)), type_(std::move(type)), room_(std::move(room)),
      carrier_(std::move(carrier)) {
  if (!valid_name(id_)) {
    throw std::invalid_argument("device id '" + id_ + "' must be letters, digits, '_' or '-'");
  }
}

Device& Device::add(std::string name, std::shared_ptr<planet::Servant> servant) {
  if (!valid_name(name)) {
    throw std::invalid_argument("capability name '" + name + "' of device " + id_ +
                                " must be letters, digits, '_' or '-'");
  }
  if (!servant) throw std::invalid_argument("capability " + name + " of " + id_ + " has no servant");
  for (const auto& c : capabilities_) {
    if (c.name == name) {
      throw std::invalid_argument("device " + id_ + " already has a capability '" + name + "'");
    }
  }
  capabilities_.push_back(Capability{std::move(name), std::move(servant)});
  return *this;
}

std::string Device::path_of(const Capability& capability) const {
  return "/devices/" + id_ + "/" + capability.name;
}

df::DeviceInfo Device::info() const {
  df::DeviceInfo info;
  info.id = id_;
  info.type = type_;
  info.room = room_;
  info.carrier = carrier_;
  for (const auto& c : capabilities_) {
    info.capabilities.push_back(df::CapabilityInfo{c.name, c.interface_id(), path_of(c)});
  }
  return info;
}

}  // namespace icars::device
