#include "ast.h"

#include <fmt/format.h>

#include <algorithm>

namespace icars::planet::idl {

std::string_view idl_name(Builtin type) {
  switch (type) {
    case Builtin::void_type:
      return "void";
    case Builtin::boolean:
      return "bool";
    case Builtin::byte:
      return "byte";
    case Builtin::short_int:
      return "short";
    case Builtin::int32:
      return "int";
    case Builtin::int64:
      return "long";
    case Builtin::float32:
      return "float";
    case Builtin::float64:
      return "double";
    case Builtin::string:
      return "string";
    case Builtin::binary:
      return "binary";
    case Builtin::stream:
      return "stream";
  }
  return "?";
}

std::string_view idl_name(DefinitionKind kind) {
  switch (kind) {
    case DefinitionKind::module:
      return "module";
    case DefinitionKind::enumeration:
      return "enum";
    case DefinitionKind::valued:
      return "valued";
    case DefinitionKind::event:
      return "event";
    case DefinitionKind::exception:
      return "exception";
    case DefinitionKind::interface:
      return "interface";
  }
  return "?";
}

bool Type::is_named(DefinitionKind k) const {
  return kind == Kind::named && definition != nullptr && definition->kind == k;
}

const Interface& Type::interface() const { return static_cast<const Interface&>(*definition); }

std::string Type::to_idl() const {
  switch (kind) {
    case Kind::builtin:
      return std::string(idl_name(builtin));
    case Kind::sequence:
      return fmt::format("sequence<{}>", element->to_idl());
    case Kind::named:
      return definition->qualified_name;
  }
  return "?";
}

namespace {
void collect(const Interface& i, std::vector<const Interface*>& seen,
             std::vector<Interface::Member>& out) {
  if (std::find(seen.begin(), seen.end(), &i) != seen.end()) return;
  seen.push_back(&i);
  for (const Interface* base : i.bases) collect(*base, seen, out);
  for (const Operation& op : i.operations) out.push_back({&i, &op});
}
}  // namespace

std::vector<Interface::Member> Interface::all_operations() const {
  std::vector<const Interface*> seen;
  std::vector<Member> out;
  collect(*this, seen, out);
  return out;
}

}  // namespace icars::planet::idl
