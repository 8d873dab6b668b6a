// A voice-command table: what a person says, mapped to what the house's devices do, written in
// a policy instead of in C++ (the VoiceCommands behavior runs one). One entry per line:
//
//   PATTERN => TARGET.ACTION(ARGUMENT)
//
//   PATTERN   words said, matched case-insensitively anywhere in the utterance, on word
//             boundaries: `lights on`; `(up|down)` one of several words; `{n}` a number;
//             `{w}` one word. Captures are numbered from 1 in order ({1}, {2}), and a named
//             capture is also its name ({n}).
//   TARGET    a device id (`study_light`), or a service type in a room (`LightControl@study`)
//             or in any room (`LightControl@*`): every available one.
//   ACTION    power(on|off)               LightControl, TVControl
//             intensity(0..100)           LightControl (on at that percentage)
//             channel(N)                  TVControl
//             volume(N | +N | -N | up | down)   TVControl, AudioControl (up/down: by `step`)
//             play(TRACK), stop(), say(TEXT)    AudioControl
//   ARGUMENT  text with {1}, {n} replaced by what was said.
//
// Blank lines and lines starting with '#' are ignored; ';' also ends an entry. The first
// entry that matches is the one that runs.
#pragma once

#include <cstddef>
#include <optional>
#include <regex>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace icars::home {

class CommandTableError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct CommandEntry {
  std::string pattern;   // as written
  std::string target;    // a device id, or "Type@room" / "Type@*"
  std::string action;    // power, intensity, channel, volume, play, stop, say
  std::string argument;  // with placeholders
  std::regex matcher;
  std::vector<std::string> capture_names;  // per capture group, "" when unnamed

  bool targets_device() const { return target.find('@') == std::string::npos; }
  std::string service_type() const;  // "" for a device target
  std::string room() const;          // "" for a device target or "@*"
};

class CommandTable {
 public:
  // Throws CommandTableError "entry N (`text`): problem, expected ...".
  static CommandTable parse(std::string_view text);

  struct Match {
    const CommandEntry* entry = nullptr;
    std::string argument;  // placeholders replaced
  };
  // The first entry whose pattern occurs in `utterance`.
  std::optional<Match> match(std::string_view utterance) const;

  const std::vector<CommandEntry>& entries() const { return entries_; }

  // Every phrase the table acts on, for a speech recognizer's vocabulary: each pattern with its
  // alternatives expanded and {n} as 0..max_number. An entry with a {w} (any word) cannot be
  // listed and is left out: it matches only what a recognizer of free speech produced.
  std::vector<std::string> phrases(int max_number = 100) const;

 private:
  std::vector<CommandEntry> entries_;
};

// The service types an action applies to ("power" -> LightControl, TVControl).
std::vector<std::string_view> services_of_action(std::string_view action);

}  // namespace icars::home
