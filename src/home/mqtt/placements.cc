#include "icars/home/mqtt/placements.h"

#include <fmt/format.h>

#include <fstream>
#include <iterator>
#include <set>

#include "icars/xml/xml_text.h"

namespace icars::home::mqtt {

namespace {

bool is_name(std::string_view s) {
  if (s.empty()) return false;
  for (const char c : s) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' || c == '-';
    if (!ok) return false;
  }
  return true;
}

}  // namespace

PlacementError::PlacementError(const std::string& source, std::size_t line, const std::string& problem)
    : std::runtime_error(fmt::format("{}:{}: {}", source, line, problem)), line_(line) {}

PlacementTable parse_placements(std::string_view text, const std::string& source) {
  const xml::XmlText xml(text);
  pugi::xml_document doc;
  if (const auto problem = xml.load(doc)) throw PlacementError(source, problem->at.line, problem->message);
  const auto root = doc.document_element();
  if (std::string_view(root.name()) != "placements") {
    throw PlacementError(source, xml.line(root),
                         fmt::format("the root element is <{}>, expected <placements>", root.name()));
  }
  PlacementTable table;
  std::set<std::string> device_ids;
  for (const auto& node : root.children()) {
    if (node.type() != pugi::node_element) continue;
    const auto line = xml.line(node);
    if (std::string_view(node.name()) != "entity") {
      throw PlacementError(source, line, fmt::format("<{}> in <placements>: only <entity> elements belong here", node.name()));
    }
    for (const auto& a : node.attributes()) {
      const std::string_view name = a.name();
      if (name != "unique_id" && name != "device" && name != "room" && name != "furniture") {
        throw PlacementError(source, line,
                             fmt::format("unknown attribute '{}' of <entity> (unique_id, device, room, furniture)", name));
      }
    }
    const std::string unique_id = node.attribute("unique_id").value();
    if (unique_id.empty()) throw PlacementError(source, line, "<entity> needs a unique_id (the entity's, from its discovery config)");
    Placement p;
    p.device_id = node.attribute("device").value();
    p.room = node.attribute("room").value();
    p.furniture = node.attribute("furniture").value();
    if (p.device_id.empty()) {
      throw PlacementError(source, line, fmt::format("entity '{}' needs a device (the name policies use)", unique_id));
    }
    for (const auto& [what, value] : {std::pair{"device", &p.device_id}, {"room", &p.room}, {"furniture", &p.furniture}}) {
      if (!value->empty() && !is_name(*value)) {
        throw PlacementError(source, line,
                             fmt::format("{}=\"{}\" of entity '{}' is not a name (letters, digits, '_' and '-')", what,
                                         *value, unique_id));
      }
    }
    if (table.contains(unique_id)) throw PlacementError(source, line, fmt::format("entity '{}' is placed twice", unique_id));
    if (!device_ids.insert(p.device_id).second) {
      throw PlacementError(source, line, fmt::format("device '{}' is given to two entities", p.device_id));
    }
    table.emplace(unique_id, std::move(p));
  }
  return table;
}

PlacementTable load_placements(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw PlacementError(file.string(), 0, "cannot open the placement file");
  const std::string text{std::istreambuf_iterator<char>(in), {}};
  return parse_placements(text, file.string());
}

}  // namespace icars::home::mqtt
