#include "parser.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>
#include <system_error>

#include "lexer.h"

namespace icars::planet::idl {

namespace {

namespace fs = std::filesystem;

constexpr std::array<std::string_view, 92> kCppKeywords = {
    "alignas",       "alignof",     "and",
    "and_eq",        "asm",         "auto",
    "bitand",        "bitor",       "bool",
    "break",         "case",        "catch",
    "char",          "char8_t",     "char16_t",
    "char32_t",      "class",       "compl",
    "concept",       "const",       "consteval",
    "constexpr",     "constinit",   "const_cast",
    "continue",      "co_await",    "co_return",
    "co_yield",      "decltype",    "default",
    "delete",        "do",          "double",
    "dynamic_cast",  "else",        "enum",
    "explicit",      "export",      "extern",
    "false",         "float",       "for",
    "friend",        "goto",        "if",
    "inline",        "int",         "long",
    "mutable",       "namespace",   "new",
    "noexcept",      "not",         "not_eq",
    "nullptr",       "operator",    "or",
    "or_eq",         "private",     "protected",
    "public",        "register",    "reinterpret_cast",
    "requires",      "return",      "short",
    "signed",        "sizeof",      "static",
    "static_assert", "static_cast", "struct",
    "switch",        "template",    "this",
    "thread_local",  "throw",       "true",
    "try",           "typedef",     "typeid",
    "typename",      "union",       "unsigned",
    "using",         "virtual",     "void",
    "volatile",      "wchar_t",     "while",
    "xor",           "xor_eq",
};
// Names the generated code relies on at namespace scope.
constexpr std::array<std::string_view, 3> kReservedNames = {"std", "icars", "asio"};
// Members of the generated proxy and servant (and their bases) an operation must not hide.
constexpr std::array<std::string_view, 18> kReservedOperationNames = {
    "call",      "async_call", "notify",  "ref",          "communicator", "link",
    "path",      "object",     "timeout", "with_timeout", "set_timeout",  "bound",
    "implement", "dispatch",   "type_id", "has_method",   "bind_result",  "async_call_bound"};
// Parameters the generated methods add after the operation's own.
constexpr std::array<std::string_view, 2> kReservedParameterNames = {"current", "token"};
// Members of RemoteException and the generated exception constructor.
constexpr std::array<std::string_view, 7> kReservedExceptionFields = {
    "message", "type_id", "what", "kind", "properties", "remote_message", "static_type_id"};

template <class Array>
bool contains(const Array& words, std::string_view word) {
  return std::find(words.begin(), words.end(), word) != words.end();
}

bool has_reserved_underscores(std::string_view name) {
  return name.front() == '_' || name.back() == '_' || name.find("__") != std::string_view::npos;
}

std::string join_scope(const std::vector<std::string>& scope, std::size_t count,
                       std::string_view name) {
  std::string out;
  for (std::size_t i = 0; i < count; ++i) out += scope[i] + "::";
  return out + std::string(name);
}

class SymbolTable {
 public:
  const Definition* find(std::string_view qualified) const {
    const auto it = by_name_.find(qualified);
    return it == by_name_.end() ? nullptr : it->second;
  }
  // C++-like lookup: `name` inside the innermost module first, then outwards.
  const Definition* lookup(const std::vector<std::string>& scope, std::string_view name,
                           bool absolute) const {
    if (absolute) return find(name);
    for (std::size_t n = scope.size() + 1; n-- > 0;) {
      if (const Definition* d = find(join_scope(scope, n, name))) return d;
    }
    return nullptr;
  }
  void add(const Definition& d) { by_name_.emplace(d.qualified_name, &d); }

