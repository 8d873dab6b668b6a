#include "icars/xml/xml_text.h"

#include <fmt/format.h>

#include <algorithm>
#include <set>

namespace icars::xml {

XmlText::XmlText(std::string_view text) : text_(text) {
  line_starts_.push_back(0);
  for (std::size_t i = 0; i < text.size(); ++i) {
    if (text[i] == '\n') line_starts_.push_back(i + 1);
  }
}

Position XmlText::position(std::ptrdiff_t offset) const {
  const auto at = static_cast<std::size_t>(std::clamp<std::ptrdiff_t>(
      offset, 0, static_cast<std::ptrdiff_t>(text_.size())));
  const auto it = std::upper_bound(line_starts_.begin(), line_starts_.end(), at);
  const auto line = static_cast<std::size_t>(it - line_starts_.begin());
  std::size_t column = 1;
  for (std::size_t i = line_starts_[line - 1]; i < at; ++i) {
    if ((static_cast<unsigned char>(text_[i]) & 0xC0) != 0x80) ++column;  // not a continuation byte
  }
  return {line, column};
}

Position XmlText::position(const pugi::xml_node& node) const {
  const auto offset = node.offset_debug();
  if (offset < 0) return {};
  // pugixml's offset is past the markup: an element's name after '<', a comment's text after
  // '<!--'; the position is the markup's start.
  const std::ptrdiff_t markup = node.type() == pugi::node_element   ? 1
                                : node.type() == pugi::node_comment ? 4
                                                                    : 0;
  return position(std::max<std::ptrdiff_t>(0, offset - markup));
}

namespace {

std::string_view name_at(std::string_view text, std::size_t at) {
  std::size_t end = at;
  while (end < text.size() && text[end] != '>' && text[end] != '/' &&
         std::string_view(" \t\r\n").find(text[end]) == std::string_view::npos) {
    ++end;
  }
  return text.substr(at, end - at);
}

// Whether the element starting at `open` (its '<') is closed before `before`: an empty-element
// tag, or a closing tag of its name in between.
bool closed_before(std::string_view text, std::size_t open, std::string_view name, std::size_t before) {
  char quote = 0;
  std::size_t i = open + 1;
  for (; i < text.size(); ++i) {
    const char ch = text[i];
    if (quote != 0) {
      if (ch == quote) quote = 0;
    } else if (ch == '"' || ch == '\'') {
      quote = ch;
    } else if (ch == '>') {
      break;
    }
  }
  if (i < text.size() && text[i - 1] == '/') return true;
  const auto end_tag = text.substr(0, before).find(fmt::format("</{}", name), i);
  return end_tag != std::string_view::npos;
}

pugi::xml_node last_element(const pugi::xml_node& parent) {
  for (auto c = parent.last_child(); c; c = c.previous_sibling()) {
    if (c.type() == pugi::node_element) return c;
  }
  return {};
}

}  // namespace

std::optional<XmlProblem> XmlText::load(pugi::xml_document& doc) const {
  const auto result = doc.load_buffer(text_.data(), text_.size(),
                                      pugi::parse_default | pugi::parse_comments, pugi::encoding_utf8);
  if (result) return check(doc);
  const auto offset = static_cast<std::size_t>(std::clamp<std::ptrdiff_t>(
      result.offset, 0, static_cast<std::ptrdiff_t>(text_.size())));
  switch (result.status) {
    case pugi::status_bad_start_element:
    case pugi::status_bad_attribute: {
      // The parser stops where the tag went wrong, often on the next line (a missing '>' or
      // quote): the tag is reported where it opens.
      const auto open = offset == 0 ? std::string_view::npos : text_.rfind('<', offset - 1);
      if (open == std::string_view::npos) break;
      const auto stop = position(static_cast<std::ptrdiff_t>(offset));
      return XmlProblem{position(static_cast<std::ptrdiff_t>(open)),
                        fmt::format("malformed XML: the tag <{}> is not well-formed ({} at line {}, "
                                    "column {}), expected name=\"value\" attributes and a closing '>' "
                                    "or '/>'",
                                    name_at(text_, open + 1), result.description(), stop.line,
                                    stop.column)};
    }
    case pugi::status_end_element_mismatch: {
      // The element left open is the last one begun and not closed before the closing tag.
      // The offset is the closing tag's name, or the end of a document that ended early.
      const bool at_closing_tag = offset >= 2 && text_.substr(offset - 2, 2) == "</";
      const std::string_view closing = at_closing_tag ? name_at(text_, offset) : std::string_view{};
      pugi::xml_node open_element;  // the deepest element begun last
      for (auto n = last_element(doc); n; n = last_element(n)) open_element = n;
      while (open_element && open_element.type() == pugi::node_element &&
             closed_before(text_, static_cast<std::size_t>(open_element.offset_debug() - 1),
                           open_element.name(), offset)) {
        open_element = open_element.parent();
      }
      if (!open_element || open_element.type() != pugi::node_element) break;
      const auto opened = position(open_element);
      return XmlProblem{
          position(static_cast<std::ptrdiff_t>(at_closing_tag ? offset - 2 : text_.size())),
          closing.empty()
              ? fmt::format("malformed XML: <{}> (line {}) is never closed, expected </{}>",
                            open_element.name(), opened.line, open_element.name())
              : fmt::format("malformed XML: </{}> closes <{}> opened at line {}, expected </{}>",
                            closing, open_element.name(), opened.line, open_element.name())};
      break;
    }
    default:
      break;
  }
  return XmlProblem{position(static_cast<std::ptrdiff_t>(offset)),
                    fmt::format("malformed XML: {}", result.description())};
}

// What pugixml accepts and XML does not; comments are dropped once checked.
std::optional<XmlProblem> XmlText::check(const pugi::xml_node& root) const {
  std::vector<pugi::xml_node> comments;
  for (auto n = root.first_child(); n;) {
    if (n.type() == pugi::node_comment) {
      const std::string_view body = n.value();
      if (body.find("--") != std::string_view::npos || body.ends_with('-')) {
        return XmlProblem{position(n), "malformed XML: a comment contains '--', which XML does not allow "
                                       "inside <!-- -->"};
      }
      comments.push_back(n);
    } else if (n.type() == pugi::node_element) {
      std::set<std::string_view> names;
      for (const auto& a : n.attributes()) {
        if (!names.insert(a.name()).second) {
          return XmlProblem{position(n), fmt::format("malformed XML: <{}> has attribute \"{}\" twice",
                                                     n.name(), a.name())};
        }
      }
    }
    // Depth first, without recursion: documents may nest deeply.
    if (n.first_child()) {
      n = n.first_child();
      continue;
    }
    while (n && !n.next_sibling() && n != root) n = n.parent();
    if (!n || n == root) break;
    n = n.next_sibling();
  }
  for (auto& c : comments) c.parent().remove_child(c);
  return std::nullopt;
}

}  // namespace icars::xml
