// planet-idl abstract syntax tree: the checked form of IDL files the generator works from.
//
// The parser builds one SourceFile per IDL file; names in it are already resolved (a named
// Type points at its Definition), so the generator never looks anything up. Definitions are
// owned by the module block that contains them; a file's top level is its `root` module, whose
// name is empty. Modules may be reopened, also across files: each `module a { ... }` block is a
// node of its own, while the symbol table knows `a` once.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "diagnostic.h"

namespace icars::planet::idl {

enum class Builtin : std::uint8_t {
  void_type,
  boolean,
  byte,
  short_int,
  int32,
  int64,
  float32,
  float64,
  string,
  binary,
  stream,
};

std::string_view idl_name(Builtin type);  // "void", "bool", ...

enum class DefinitionKind : std::uint8_t {
  module,
  enumeration,
  valued,
  event,
  exception,
  interface
};

std::string_view idl_name(DefinitionKind kind);  // "module", "enum", "valued", ...

struct Definition;
struct Interface;

struct Type {
  enum class Kind : std::uint8_t { builtin, sequence, named };

  Kind kind = Kind::builtin;
  Builtin builtin = Builtin::void_type;
  std::shared_ptr<const Type> element;     // the T of sequence<T>
  const Definition* definition = nullptr;  // what a named type refers to
  SourceLocation location;

  bool is_builtin(Builtin b) const { return kind == Kind::builtin && builtin == b; }
  bool is_void() const { return is_builtin(Builtin::void_type); }
  bool is_stream() const { return is_builtin(Builtin::stream); }
  bool is_named(DefinitionKind k) const;
  bool is_interface() const { return is_named(DefinitionKind::interface); }
  const Interface& interface() const;  // requires is_interface()
  std::string to_idl() const;          // "sequence<home::Pose>"
};

struct Definition {
  Definition(DefinitionKind k, std::string n, std::string qualified, SourceLocation where)
      : kind(k), name(std::move(n)), qualified_name(std::move(qualified)), location(where) {}
  virtual ~Definition() = default;
  Definition(const Definition&) = delete;
  Definition& operator=(const Definition&) = delete;

  DefinitionKind kind;
  std::string name;
  std::string qualified_name;  // "a::b::Name", the PLANET type id
  SourceLocation location;
};

struct Module : Definition {
  Module(std::string n, std::string qualified, SourceLocation where)
      : Definition(DefinitionKind::module, std::move(n), std::move(qualified), where) {}
  std::vector<std::unique_ptr<Definition>> definitions;  // in source order
};

struct Enumerator {
  std::string name;
  std::int32_t value = 0;
  SourceLocation location;
};

struct Enum : Definition {
  Enum(std::string n, std::string qualified, SourceLocation where)
      : Definition(DefinitionKind::enumeration, std::move(n), std::move(qualified), where) {}
  std::vector<Enumerator> enumerators;  // at least one
};

struct Field {
  std::string name;
  Type type;
  SourceLocation location;
};

// A valued, an event or an exception: a named list of typed fields.
struct Struct : Definition {
  using Definition::Definition;
  std::vector<Field> fields;
};

struct Parameter {
  std::string name;
  Type type;
  SourceLocation location;
};

struct Operation {
  std::string name;
  Type result;
  std::vector<Parameter> parameters;
  std::vector<const Struct*> raises;  // exceptions, in the order written
  bool oneway = false;
  // May be sent again after a lost connection (planet::CallMode::idempotent); never oneway.
  bool idempotent = false;
  SourceLocation location;
};

struct Interface : Definition {
  Interface(std::string n, std::string qualified, SourceLocation where)
      : Definition(DefinitionKind::interface, std::move(n), std::move(qualified), where) {}
  std::vector<const Interface*> bases;  // as written after ':'
  std::vector<Operation> operations;    // declared here, in source order

  // An operation together with the interface that declares it.
  struct Member {
    const Interface* owner;
    const Operation* operation;
  };
  // Inherited operations first (each base once, depth first), then this interface's own.
  std::vector<Member> all_operations() const;
};

struct SourceFile;

struct Include {
  std::string written;  // as in the include directive
  const SourceFile* file = nullptr;
  SourceLocation location;
};

struct SourceFile {
  SourceFile(std::string p, std::string t) : path(std::move(p)), text(std::move(t)) {}
  SourceFile(const SourceFile&) = delete;
  SourceFile& operator=(const SourceFile&) = delete;

  std::string path;  // as given on the command line or resolved for an include
  std::string text;
  std::vector<Include> includes;
  Module root{"", "", SourceLocation{}};
};

}  // namespace icars::planet::idl
