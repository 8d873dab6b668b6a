// The placement file: entities placed by unique id, and every mistake reported at its line.
#include "icars/home/mqtt/placements.h"

#include <gtest/gtest.h>

namespace icars::home::mqtt {
namespace {

TEST(Placements, PlaceEntitiesByUniqueId) {
  const auto table = parse_placements(R"(<placements>
  <!-- the living room -->
  <entity unique_id="0x00158d0001a2b3c4_light" device="living_light" room="living_room"/>
  <entity unique_id="0x00158d0001a2b3c5_occupancy" device="sofa_sensor" room="living_room" furniture="sofa"/>
  <entity unique_id="tasmota_plug_1" device="kettle"/>
</placements>)", "p.xml");
  ASSERT_EQ(table.size(), 3u);
  EXPECT_EQ(table.at("0x00158d0001a2b3c4_light").device_id, "living_light");
  EXPECT_EQ(table.at("0x00158d0001a2b3c4_light").room, "living_room");
  EXPECT_EQ(table.at("0x00158d0001a2b3c5_occupancy").furniture, "sofa");
  EXPECT_EQ(table.at("tasmota_plug_1").room, "") << "the config's area then";
  EXPECT_TRUE(parse_placements("<placements/>", "empty.xml").empty());
}

TEST(Placements, EachMistakeIsReportedAtItsLine) {
  const std::vector<std::tuple<std::string, std::size_t, std::string>> cases = {
      {"<placements>\n<entity unique_id=\"a\" device=\"x\">\n", 3, "<entity> (line 2) is never closed"},
      {"<homes/>", 1, "expected <placements>"},
      {"<placements>\n\n<device unique_id=\"a\" device=\"x\"/>\n</placements>", 3, "only <entity>"},
      {"<placements>\n<entity device=\"x\"/>\n</placements>", 2, "needs a unique_id"},
      {"<placements>\n<entity unique_id=\"a\"/>\n</placements>", 2, "needs a device"},
      {"<placements>\n<entity unique_id=\"a\" device=\"x\" area=\"y\"/>\n</placements>", 2, "unknown attribute 'area'"},
      {"<placements>\n<entity unique_id=\"a\" device=\"living light\"/>\n</placements>", 2, "is not a name"},
      {"<placements>\n<entity unique_id=\"a\" device=\"x\" room=\"a/b\"/>\n</placements>", 2, "is not a name"},
      {"<placements>\n<entity unique_id=\"a\" device=\"x\"/>\n<entity unique_id=\"a\" device=\"y\"/>\n</placements>", 3,
       "placed twice"},
      {"<placements>\n<entity unique_id=\"a\" device=\"x\"/>\n<entity unique_id=\"b\" device=\"x\"/>\n</placements>", 3,
       "given to two entities"},
  };
  for (const auto& [text, line, message] : cases) {
    SCOPED_TRACE(text);
    try {
      parse_placements(text, "p.xml");
      ADD_FAILURE() << "accepted";
    } catch (const PlacementError& e) {
      EXPECT_EQ(e.line(), line) << e.what();
      EXPECT_NE(std::string(e.what()).find(message), std::string::npos) << e.what();
      EXPECT_EQ(std::string(e.what()).rfind("p.xml:" + std::to_string(line) + ":", 0), 0u) << e.what();
    }
  }
  try {
    load_placements("/no/such/placements.xml");
    ADD_FAILURE() << "accepted";
  } catch (const PlacementError& e) {
    EXPECT_NE(std::string(e.what()).find("cannot open"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace icars::home::mqtt
