// The placement file of the MQTT bridge: where each discovered entity stands in the house and
// the name policies use for it (docs/mqtt.md, "Placements").
//
//   <placements>
//     <entity unique_id="0x00158d0001a2b3c4_light" device="living_light" room="living_room"/>
//     <entity unique_id="0x00158d0001a2b3c5_occupancy" device="sofa_sensor" room="living_room"
//             furniture="sofa"/>
//   </placements>
//
// An entity the file does not name keeps its unique id as device id and its config's area as
// room.
#pragma once

#include <filesystem>
#include <stdexcept>
#include <string>
#include <string_view>

#include "icars/home/mqtt/entity_devices.h"

namespace icars::home::mqtt {

// A placement file that cannot be used: "<file>:<line>: <what is wrong>" (line 0 when the file
// cannot be read).
class PlacementError : public std::runtime_error {
 public:
  PlacementError(const std::string& source, std::size_t line, const std::string& problem);
  std::size_t line() const { return line_; }

 private:
  std::size_t line_;
};

// Reads placements from XML text; `source` names it in errors. Throws PlacementError for
// malformed XML, another root element, an element other than <entity>, a missing or empty
// `unique_id` or `device`, an unknown attribute, an id or room that is not a name (letters,
// digits, '_' and '-'), and a unique id or device id given twice.
PlacementTable parse_placements(std::string_view text, const std::string& source);
PlacementTable load_placements(const std::filesystem::path& file);

}  // namespace icars::home::mqtt