 private:
  std::map<std::string, const Definition*, std::less<>> by_name_;
};

struct ScopedName {
  std::string text;  // "a::b::X" without a leading "::"
  bool absolute = false;
  SourceLocation location;
};

enum class Use : std::uint8_t { result, parameter, field, element };

std::string_view use_name(Use use) {
  switch (use) {
    case Use::result:
      return "a result type";
    case Use::parameter:
      return "a parameter type";
    case Use::field:
      return "the type of a field";
    case Use::element:
      return "a sequence element";
  }
  return "used here";
}

constexpr std::string_view kDataTypes =
    "a data type (bool, byte, short, int, long, float, double, string, binary, a sequence, an "
    "enum, a valued or an event)";

class Loader;

// Parses the tokens of one file into its SourceFile, resolving names through the shared
// symbol table and loading includes through the Loader.
class FileParser {
 public:
  FileParser(SourceFile& file, Loader& loader, SymbolTable& symbols)
      : file_(file), tokens_(tokenize(file.path, file.text)), loader_(loader), symbols_(symbols) {}

  void parse() {
    while (peek().is_keyword("include")) parse_include();
    while (!peek().is(TokenKind::end_of_file)) parse_definition(file_.root);
  }

 private:
  // --- Token helpers ---
  const Token& peek() const { return tokens_[pos_]; }
  const Token& advance() {
    const Token& t = tokens_[pos_];
    if (!t.is(TokenKind::end_of_file)) ++pos_;
    return t;
  }
  bool accept(TokenKind kind) {
    if (!peek().is(kind)) return false;
    advance();
    return true;
  }
  bool accept_keyword(std::string_view word) {
    if (!peek().is_keyword(word)) return false;
    advance();
    return true;
  }
  const Token& expect(TokenKind kind, std::string_view expected) {
    if (!peek().is(kind)) unexpected(peek(), expected);
    return advance();
  }
  [[noreturn]] static void unexpected(const Token& t, std::string_view expected) {
    throw CompileError(t.location, fmt::format("unexpected {}", describe(t)),
                       std::string(expected));
  }
  void fail_if_unclosed(std::string_view what, const Definition& d) const {
    if (!peek().is(TokenKind::end_of_file)) return;
    throw CompileError(
        peek().location, "unexpected end of file",
        fmt::format("'}}' to close {} '{}' opened at {}", what, d.name, d.location.to_string()));
  }

  // --- Names ---
  std::string qualify(std::string_view name) const {
    return join_scope(scope_, scope_.size(), name);
  }
  // `icars` may name an outermost module (ICARS's own IDL nests its modules in it, so that the
  // generated code is in namespace icars) and so begin a scoped name; nowhere else.
  static void check_name(const Token& t, std::string_view role, bool may_be_icars = false) {
    if (t.is(TokenKind::keyword)) {
      throw CompileError(t.location, quote(t.text) + " is a keyword of the IDL", std::string(role));
    }
    if (!t.is(TokenKind::identifier)) unexpected(t, role);
    if (contains(kCppKeywords, t.text)) {
      throw CompileError(t.location, quote(t.text) + " is a C++ keyword",
                         std::string(role) + " that is not a C++ keyword");
    }
    if (contains(kReservedNames, t.text) && !(may_be_icars && t.text == "icars")) {
      throw CompileError(t.location, quote(t.text) + " is reserved for the C++ mapping",
                         std::string(role) + " other than std, icars and asio");
    }
    if (has_reserved_underscores(t.text)) {
      throw CompileError(t.location, quote(t.text) + " starts or ends with '_' or contains '__'",
                         std::string(role) + " without them (C++ and the generated code use them)");
    }
  }
  std::string take_name(std::string_view role, bool may_be_icars = false) {
    check_name(peek(), role, may_be_icars);
    return std::string(advance().text);
  }
  ScopedName parse_scoped_name(std::string_view role) {
    ScopedName name;
    name.location = peek().location;
    name.absolute = accept(TokenKind::scope);
    name.text = take_name(role, /*may_be_icars=*/true);  // the outermost module, if any
    while (accept(TokenKind::scope)) {
      name.text += "::";
      name.text += take_name(role);
    }
    return name;
  }
  // The definition `name` names, which must be of `kind` (an interface or an exception, hence
  // "an"); otherwise an error naming what it is instead.
  const Definition& lookup_as(const ScopedName& name, DefinitionKind kind,
                              std::string_view what) const {
    const Definition* d = lookup(name);
    if (d == nullptr || d->kind != kind) {
      throw CompileError(
          name.location,
          d == nullptr
              ? fmt::format("unknown {} '{}'", what, name.text)
              : fmt::format("'{}' is {} {}, not an {}", name.text,
                            d->kind == DefinitionKind::enumeration ? "an" : "a", idl_name(d->kind),
                            what),
          fmt::format("the name of an {} defined before this point", what));
    }
    return *d;
  }
  const Definition* lookup(const ScopedName& name) const {
    return symbols_.lookup(scope_, name.text, name.absolute);
  }

