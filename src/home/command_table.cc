#include "icars/home/command_table.h"

#include <fmt/format.h>

#include <algorithm>
#include <set>
#include <cctype>
#include <map>

namespace icars::home {

namespace {

const std::map<std::string_view, std::vector<std::string_view>>& actions() {
  static const std::map<std::string_view, std::vector<std::string_view>> table = {
      {"power", {"LightControl", "TVControl"}},
      {"intensity", {"LightControl"}},
      {"channel", {"TVControl"}},
      {"volume", {"TVControl", "AudioControl"}},
      {"play", {"AudioControl"}},
      {"stop", {"AudioControl"}},
      {"say", {"AudioControl"}},
  };
  return table;
}

std::string trim(std::string_view s) {
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front())) != 0) s.remove_prefix(1);
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back())) != 0) s.remove_suffix(1);
  return std::string(s);
}

std::string lower(std::string_view s) {
  std::string out(s);
  for (auto& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

bool is_word_char(char c) { return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '_' || c == '\''; }

// The pattern as a regular expression; `names` gets one entry per capture group.
std::string compile(std::string_view pattern, std::vector<std::string>& names, const std::string& where) {
  std::string re = "(?:^|[^a-z0-9_'])";
  bool need_space = false;
  std::size_t i = 0;
  const auto word_gap = [&] {
    if (need_space) re += "\\s+";
    need_space = true;
  };
  while (i < pattern.size()) {
    const char c = pattern[i];
    if (std::isspace(static_cast<unsigned char>(c)) != 0) {
      ++i;
      continue;
    }
    if (c == '(') {
      const auto close = pattern.find(')', i);
      if (close == std::string_view::npos) throw CommandTableError(where + ": '(' without ')', expected (word|word)");
      std::string group;
      std::size_t start = i + 1;
      for (std::size_t j = start; j <= close; ++j) {
        if (j == close || pattern[j] == '|') {
          const auto word = lower(trim(pattern.substr(start, j - start)));
          if (word.empty() || !std::all_of(word.begin(), word.end(), [](char w) { return is_word_char(w) || w == ' '; })) {
            throw CommandTableError(where + ": an empty or non-word alternative in (" +
                                    std::string(pattern.substr(i + 1, close - i - 1)) + "), expected (word|word)");
          }
          std::string alternative;
          for (const char w : word) alternative += w == ' ' ? std::string("\\s+") : std::string(1, w);
          group += (group.empty() ? "" : "|") + alternative;
          start = j + 1;
        }
      }
      word_gap();
      re += "(" + group + ")";
      names.emplace_back();
      i = close + 1;
    } else if (c == '{') {
      const auto close = pattern.find('}', i);
      if (close == std::string_view::npos) throw CommandTableError(where + ": '{' without '}', expected {n} or {w}");
      const auto name = std::string(pattern.substr(i + 1, close - i - 1));
      word_gap();
      if (name == "n") {
        re += "(\\d+)";
      } else if (name == "w") {
        re += "([a-z0-9_']+)";
      } else {
        throw CommandTableError(where + ": unknown capture {" + name + "}, expected {n} (a number) or {w} (a word)");
      }
      names.push_back(name);
      i = close + 1;
    } else if (is_word_char(c)) {
      std::size_t end = i;
      while (end < pattern.size() && is_word_char(pattern[end])) ++end;
      word_gap();
      re += lower(pattern.substr(i, end - i));
      i = end;
    } else {
      throw CommandTableError(where + fmt::format(": unexpected '{}' in the pattern, expected words, (a|b), {{n}} or {{w}}", c));
    }
  }
  if (!need_space) throw CommandTableError(where + ": an empty pattern, expected the words to listen for");
  return re + "(?:$|[^a-z0-9_'])";
}

CommandEntry parse_entry(std::string_view line, std::size_t number) {
  const std::string where = fmt::format("entry {} (`{}`)", number, trim(line));
  const auto arrow = line.find("=>");
  if (arrow == std::string_view::npos) throw CommandTableError(where + ": no '=>', expected PATTERN => TARGET.ACTION(ARGUMENT)");
  CommandEntry e;
  e.pattern = trim(line.substr(0, arrow));
  const auto call = trim(line.substr(arrow + 2));
  const auto open = call.find('(');
  const auto dot = call.rfind('.', open);
  if (open == std::string::npos || call.back() != ')' || dot == std::string::npos || dot == 0) {
    throw CommandTableError(where + ": '" + call + "' is not TARGET.ACTION(ARGUMENT), e.g. study_light.power(on)");
  }
  e.target = trim(std::string_view(call).substr(0, dot));
  e.action = trim(std::string_view(call).substr(dot + 1, open - dot - 1));
  e.argument = trim(std::string_view(call).substr(open + 1, call.size() - open - 2));
  const auto known = actions().find(e.action);
  if (known == actions().end()) {
    throw CommandTableError(where + ": unknown action '" + e.action + "', expected power, intensity, channel, volume, play, stop or say");
  }
  if (!e.targets_device()) {
    const auto type = e.service_type();
    if (std::find(known->second.begin(), known->second.end(), type) == known->second.end()) {
      std::string types;
      for (const auto t : known->second) types += (types.empty() ? "" : " or ") + std::string(t);
      throw CommandTableError(where + fmt::format(": {} cannot {}, expected {}", type, e.action, types));
    }
    if (e.room().empty() && e.target.substr(e.target.find('@') + 1) != "*") {
      throw CommandTableError(where + ": '" + e.target + "' names no room, expected Type@room or Type@*");
    }
  }
  const bool needs_argument = e.action != "stop";
  if (needs_argument == e.argument.empty()) {
    throw CommandTableError(where + (needs_argument ? ": " + e.action + "() needs an argument" : ": stop() takes no argument"));
  }
  const auto regex = compile(e.pattern, e.capture_names, where);
  e.matcher = std::regex(regex, std::regex::ECMAScript | std::regex::icase);
  // Every placeholder of the argument is a capture of the pattern.
  for (std::size_t i = e.argument.find('{'); i != std::string::npos; i = e.argument.find('{', i + 1)) {
    const auto close = e.argument.find('}', i);
    if (close == std::string::npos) throw CommandTableError(where + ": '{' without '}' in the argument");
    const auto name = e.argument.substr(i + 1, close - i - 1);
    const bool numbered = !name.empty() && std::all_of(name.begin(), name.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)) != 0; });
    const bool exists = numbered ? std::stoul(name) >= 1 && std::stoul(name) <= e.capture_names.size()
                                 : std::find(e.capture_names.begin(), e.capture_names.end(), name) != e.capture_names.end();
    if (!exists) throw CommandTableError(where + ": the argument uses {" + name + "}, which the pattern does not capture");
  }
  return e;
}

}  // namespace

