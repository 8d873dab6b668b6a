// VoiceCommands: every SpeechEvent of the house's speech sensors is looked up in the policy's
// command table; the first entry that matches runs its action on every available service of
// its target, and a VoiceCommand event says what was done.
#include "voice_commands.h"

#include <fmt/format.h>

#include <algorithm>
#include <charconv>

#include "icars/home/adaptors.h"
#include "icars/home/command_table.h"
#include "icars/home/services.h"
#include "speech_listener.h"

namespace icars::home {

namespace s = icars::service;
using namespace icars::behavior;

namespace {

std::optional<bool> on_off(std::string_view v) {
  if (v == "on" || v == "true" || v == "yes") return true;
  if (v == "off" || v == "false" || v == "no") return false;
  return std::nullopt;
}

std::optional<int> integer(std::string_view v) {
  int n = 0;
  const auto [end, ec] = std::from_chars(v.data(), v.data() + v.size(), n);
  if (ec != std::errc{} || end != v.data() + v.size()) return std::nullopt;
  return n;
}

class VoiceCommands final : public SpeechListener {
 public:
  explicit VoiceCommands(const Params& p)
      : table_(CommandTable::parse(p.string("commands"))), step_(static_cast<int>(p.integer("step"))) {}

 protected:
  void entry() override { listen_for_phrases(table_.phrases()); }

  void handle_event(const Event& e) override {
    if (e.type() != "SpeechEvent") return;
    const auto text = e.get<std::string>("text");
    const auto match = table_.match(text);
    if (!match) return;
    const auto& entry = *match->entry;
    std::vector<std::shared_ptr<s::Service>> targets;
    if (entry.targets_device()) {
      auto on_device = services().find(s::ServiceQuery{}.on_device(entry.target).available());
      const auto types = services_of_action(entry.action);
      for (auto& service : on_device) {
        if (std::find(types.begin(), types.end(), service->type()) != types.end()) targets.push_back(service);
      }
    } else {
      auto query = of_type(entry.service_type());
      if (!entry.room().empty()) query.in_room(entry.room());
      targets = services().find(query.available());
    }
    if (targets.empty()) {
      note(fmt::format("\"{}\": no available service of {} can {}", text, entry.target, entry.action));
      return;
    }
    for (const auto& target : targets) run(*target, entry.action, match->argument);
    Event done("VoiceCommand");
    done.set("text", text);
    done.set("target", entry.target);
    done.set("action", entry.action);
    done.set("argument", match->argument);
    propagate(std::move(done));
  }

 private:
  void run(s::Service& target, const std::string& action, const std::string& argument) {
    auto report = [this](std::exception_ptr e, auto&&...) {
      if (e) note("a voice command failed: " + describe(e));
    };
    const auto bad = [&](std::string_view expected) {
      note(fmt::format("{}({}): '{}' is not {}", action, argument, argument, expected));
    };
    if (auto* light = dynamic_cast<LightService*>(&target)) {
      if (action == "power") {
        const auto on = on_off(argument);
        if (!on) return bad("on or off");
        invoke(*light, fmt::format("set_power({})", *on), [&](auto done) { light->proxy().set_power_async(*on, done); }, report);
      } else if (action == "intensity") {
        const auto n = integer(argument);
        if (!n || *n < 0 || *n > 100) return bad("a percentage 0-100");
        invoke(*light, fmt::format("set_intensity({})", *n), [&](auto done) { light->proxy().set_intensity_async(*n, done); }, report);
        invoke(*light, fmt::format("set_power({})", *n > 0), [&](auto done) { light->proxy().set_power_async(*n > 0, done); }, report);
      }
    } else if (auto* tv = dynamic_cast<TVControlService*>(&target)) {
      if (action == "power") {
        const auto on = on_off(argument);
        if (!on) return bad("on or off");
        invoke(*tv, fmt::format("set_power({})", *on), [&](auto done) { tv->proxy().set_power_async(*on, done); }, report);
      } else if (action == "channel") {
        const auto n = integer(argument);
        if (!n) return bad("a channel number");
        invoke(*tv, fmt::format("set_channel({})", *n), [&](auto done) { tv->proxy().set_channel_async(*n, done); }, report);
      } else if (action == "volume") {
        volume<TVState>(*tv, argument, [](TVControlService& t, auto done) { t.proxy().state_async(done); },
               [](TVControlService& t, int v, auto done) { t.proxy().set_volume_async(v, done); });
      }
    } else if (auto* speaker = dynamic_cast<SpeakerService*>(&target)) {
      if (action == "play") {
        invoke(*speaker, fmt::format("play({})", argument), [&](auto done) { speaker->proxy().play_async(argument, done); }, report);
      } else if (action == "stop") {
        invoke(*speaker, "stop", [&](auto done) { speaker->proxy().stop_async(done); }, report);
      } else if (action == "say") {
        invoke(*speaker, fmt::format("speak({})", argument), [&](auto done) { speaker->proxy().speak_async(argument, done); }, report);
      } else if (action == "volume") {
        volume<SpeakerState>(*speaker, argument, [](SpeakerService& t, auto done) { t.proxy().state_async(done); },
               [](SpeakerService& t, int v, auto done) { t.proxy().set_volume_async(v, done); });
      }
    }
  }