  void check_new_definition(const Token& name_token, DefinitionKind kind) const;
  void check_generated_names(const Token& name_token, DefinitionKind kind) const;
  template <class D>
  D& add(Module& parent, std::unique_ptr<D> definition) {
    D& d = *definition;
    symbols_.add(d);
    parent.definitions.push_back(std::move(definition));
    return d;
  }

  // --- Grammar ---
  void parse_include();
  void parse_definition(Module& parent);
  void parse_module(Module& parent);
  void parse_enum(Module& parent);
  Enumerator parse_enumerator(const Enum& e, std::int64_t implicit_value);
  std::int64_t parse_enum_value();
  void parse_struct(Module& parent, DefinitionKind kind);
  Field parse_field(const Struct& s);
  void parse_interface(Module& parent);
  void parse_bases(Interface& i);
  void parse_operation(Interface& i);
  void check_operation_name(const Interface& i, const Token& name_token) const;
  Parameter parse_parameter(const Operation& op);
  void parse_raises(Operation& op);
  Type parse_type(std::size_t depth);
  Type parse_sequence(std::size_t depth);
  Type parse_named_type();
  static void check_use(const Type& type, Use use);

  SourceFile& file_;
  std::vector<Token> tokens_;
  std::size_t pos_ = 0;
  Loader& loader_;
  SymbolTable& symbols_;
  std::vector<std::string> scope_;  // names of the enclosing modules
};

// Reads files, runs a FileParser on each and detects include cycles.
class Loader {
 public:
  Loader(const ParseOptions& options, SourceReader& reader) : options_(options), reader_(reader) {}

  Program run(const fs::path& main) {
    std::optional<std::string> text = reader_.read(main);
    if (!text) {
      const std::string path = main.string();
      throw CompileError(SourceLocation{path, 0, 0}, fmt::format("cannot read {}", quote(path)),
                         "a readable IDL file");
    }
    program_.main = &parse(main.string(), std::move(*text), reader_.identity(main));
    return std::move(program_);
  }

  const SourceFile& include(const Token& name, const SourceFile& from) {
    if (stack_.size() >= kMaxIncludeDepth) {
      throw CompileError(name.location, "includes nested deeper than 32 files",
                         "at most 32 nested includes");
    }
    auto [path, text] = find(name, from);
    std::string id = reader_.identity(path);
    check_cycle(name, id, path);
    if (const auto it = done_.find(id); it != done_.end()) return *it->second;
    return parse(path.string(), std::move(text), std::move(id));
  }

 private:
  struct Open {
    std::string id;
    std::string path;
  };

  const SourceFile& parse(std::string path, std::string text, std::string id) {
    auto file = std::make_unique<SourceFile>(std::move(path), std::move(text));
    stack_.push_back({id, file->path});
    FileParser(*file, *this, symbols_).parse();
    stack_.pop_back();
    done_.emplace(std::move(id), file.get());
    program_.files.push_back(std::move(file));
    return *program_.files.back();
  }

  std::pair<fs::path, std::string> find(const Token& name, const SourceFile& from) const {
    const fs::path written{std::string(name.text)};
    if (written.empty())
      throw CompileError(name.location, "empty include file name", "a file name");
    std::vector<fs::path> candidates;
    if (written.is_absolute()) {
      candidates.push_back(written);
    } else {
      candidates.push_back((fs::path(from.path).parent_path() / written).lexically_normal());
      for (const fs::path& dir : options_.import_dirs) {
        candidates.push_back((dir / written).lexically_normal());
      }
    }
    std::string searched;
    for (const fs::path& candidate : candidates) {
      if (std::optional<std::string> text = reader_.read(candidate)) return {candidate, *text};
      if (!searched.empty()) searched += ", ";
      searched += candidate.string();
    }
    throw CompileError(
        name.location,
        fmt::format("cannot find include file \"{}\" (searched {})", name.text, searched),
        "a file next to the including file or in an import directory (-I)");
  }

