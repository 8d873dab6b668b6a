// Tutorial, step 3 (service provider): the adaptor services through which behaviors use the
// new capabilities. When a device registers, the Service Framework's device registry asks its
// AdaptorFactory for one adaptor per capability, keyed by the capability's interface id, and
// puts it in the service container, where behaviors discover it by type and room.
#pragma once

#include "fan.planet.h"
#include "icars/service/adaptor.h"
#include "icars/service/device_registry.h"

namespace tutorial {

// An actuator: the service is the capability's proxy, bound while its device is connected.
class FanService final : public icars::service::AdaptorOf<FanPrx> {
 public:
  FanService(const icars::df::DeviceInfo& device, const icars::df::CapabilityInfo& capability)
      : AdaptorOf("Fan", device, capability) {}
};

// A sensor: the adaptor serves a TemperatureListener on the server and subscribes it to the
// thermometer on every bind, so events flow again after the device reconnects.
class ThermometerService final
    : public icars::service::SensorAdaptor<ThermometerPrx, TemperatureListener, TemperatureEvent,
                                           TemperatureListener::on_temperature> {
 public:
  ThermometerService(const icars::df::DeviceInfo& device, const icars::df::CapabilityInfo& capability)
      : SensorAdaptor("Thermometer", device, capability) {}
};

// Teaches `factory` the adaptors of fan.idl's capabilities.
inline void add_adaptors(icars::service::AdaptorFactory& factory) {
  factory.add<Fan, FanService>();
  factory.add<Thermometer, ThermometerService>();
}

}  // namespace tutorial
