// XML files that people write (houses, collaboration policies): a document read with the
// position of everything in it, and a malformed one reported where the mistake is.
//
// pugixml parses; XmlText adds what an error message needs — line and column of any node or
// offset — and what pugixml lets through but an XML reader such as xmllint rejects: a repeated
// attribute, and `--` inside a comment. A tag that is never closed is reported where it opens,
// and a closing tag that does not match names the element left open.
#pragma once

#include <pugixml.hpp>

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace icars::xml {

struct Position {
  std::size_t line = 0;    // 1-based; 0: not in the text
  std::size_t column = 0;  // 1-based, in characters (UTF-8 code points)
};

// A document that is not well-formed: where, and what is wrong (without the position).
struct XmlProblem {
  Position at;
  std::string message;
};

class XmlText {
 public:
  explicit XmlText(std::string_view text);  // the text must outlive this object

  Position position(std::ptrdiff_t offset) const;  // offsets past the end: the end of the text
  Position position(const pugi::xml_node& node) const;
  std::size_t line(const pugi::xml_node& node) const { return position(node).line; }

  // Parses the text into `doc` (comments dropped); a malformed document leaves `doc` in an
  // unspecified state and returns what is wrong.
  std::optional<XmlProblem> load(pugi::xml_document& doc) const;

 private:
  std::optional<XmlProblem> check(const pugi::xml_node& root) const;

  std::string_view text_;
  std::vector<std::size_t> line_starts_;
};

}  // namespace icars::xml
