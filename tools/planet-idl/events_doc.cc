#include "events_doc.h"

#include <fmt/format.h>

#include <algorithm>
#include <cstddef>
#include <optional>

namespace icars::planet::idl {

namespace {

// The lines of a file's text, without their line ends.
std::vector<std::string_view> lines_of(std::string_view text) {
  std::vector<std::string_view> lines;
  while (!text.empty()) {
    const auto end = text.find('\n');
    auto line = text.substr(0, end);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    lines.push_back(line);
    if (end == std::string_view::npos) break;
    text.remove_prefix(end + 1);
  }
  return lines;
}

std::string_view trim(std::string_view s) {
  const auto first = s.find_first_not_of(" \t");
  if (first == std::string_view::npos) return {};
  const auto last = s.find_last_not_of(" \t");
  return s.substr(first, last - first + 1);
}

// The text of a `//` comment that is all of `line` (blanks aside), or nullopt.
std::optional<std::string_view> comment_line(std::string_view line) {
  const auto t = trim(line);
  if (!t.starts_with("//")) return std::nullopt;
  return trim(t.substr(2));
}

// Joins comment texts into one paragraph.
std::string join(const std::vector<std::string_view>& parts) {
  std::string out;
  for (const auto p : parts) {
    if (p.empty()) continue;
    if (!out.empty()) out += ' ';
    out += p;
  }
  return out;
}

// The comment lines right above line `line` (1-based), section rules (`// --- x ---`) excluded.
std::string comment_above(const std::vector<std::string_view>& lines, std::uint32_t line) {
  std::vector<std::string_view> parts;
  for (auto i = static_cast<std::size_t>(line) - 1; i > 0; --i) {
    const auto text = comment_line(lines[i - 1]);
    if (!text || text->starts_with("---")) break;
    parts.insert(parts.begin(), *text);
  }
  return join(parts);
}

// The comment after a field's ';' on its line, with the comment-only lines below it that start
// in the same column.
std::string comment_after(const std::vector<std::string_view>& lines, const SourceLocation& at) {
  const auto index = static_cast<std::size_t>(at.line) - 1;
  if (index >= lines.size()) return "";
  const auto line = lines[index];
  const auto semicolon = line.find(';', at.column - 1);
  if (semicolon == std::string_view::npos) return "";
  const auto slashes = line.find_first_not_of(" \t", semicolon + 1);
  if (slashes == std::string_view::npos || line.substr(slashes, 2) != "//") return "";
  std::vector<std::string_view> parts{trim(line.substr(slashes + 2))};
  for (auto next = index + 1; next < lines.size(); ++next) {
    const auto text = comment_line(lines[next]);
    if (!text || lines[next].find("//") != slashes) break;
    parts.push_back(*text);
  }
  return join(parts);
}

// '|' would end a table cell.
std::string cell(std::string_view text) {
  std::string out;
  for (const char c : text) {
    if (c == '|') out += '\\';
    out += c;
  }
  return out;
}

// GitHub's anchor for a heading that is one identifier.
std::string anchor(std::string_view name) {
  std::string out;
  for (const char c : name) out += static_cast<char>(c >= 'A' && c <= 'Z' ? c - 'A' + 'a' : c);
  return out;
}

void collect_events(const Module& module, std::vector<const Struct*>& out) {
  for (const auto& d : module.definitions) {
    if (d->kind == DefinitionKind::module) collect_events(static_cast<const Module&>(*d), out);
    if (d->kind == DefinitionKind::event) out.push_back(static_cast<const Struct*>(d.get()));
  }
}

void collect_interfaces(const Module& module, std::vector<const Interface*>& out) {
  for (const auto& d : module.definitions) {
    if (d->kind == DefinitionKind::module) collect_interfaces(static_cast<const Module&>(*d), out);
    if (d->kind == DefinitionKind::interface) {
      const auto* i = static_cast<const Interface*>(d.get());
      if (std::find(out.begin(), out.end(), i) == out.end()) out.push_back(i);
    }
  }
}

void collect_interfaces(const SourceFile& file, std::vector<const Interface*>& out) {
  for (const auto& include : file.includes) {
    if (include.file) collect_interfaces(*include.file, out);
  }
  collect_interfaces(file.root, out);
}

bool takes(const Operation& op, const Definition& type) {
  return std::any_of(op.parameters.begin(), op.parameters.end(), [&](const Parameter& p) {
    return p.type.kind == Type::Kind::named && p.type.definition == &type;
  });
}

// "Delivered to `SoundListener.on_sound`; a `SoundListener` is taken by `Microphone.subscribe`,
// `Microphone.unsubscribe`.", one sentence per listener operation (none: "").
std::string deliveries(const Struct& event, const std::vector<const Interface*>& interfaces) {
  std::string out;
  for (const Interface* listener : interfaces) {
    for (const Operation& op : listener->operations) {
      if (!takes(op, event)) continue;
      std::string takers;
      for (const Interface* i : interfaces) {
        for (const Operation& taker : i->operations) {
          if (takes(taker, *listener))
            takers += fmt::format("{}`{}.{}`", takers.empty() ? "" : ", ", i->name, taker.name);
        }
      }
      out += fmt::format("\nDelivered to `{}.{}`", listener->name, op.name);
      out += takers.empty() ? ".\n"
                            : fmt::format("; a `{}` is taken by {}.\n", listener->name, takers);
    }
  }
  return out;
}

struct Documented {
  const SourceFile* file;
  const Struct* event;
};

}  // namespace

std::string_view condition_type(const Type& type) {
  if (type.kind != Type::Kind::builtin) return "absent";
  switch (type.builtin) {
    case Builtin::boolean:
      return "bool";
    case Builtin::byte:
    case Builtin::short_int:
    case Builtin::int32:
    case Builtin::int64:
    case Builtin::float32:
    case Builtin::float64:
      return "number";
    case Builtin::string:
      return "string";
    case Builtin::void_type:
    case Builtin::binary:
    case Builtin::stream:
      return "absent";
  }
  return "absent";
}

std::string generate_events_doc(const std::vector<const SourceFile*>& files) {
  std::vector<Documented> events;
  std::vector<const Interface*> interfaces;
  std::string sources;
  for (const SourceFile* file : files) {
    std::vector<const Struct*> found;
    collect_events(file->root, found);
    for (const Struct* e : found) events.push_back({file, e});
    collect_interfaces(*file, interfaces);
    sources += (sources.empty() ? "" : ", ") + fmt::format("`{}`", file->path);
  }

  std::string out = "# Events\n\n";
  out += fmt::format(
      "<!-- Generated by `planet-idl --events-doc` from {}: do not edit.\n"
      "     Regenerate with `cmake --build <build dir> --target events_doc`; a test fails while\n"
      "     this page is out of date. -->\n\n",
      sources);
  out +=
      "The events the IDL declares: what devices and services publish and a collaboration policy\n"
      "senses (`<behavior type=\"Sense\" service=\"...\"/>`, docs/policy.md). A condition names "
      "an\n"
      "event's type without its modules (`event == 'OccupancyEvent'`) and reads its fields as\n"
      "properties by name (`furniture == 'sofa' and occupied`).\n\n"
      "What a condition sees of a field depends on its IDL type "
      "(include/icars/behavior/condition.h):\n"
      "`bool` is a bool; `byte`, `short`, `int`, `long`, `float` and `double` are numbers; "
      "`string`\n"
      "is a string. A field of any other type (`binary`, sequences, valued types, enums) is "
      "absent:\n"
      "a condition reading it sees nothing, and the trace leaves it out of the event's properties\n"
      "(docs/trace.md).\n\n";

  if (events.empty()) return out + "No events are declared.\n";
  out += "| event | file | fields |\n|---|---|---|\n";
  for (const auto& [file, e] : events) {
    std::string fields;
    for (const Field& f : e->fields) fields += (fields.empty() ? "" : ", ") + f.name;
    out +=
        fmt::format("| [`{}`](#{}) | `{}` | {} |\n", e->name, anchor(e->name), file->path, fields);
  }

  for (const auto& [file, e] : events) {
    const auto lines = lines_of(file->text);
    out += fmt::format("\n## {}\n\n`{}`, in `{}`.", e->name, e->qualified_name, file->path);
    if (const auto doc = comment_above(lines, e->location.line); !doc.empty()) out += " " + doc;
    out += "\n";
    out += deliveries(*e, interfaces);
    out += "\n| field | IDL type | in a condition | meaning |\n|---|---|---|---|\n";
    for (const Field& f : e->fields) {
      out += fmt::format("| `{}` | `{}` | {} | {} |\n", f.name, f.type.to_idl(),
                         condition_type(f.type), cell(comment_after(lines, f.location)));
    }
  }
  return out;
}

}  // namespace icars::planet::idl