  void check_cycle(const Token& name, const std::string& id, const fs::path& path) const {
    const auto open =
        std::find_if(stack_.begin(), stack_.end(), [&](const Open& o) { return o.id == id; });
    if (open == stack_.end()) return;
    std::string chain;
    for (auto it = open; it != stack_.end(); ++it) chain += it->path + " -> ";
    throw CompileError(name.location, "include cycle " + chain + path.string(),
                       "files that do not include each other");
  }

  const ParseOptions& options_;
  SourceReader& reader_;
  SymbolTable symbols_;
  Program program_;
  std::vector<Open> stack_;                        // files being parsed, outermost first
  std::map<std::string, const SourceFile*> done_;  // by identity
};

// --- Definitions -----------------------------------------------------------------------------

void FileParser::parse_include() {
  const Token& keyword = advance();
  const Token& name = expect(TokenKind::string, "a file name in double quotes after 'include'");
  expect(TokenKind::semicolon, "';' after the include");
  const SourceFile& included = loader_.include(name, file_);
  file_.includes.push_back({std::string(name.text), &included, keyword.location});
}

void FileParser::parse_definition(Module& parent) {
  const Token& t = peek();
  if (t.is_keyword("module")) return parse_module(parent);
  if (t.is_keyword("enum")) return parse_enum(parent);
  if (t.is_keyword("valued")) return parse_struct(parent, DefinitionKind::valued);
  if (t.is_keyword("event")) return parse_struct(parent, DefinitionKind::event);
  if (t.is_keyword("exception")) return parse_struct(parent, DefinitionKind::exception);
  if (t.is_keyword("interface")) return parse_interface(parent);
  if (t.is_keyword("include")) {
    throw CompileError(t.location, "include after a definition",
                       "includes only at the top of the file, before any definition");
  }
  unexpected(t, "a definition (module, enum, valued, event, exception or interface)");
}

void FileParser::check_new_definition(const Token& name_token, DefinitionKind kind) const {
  const std::string qualified = qualify(name_token.text);
  if (const Definition* existing = symbols_.find(qualified)) {
    if (kind == DefinitionKind::module && existing->kind == DefinitionKind::module) return;
    throw CompileError(name_token.location,
                       fmt::format("'{}' is already defined as {} at {}", qualified,
                                   idl_name(existing->kind), existing->location.to_string()),
                       "a name not yet used in this module");
  }
  check_generated_names(name_token, kind);
}

// An interface X generates the classes XPrx and XServant beside it.
void FileParser::check_generated_names(const Token& name_token, DefinitionKind kind) const {
  const std::string qualified = qualify(name_token.text);
  for (const std::string_view suffix : {std::string_view("Prx"), std::string_view("Servant")}) {
    if (kind == DefinitionKind::interface) {
      if (const Definition* d = symbols_.find(qualified + std::string(suffix))) {
        throw CompileError(
            name_token.location,
            fmt::format("interface '{}' generates the class '{}{}', already defined "
                        "at {}",
                        name_token.text, name_token.text, suffix, d->location.to_string()),
            "an interface name whose Prx and Servant classes are free");
      }
    }
    if (!qualified.ends_with(suffix)) continue;
    const Definition* d = symbols_.find(qualified.substr(0, qualified.size() - suffix.size()));
    if (d != nullptr && d->kind == DefinitionKind::interface) {
      throw CompileError(name_token.location,
                         fmt::format("'{}' is the name of a class generated for interface '{}'",
                                     name_token.text, d->name),
                         "another name");
    }
  }
}

void FileParser::parse_module(Module& parent) {
  const Token& keyword = advance();
  if (scope_.size() >= kMaxModuleDepth) {
    throw CompileError(keyword.location, "modules nested deeper than 32 levels",
                       "at most 32 nested modules");
  }
  const Token& name_token = peek();
  const std::string name = take_name("a module name", /*may_be_icars=*/scope_.empty());
  check_new_definition(name_token, DefinitionKind::module);
  auto module = std::make_unique<Module>(name, qualify(name), name_token.location);
  Module& m = *module;
  if (symbols_.find(m.qualified_name) == nullptr) symbols_.add(m);
  parent.definitions.push_back(std::move(module));
  expect(TokenKind::left_brace, "'{' after the module name");
  scope_.push_back(name);
  while (!peek().is(TokenKind::right_brace)) {
    fail_if_unclosed("module", m);
    parse_definition(m);
  }
  advance();
  scope_.pop_back();
  accept(TokenKind::semicolon);
}

void FileParser::parse_enum(Module& parent) {
  advance();
  const Token& name_token = peek();
  const std::string name = take_name("an enum name");
  check_new_definition(name_token, DefinitionKind::enumeration);
  auto e = std::make_unique<Enum>(name, qualify(name), name_token.location);
  expect(TokenKind::left_brace, "'{' after the enum name");
  std::int64_t next = 0;
  do {
    if (peek().is(TokenKind::right_brace) && !e->enumerators.empty()) break;  // trailing ','
    e->enumerators.push_back(parse_enumerator(*e, next));
    next = std::int64_t{e->enumerators.back().value} + 1;
  } while (accept(TokenKind::comma));
  expect(TokenKind::right_brace, "',' or '}' after the enumerator");
  expect(TokenKind::semicolon, "';' after the enum");
  add(parent, std::move(e));
}

Enumerator FileParser::parse_enumerator(const Enum& e, std::int64_t implicit_value) {
  const Token& name_token = peek();
  const std::string name = take_name("an enumerator name");
  std::int64_t value = implicit_value;
  if (accept(TokenKind::equals)) value = parse_enum_value();
  if (value > std::numeric_limits<std::int32_t>::max()) {
    throw CompileError(name_token.location,
                       fmt::format("enumerator '{}' would have the value {}, which does not fit "
                                   "in 32 bits",
                                   name, value),
                       "values from -2147483648 to 2147483647");
  }
  for (const Enumerator& other : e.enumerators) {
    if (other.name == name) {
      throw CompileError(name_token.location,
                         fmt::format("enumerator '{}' is already declared at {}", name,
                                     other.location.to_string()),
                         "a name not yet used in enum '" + e.name + "'");
    }
    if (other.value == value) {
      throw CompileError(
          name_token.location,
          fmt::format("enumerator '{}' has the value {} of '{}'", name, value, other.name),
          "distinct values in enum '" + e.name + "'");
    }
  }
  return Enumerator{name, static_cast<std::int32_t>(value), name_token.location};
}

std::int64_t FileParser::parse_enum_value() {
  const bool negative = accept(TokenKind::minus);
  const Token& t = expect(TokenKind::integer, "an integer value after '='");
  constexpr std::uint64_t kLimit = std::uint64_t{1} << 31;
  if (t.value > kLimit || (!negative && t.value == kLimit)) {
    throw CompileError(t.location,
                       fmt::format("enum value {}{} is out of range", negative ? "-" : "", t.text),
                       "values from -2147483648 to 2147483647");
  }
  const auto magnitude = static_cast<std::int64_t>(t.value);
  return negative ? -magnitude : magnitude;
}

void FileParser::parse_struct(Module& parent, DefinitionKind kind) {
  advance();
  const Token& name_token = peek();
  const std::string name = take_name(fmt::format("a name for the {}", idl_name(kind)));
  check_new_definition(name_token, kind);
  auto s = std::make_unique<Struct>(kind, name, qualify(name), name_token.location);
  expect(TokenKind::left_brace, fmt::format("'{{' after the {} name", idl_name(kind)));
  while (!peek().is(TokenKind::right_brace)) {
    fail_if_unclosed(idl_name(kind), *s);
    s->fields.push_back(parse_field(*s));
  }
  if (kind == DefinitionKind::valued && s->fields.empty()) {
    throw CompileError(peek().location, fmt::format("valued '{}' has no fields", name),
                       "at least one field (an empty valued cannot be told apart on the wire)");
  }
  advance();
  expect(TokenKind::semicolon, fmt::format("';' after the {}", idl_name(kind)));
  add(parent, std::move(s));
}

Field FileParser::parse_field(const Struct& s) {
  Type type = parse_type(0);
  check_use(type, Use::field);
  const Token& name_token = peek();
  std::string name = take_name("a field name");
  if (name == s.name) {
    throw CompileError(name_token.location,
                       fmt::format("field '{}' has the name of its {}", name, idl_name(s.kind)),
                       "another field name");
  }
  if (s.kind == DefinitionKind::exception && contains(kReservedExceptionFields, name)) {
    throw CompileError(name_token.location,
                       fmt::format("field name '{}' is used by the exception's C++ class", name),
                       "a name other than message, type_id, static_type_id, what, kind, "
                       "properties and remote_message");
  }
  for (const Field& other : s.fields) {
    if (other.name == name) {
      throw CompileError(
          name_token.location,
          fmt::format("field '{}' is already declared at {}", name, other.location.to_string()),
          fmt::format("a name not yet used in {} '{}'", idl_name(s.kind), s.name));
    }
  }
  expect(TokenKind::semicolon, "';' after the field");
  return Field{std::move(name), std::move(type), name_token.location};
}

// --- Interfaces ------------------------------------------------------------------------------

void FileParser::parse_interface(Module& parent) {
  advance();
  const Token& name_token = peek();
  const std::string name = take_name("an interface name");
  check_new_definition(name_token, DefinitionKind::interface);
  auto owned = std::make_unique<Interface>(name, qualify(name), name_token.location);
  if (accept(TokenKind::colon)) parse_bases(*owned);
  Interface& i = add(parent, std::move(owned));  // operations may name the interface itself
  expect(TokenKind::left_brace, "'{' after the interface name");
  while (!peek().is(TokenKind::right_brace)) {
    fail_if_unclosed("interface", i);
    parse_operation(i);
  }
  advance();
  expect(TokenKind::semicolon, "';' after the interface");
}

void FileParser::parse_bases(Interface& i) {
  do {
    const ScopedName name = parse_scoped_name("the name of a base interface");
    const auto* base =
        static_cast<const Interface*>(&lookup_as(name, DefinitionKind::interface, "interface"));
    if (std::find(i.bases.begin(), i.bases.end(), base) != i.bases.end()) {
      throw CompileError(name.location, fmt::format("'{}' is named twice as a base", name.text),
                         "each base interface once");
    }
    i.bases.push_back(base);
  } while (accept(TokenKind::comma));
  const auto inherited = i.all_operations();
  for (auto a = inherited.begin(); a != inherited.end(); ++a) {
    for (auto b = a + 1; b != inherited.end(); ++b) {
      if (a->operation->name != b->operation->name) continue;
      throw CompileError(i.location,
                         fmt::format("interface '{}' inherits two operations named '{}' (from "
                                     "'{}' and '{}')",
                                     i.name, a->operation->name, a->owner->qualified_name,
                                     b->owner->qualified_name),
                         "base interfaces whose operation names differ");
    }
  }
}

void FileParser::parse_operation(Interface& i) {
  Operation op;
  const Token& first = peek();
  op.idempotent = accept_keyword("idempotent");
  op.oneway = accept_keyword("oneway");
  if (op.oneway && (op.idempotent || peek().is_keyword("idempotent"))) {
    throw CompileError(first.location, "an operation is both 'idempotent' and 'oneway'",
                       "one of them (a oneway call has no reply to wait for, so it is never "
                       "sent again)");
  }
  op.result = parse_type(0);
  check_use(op.result, Use::result);
  const Token& name_token = peek();
  op.name = take_name("an operation name");
  op.location = name_token.location;
  check_operation_name(i, name_token);
  if (op.oneway && !op.result.is_void()) {
    throw CompileError(
        op.result.location,
        fmt::format("oneway operation '{}' returns '{}'", op.name, op.result.to_idl()),
        "'void' (a oneway call has no reply to carry a result)");
  }
  expect(TokenKind::left_paren, "'(' after the operation name");
  if (!accept(TokenKind::right_paren)) {
    do {
      op.parameters.push_back(parse_parameter(op));
    } while (accept(TokenKind::comma));
    expect(TokenKind::right_paren, "',' or ')' after the parameter");
  }
  if (peek().is_keyword("raises")) parse_raises(op);
  expect(TokenKind::semicolon, "';' after the operation");
  i.operations.push_back(std::move(op));
}

void FileParser::check_operation_name(const Interface& i, const Token& name_token) const {
  const std::string name(name_token.text);
  if (contains(kReservedOperationNames, name) || name == i.name || name == i.name + "Prx" ||
      name == i.name + "Servant") {
    throw CompileError(
        name_token.location,
        fmt::format("operation name '{}' is used by the generated C++ classes", name),
        "another name (not call, async_call, notify, ref, communicator, link, "
        "path, object, timeout, with_timeout, set_timeout, bound, implement, "
        "dispatch, type_id, has_method, bind_result, async_call_bound or the "
        "interface's own names)");
  }
  for (const Interface::Member& m : i.all_operations()) {
    const std::string& other = m.operation->name;
    if (other == name) {
      throw CompileError(name_token.location,
                         fmt::format("operation '{}' is already declared at {}", name,
                                     m.operation->location.to_string()),
                         fmt::format("a name not yet used in interface '{}'", i.name));
    }
    if (other + "_async" == name || name + "_async" == other) {
      throw CompileError(name_token.location,
                         fmt::format("operation '{}' clashes with the asynchronous method "
                                     "generated for '{}'",
                                     name, std::min(name, other)),
                         "a name that does not differ from another operation's by '_async'");
    }
  }
}

Parameter FileParser::parse_parameter(const Operation& op) {
  if (op.parameters.size() >= 255) {
    throw CompileError(peek().location,
                       fmt::format("operation '{}' has more than 255 parameters", op.name),
                       "at most 255 parameters (the PLANET argument count is one byte)");
  }
  Type type = parse_type(0);
  check_use(type, Use::parameter);
  const Token& name_token = peek();
  std::string name = take_name("a parameter name");
  if (contains(kReservedParameterNames, name)) {
    throw CompileError(name_token.location,
                       fmt::format("parameter name '{}' is used by the generated methods", name),
                       "a name other than current and token");
  }
  // Inside a generated XPrx or XServant class, a parameter of that name would hide the class.
  if (name.ends_with("Prx") || name.ends_with("Servant")) {
    throw CompileError(name_token.location,
                       fmt::format("parameter name '{}' ends like a generated class name", name),
                       "a name that does not end in Prx or Servant");
  }
  for (const Parameter& other : op.parameters) {
    if (other.name == name) {
      throw CompileError(
          name_token.location,
          fmt::format("parameter '{}' is already declared at {}", name, other.location.to_string()),
          fmt::format("a name not yet used in operation '{}'", op.name));
    }
  }
  return Parameter{std::move(name), std::move(type), name_token.location};
}

void FileParser::parse_raises(Operation& op) {
  const Token& keyword = advance();
  if (op.oneway) {
    throw CompileError(keyword.location,
                       fmt::format("oneway operation '{}' raises exceptions", op.name),
                       "';' (a oneway call has no reply to carry an exception)");
  }
  expect(TokenKind::left_paren, "'(' after 'raises'");
  do {
    const ScopedName name = parse_scoped_name("the name of an exception");
    const auto* exception =
        static_cast<const Struct*>(&lookup_as(name, DefinitionKind::exception, "exception"));
    if (std::find(op.raises.begin(), op.raises.end(), exception) != op.raises.end()) {
      throw CompileError(name.location, fmt::format("'{}' is raised twice", name.text),
                         "each exception once");
    }
    op.raises.push_back(exception);
  } while (accept(TokenKind::comma));
  expect(TokenKind::right_paren, "',' or ')' after the exception name");
}

// --- Types -----------------------------------------------------------------------------------

std::optional<Builtin> builtin_named(const Token& t) {
  if (!t.is(TokenKind::keyword)) return std::nullopt;
  static constexpr std::array<std::pair<std::string_view, Builtin>, 11> kBuiltins = {{
      {"void", Builtin::void_type},
      {"bool", Builtin::boolean},
      {"byte", Builtin::byte},
      {"short", Builtin::short_int},
      {"int", Builtin::int32},
      {"long", Builtin::int64},
      {"float", Builtin::float32},
      {"double", Builtin::float64},
      {"string", Builtin::string},
      {"binary", Builtin::binary},
      {"stream", Builtin::stream},
  }};
  for (const auto& [word, builtin] : kBuiltins) {
    if (t.text == word) return builtin;
  }
  return std::nullopt;
}

Type FileParser::parse_type(std::size_t depth) {
  const Token& t = peek();
  if (const std::optional<Builtin> builtin = builtin_named(t)) {
    advance();
    return Type{Type::Kind::builtin, *builtin, nullptr, nullptr, t.location};
  }
  if (t.is_keyword("sequence")) return parse_sequence(depth);
  if (t.is(TokenKind::identifier) || t.is(TokenKind::scope)) return parse_named_type();
  unexpected(t, "a type");
}

Type FileParser::parse_sequence(std::size_t depth) {
  const Token& keyword = advance();
  if (depth >= kMaxSequenceDepth) {
    throw CompileError(keyword.location, "sequences nested deeper than 32 levels",
                       "at most 32 nested sequences (the PLANET serializer's limit)");
  }
  expect(TokenKind::left_angle, "'<' after 'sequence'");
  Type element = parse_type(depth + 1);
  check_use(element, Use::element);
  expect(TokenKind::right_angle, "'>' after the sequence's element type");
  return Type{Type::Kind::sequence, Builtin::void_type,
              std::make_shared<const Type>(std::move(element)), nullptr, keyword.location};
}

Type FileParser::parse_named_type() {
  const ScopedName name = parse_scoped_name("a type name");
  const Definition* d = lookup(name);
  if (d == nullptr) {
    throw CompileError(name.location, fmt::format("unknown type '{}'", name.text),
                       "a builtin type or the name of an enum, valued, event or interface "
                       "defined before this point");
  }
  if (d->kind == DefinitionKind::module) {
    throw CompileError(name.location, fmt::format("'{}' is a module, not a type", name.text),
                       "a type");
  }
  return Type{Type::Kind::named, Builtin::void_type, nullptr, d, name.location};
}

void FileParser::check_use(const Type& type, Use use) {
  if (type.is_named(DefinitionKind::exception)) {
    throw CompileError(
        type.location,
        fmt::format("'{}' is an exception, which only raises (...) may name", type.to_idl()),
        "a data type or an interface");
  }
  if (type.is_void() && use != Use::result) {
    throw CompileError(type.location, fmt::format("'void' cannot be {}", use_name(use)),
                       use == Use::parameter ? std::string(kDataTypes) + ", an interface or stream"
                                             : std::string(kDataTypes));
  }
  if ((type.is_stream() || type.is_interface()) && (use == Use::field || use == Use::element)) {
    throw CompileError(type.location,
                       fmt::format("'{}' cannot be {} (streams and interfaces are only passed "
                                   "as parameters and results)",
                                   type.to_idl(), use_name(use)),
                       std::string(kDataTypes));
  }
}

}  // namespace

std::string SourceReader::identity(const fs::path& path) {
  return path.lexically_normal().string();
}

std::optional<std::string> FileSystemReader::read(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return std::nullopt;
  std::ifstream in(path, std::ios::binary);
  if (!in) return std::nullopt;
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) return std::nullopt;
  return std::move(text).str();
}

std::string FileSystemReader::identity(const fs::path& path) {
  std::error_code ec;
  const fs::path canonical = fs::weakly_canonical(path, ec);
  return ec ? path.lexically_normal().string() : canonical.string();
}

Program parse_program(const fs::path& path, const ParseOptions& options, SourceReader& reader) {
  return Loader(options, reader).run(path);
}

}  // namespace icars::planet::idl
