// planet-idl events reference: the Markdown page of the events IDL files declare, as a
// collaboration policy's conditions see them (docs/events.md is written with it, so it cannot
// drift from idl/*.idl).
//
// For every `event` of the given main files, in file then source order: its name as a policy
// writes it (without modules: `SpeechEvent`), its qualified name and file, the comment lines
// right above it, the listener operations that deliver it and the operations declared to take
// those listeners, and a table of its fields: name, IDL type, what a condition reads
// (include/icars/behavior/condition.h) and the comment after the field on its line (with the
// comment-only lines that continue it in the same column). The output depends only on the
// ASTs and the paths as given, so unchanged input gives identical bytes.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "ast.h"

namespace icars::planet::idl {

// What a condition sees of a property of this type: "bool"; "number" for byte, short, int,
// long, float and double; "string"; "absent" for every other type (binary, stream, sequences,
// enums, valued types).
std::string_view condition_type(const Type& type);

// `files`: the main file of each program to document, as parsed; includes only lend their
// interfaces to the "delivered by" lines (their own events are not listed unless they are in
// `files` too).
std::string generate_events_doc(const std::vector<const SourceFile*>& files);

}  // namespace icars::planet::idl
