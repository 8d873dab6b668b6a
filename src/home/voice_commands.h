// The VoiceCommands behavior (a command table in the policy, icars/home/command_table.h);
// registered by register_behaviors.
#pragma once

#include "icars/behavior/registry.h"

namespace icars::home {

void register_voice_commands(behavior::BehaviorRegistry& registry);

}  // namespace icars::home