  // volume(N) sets it; +N, -N, up and down change it from the device's own state.
  template <class State, class S, class Read, class Write>
  void volume(S& target, const std::string& argument, Read read, Write write) {
    auto report = [this](std::exception_ptr e, auto&&...) {
      if (e) note("a voice command failed: " + describe(e));
    };
    int delta = 0;
    if (argument == "up") {
      delta = step_;
    } else if (argument == "down") {
      delta = -step_;
    } else if (!argument.empty() && (argument.front() == '+' || argument.front() == '-')) {
      const auto n = integer(std::string_view(argument).substr(1));
      if (!n) return note(fmt::format("volume({}): expected N, +N, -N, up or down", argument));
      delta = argument.front() == '+' ? *n : -*n;
    } else {
      const auto n = integer(argument);
      if (!n) return note(fmt::format("volume({}): expected N, +N, -N, up or down", argument));
      const int level = std::clamp(*n, 0, 100);
      invoke(target, fmt::format("set_volume({})", level), [&](auto done) { write(target, level, done); }, report);
      return;
    }
    auto shared = std::static_pointer_cast<S>(target.shared_from_this());
    invoke(target, "state", [&](auto done) { read(target, done); },
           [this, shared, delta, write, report](std::exception_ptr e, State state = {}) {
             if (e) return;
             const int level = std::clamp(state.volume + delta, 0, 100);
             invoke(*shared, fmt::format("set_volume({})", level), [&](auto done) { write(*shared, level, done); }, report);
           });
  }

  CommandTable table_;
  int step_;
};

}  // namespace

void register_voice_commands(BehaviorRegistry& registry) {
  using T = ParamType;
  registry.add<VoiceCommands>(
      "VoiceCommands", "runs a command table: what is said -> what the devices do (docs/policy.md, VoiceCommands)",
      {param("commands", T::string, std::nullopt, "the table, one `PATTERN => TARGET.ACTION(ARGUMENT)` per line")
           .checked_by([](std::string_view table) {
             try {
               (void)CommandTable::parse(table);
             } catch (const CommandTableError& e) {
               throw ParamError(std::string("parameter 'commands': ") + e.what());
             }
           })
           .naming_in([](std::string_view table) {
             std::vector<std::pair<std::string, std::string>> names;
             try {
               const auto parsed = CommandTable::parse(table);
               for (const auto& e : parsed.entries()) {
                 if (e.targets_device()) names.emplace_back("device", e.target);
                 if (!e.room().empty()) names.emplace_back("room", e.room());
               }
             } catch (const CommandTableError&) {  // reported by the check
             }
             return names;
           }),
       param("step", T::integer, "5", "how much volume(up) and volume(down) change the volume")});
  registry.declare_events("VoiceCommands", {{"VoiceCommand", {"text", "target", "action", "argument"}}});
}

}  // namespace icars::home
