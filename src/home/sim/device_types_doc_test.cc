// docs/house.md's table of device types is the registry's: every type home::sim_device_types()
// holds has its row, naming the capability and interface a device of that type really serves,
// and the table has no row for a type the registry lacks.
#include <gtest/gtest.h>

#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "icars/clock/sim_clock.h"
#include "icars/home/sim/sim_devices.h"
#include "icars/planet/communicator.h"
#include "icars/sim/house.h"
#include "icars/sim/world.h"

namespace icars::home {
namespace {

struct Row {
  std::string capability, interface;
};

std::string unquote(std::string cell) {
  const auto first = cell.find_first_not_of(' ');
  const auto last = cell.find_last_not_of(' ');
  cell = first == std::string::npos ? "" : cell.substr(first, last - first + 1);
  if (cell.size() >= 2 && cell.front() == '`' && cell.back() == '`')
    cell = cell.substr(1, cell.size() - 2);
  return cell;
}

// The rows of the first table under "### Device types", by type.
std::map<std::string, Row> documented_types() {
  std::ifstream in(ICARS_HOUSE_DOC);
  std::map<std::string, Row> rows;
  bool in_section = false, in_table = false;
  for (std::string line; std::getline(in, line);) {
    if (line.starts_with("#")) {
      if (in_section) break;
      in_section = line == "### Device types";
      continue;
    }
    if (!in_section) continue;
    if (!line.starts_with("|")) {
      if (in_table) break;
      continue;
    }
    in_table = true;
    std::vector<std::string> cells;
    std::istringstream split(line.substr(1));
    for (std::string cell; std::getline(split, cell, '|');) cells.push_back(unquote(cell));
    if (cells.size() < 3 || cells[0] == "type" || cells[0].starts_with("---")) continue;
    rows[cells[0]] = {cells[1], cells[2]};
  }
  return rows;
}

TEST(DeviceTypesDoc, EveryRegisteredTypeHasItsRowWithWhatItServes) {
  const auto rows = documented_types();
  ASSERT_FALSE(rows.empty()) << "no table under \"### Device types\" in " << ICARS_HOUSE_DOC;

  // A device of every type, in the paper house: the wheels on its robot, the sensors on its sofa.
  SimClock clock{at_time(0, 18, 0)};
  sim::World world{sim::load_house(ICARS_PAPER_HOUSE), clock};
  planet::Communicator communicator;
  const SimContext context{world, communicator};
  const auto& types = sim_device_types();
  for (const auto& type : types.names()) {
    SCOPED_TRACE(type);
    const auto row = rows.find(type);
    if (row == rows.end()) {
      ADD_FAILURE() << "type " << type << " (" << types.description(type)
                    << ") has no row in the table of " << ICARS_HOUSE_DOC
                    << ", section \"Device types\"";
      continue;
    }
    sim::DeviceSpec spec;
    spec.id = "documented";
    spec.type = type;
    spec.room = "living_room";
    spec.pose = {2.0, 2.0, 0};
    if (type == "Wheels") spec.carrier = "robot1";
    if (type == "Occupancy") spec.params["furniture"] = "sofa";
    const auto device = types.make(spec, context);
    ASSERT_EQ(device->capabilities().size(), 1u);
    const auto& capability = device->capabilities().front();
    EXPECT_EQ(row->second.capability, capability.name);
    EXPECT_EQ("icars::" + row->second.interface, capability.interface_id());
  }
  for (const auto& [type, row] : rows) {
    EXPECT_TRUE(types.has(type)) << ICARS_HOUSE_DOC << " lists type " << type
                                 << ", which is not registered";
  }
}

}  // namespace
}  // namespace icars::home