std::string CommandEntry::service_type() const {
  const auto at = target.find('@');
  return at == std::string::npos ? "" : target.substr(0, at);
}

std::string CommandEntry::room() const {
  const auto at = target.find('@');
  if (at == std::string::npos) return "";
  const auto r = target.substr(at + 1);
  return r == "*" ? "" : r;
}

CommandTable CommandTable::parse(std::string_view text) {
  CommandTable table;
  std::size_t number = 0;
  std::size_t start = 0;
  while (start <= text.size()) {
    auto end = text.find_first_of("\n;", start);
    if (end == std::string_view::npos) end = text.size();
    const auto line = trim(text.substr(start, end - start));
    start = end + 1;
    if (line.empty() || line.front() == '#') continue;
    table.entries_.push_back(parse_entry(line, ++number));
  }
  if (table.entries_.empty()) throw CommandTableError("the table has no entry, expected PATTERN => TARGET.ACTION(ARGUMENT)");
  return table;
}

std::optional<CommandTable::Match> CommandTable::match(std::string_view utterance) const {
  const std::string said = lower(utterance);
  for (const auto& e : entries_) {
    std::smatch m;
    if (!std::regex_search(said, m, e.matcher)) continue;
    Match out{&e, {}};
    for (std::size_t i = 0; i < e.argument.size(); ++i) {
      if (e.argument[i] != '{') {
        out.argument += e.argument[i];
        continue;
      }
      const auto close = e.argument.find('}', i);
      const auto name = e.argument.substr(i + 1, close - i - 1);
      std::size_t group = 0;
      if (std::isdigit(static_cast<unsigned char>(name.front())) != 0) {
        group = std::stoul(name);
      } else {
        group = static_cast<std::size_t>(std::find(e.capture_names.begin(), e.capture_names.end(), name) - e.capture_names.begin()) + 1;
      }
      out.argument += m[group].str();
      i = close;
    }
    return out;
  }
  return std::nullopt;
}

std::vector<std::string_view> services_of_action(std::string_view action) {
  const auto it = actions().find(action);
  return it == actions().end() ? std::vector<std::string_view>{} : it->second;
}

std::vector<std::string> CommandTable::phrases(int max_number) const {
  std::set<std::string> all;
  for (const auto& e : entries_) {
    std::vector<std::string> expanded{""};
    bool speakable = true;
    const auto append = [&](const std::vector<std::string>& choices) {
      std::vector<std::string> next;
      for (const auto& head : expanded) {
        for (const auto& c : choices) next.push_back(head.empty() ? c : head + " " + c);
      }
      expanded = std::move(next);
    };
    const std::string_view pattern = e.pattern;
    std::size_t i = 0;
    while (i < pattern.size() && speakable) {
      const char c = pattern[i];
      if (std::isspace(static_cast<unsigned char>(c)) != 0) {
        ++i;
      } else if (c == '(') {
        const auto close = pattern.find(')', i);
        std::vector<std::string> choices;
        std::size_t start = i + 1;
        for (std::size_t j = start; j <= close; ++j) {
          if (j == close || pattern[j] == '|') {
            choices.push_back(lower(trim(pattern.substr(start, j - start))));
            start = j + 1;
          }
        }
        append(choices);
        i = close + 1;
      } else if (c == '{') {
        const auto close = pattern.find('}', i);
        if (pattern.substr(i + 1, close - i - 1) != "n") speakable = false;  // {w}: any word
        std::vector<std::string> numbers;
        for (int n = 0; n <= max_number; ++n) numbers.push_back(std::to_string(n));
        append(numbers);
        i = close + 1;
      } else {
        std::size_t end = i;
        while (end < pattern.size() && is_word_char(pattern[end])) ++end;
        append({lower(pattern.substr(i, end - i))});
        i = end;
      }
    }
    if (speakable) all.insert(expanded.begin(), expanded.end());
  }
  return {all.begin(), all.end()};
}

}  // namespace icars::home
