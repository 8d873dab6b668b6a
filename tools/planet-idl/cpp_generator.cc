#include "cpp_generator.h"

#include <fmt/format.h>

#include <filesystem>
#include <string_view>
#include <vector>

namespace icars::planet::idl {

namespace {

constexpr std::string_view kPlanet = "icars::planet::";

// --- Type mapping ----------------------------------------------------------------------------

std::string cpp_name(const Definition& d) { return "::" + d.qualified_name; }

std::string_view builtin_cpp(Builtin b) {
  switch (b) {
    case Builtin::void_type:
      return "void";
    case Builtin::boolean:
      return "bool";
    case Builtin::byte:
      return "std::uint8_t";
    case Builtin::short_int:
      return "std::int16_t";
    case Builtin::int32:
      return "std::int32_t";
    case Builtin::int64:
      return "std::int64_t";
    case Builtin::float32:
      return "float";
    case Builtin::float64:
      return "double";
    case Builtin::string:
      return "std::string";
    case Builtin::binary:
      return "icars::planet::Binary";
    case Builtin::stream:
      return "icars::planet::StreamRef";
  }
  return "void";
}

// The type as it travels: in struct fields, Operation signatures and servant results.
std::string wire_type(const Type& t) {
  switch (t.kind) {
    case Type::Kind::builtin:
      return std::string(builtin_cpp(t.builtin));
    case Type::Kind::sequence:
      return fmt::format("std::vector<{}>", wire_type(*t.element));
    case Type::Kind::named:
      if (t.is_interface()) return fmt::format("{}Ref<{}>", kPlanet, cpp_name(*t.definition));
      return cpp_name(*t.definition);
  }
  return "void";
}

bool is_scalar(const Type& t) {
  if (t.kind == Type::Kind::named) return t.is_named(DefinitionKind::enumeration);
  return t.kind == Type::Kind::builtin && t.builtin != Builtin::string &&
         t.builtin != Builtin::binary;
}

// Scalars (and stream handles) by value, everything else by const reference.
std::string in_param(const std::string& type, bool by_value) {
  return by_value ? type : "const " + type + "&";
}

std::string proxy_class(const Definition& i) { return cpp_name(i) + "Prx"; }
constexpr std::string_view kInputStream = "std::shared_ptr<icars::planet::InputStream>";

std::string stub_param(const Type& t) { return in_param(wire_type(t), is_scalar(t)); }

std::string stub_result(const Type& t) {
  if (t.is_interface()) return proxy_class(*t.definition);
  if (t.is_stream()) return std::string(kInputStream);
  return wire_type(t);
}

std::string servant_param(const Type& t) {
  if (t.is_interface()) return proxy_class(*t.definition);
  if (t.is_stream()) return std::string(kInputStream);
  return in_param(wire_type(t), is_scalar(t));
}

bool is_bound(const Type& t) { return t.is_interface() || t.is_stream(); }

std::string default_initialiser(const Type& t) {
  if (t.is_named(DefinitionKind::enumeration)) {
    const auto& e = static_cast<const Enum&>(*t.definition);
    return fmt::format(" = {}::{}", cpp_name(e), e.enumerators.front().name);
  }
  return "{}";
}

std::string namespace_of(const Definition& d) {
  const std::string& q = d.qualified_name;
  return q.size() == d.name.size() ? std::string() : q.substr(0, q.size() - d.name.size() - 2);
}

std::string translator_name(const Interface& i, const Operation& op) {
  return fmt::format("translate_{}_{}", i.name, op.name);
}

template <class T, class F>
std::string join(const std::vector<T>& items, std::string_view separator, F&& format) {
  std::string out;
  for (const T& item : items) {
    if (!out.empty()) out += separator;
    out += format(item);
  }
  return out;
}

constexpr std::size_t kLineLimit = 100;

// `indent head(items...)tail` on one line when it fits, else the items on continuation lines
// (indented 4 more than `indent`), together when they fit on one, else one per line.
std::string wrap(std::string_view indent, std::string_view head,
                 const std::vector<std::string>& items, std::string_view tail) {
  std::string one_line;
  for (const std::string& item : items) {
    if (!one_line.empty()) one_line += ", ";
    one_line += item;
  }
  if (indent.size() + head.size() + one_line.size() + tail.size() + 2 <= kLineLimit) {
    return fmt::format("{}{}({}){}", indent, head, one_line, tail);
  }
  const std::string continuation = std::string(indent) + "    ";
  if (continuation.size() + one_line.size() + tail.size() + 1 <= kLineLimit) {
    return fmt::format("{}{}(\n{}{}){}", indent, head, continuation, one_line, tail);
  }
  std::string out = fmt::format("{}{}(", indent, head);
  for (std::size_t i = 0; i < items.size(); ++i) {
    out += fmt::format("\n{}{}{}", continuation, items[i], i + 1 < items.size() ? "," : "");
  }
  return out + ")" + std::string(tail);
}

template <class T, class F>
std::vector<std::string> map(const std::vector<T>& items, F&& format) {
  std::vector<std::string> out;
  out.reserve(items.size());
  for (const T& item : items) out.push_back(format(item));
  return out;
}

void collect(const Module& m, std::vector<const Definition*>& out) {
  for (const auto& d : m.definitions) {
    if (d->kind == DefinitionKind::module) {
      collect(static_cast<const Module&>(*d), out);
    } else {
      out.push_back(d.get());
    }
  }
}

// Opens and closes `namespace a::b {` blocks as the definitions being written move between
// modules.
class Namespaces {
 public:
  explicit Namespaces(std::string& out) : out_(out) {}
  void enter(const std::string& name) {
    if (name == current_) return;
    close();
    if (!name.empty()) out_ += fmt::format("namespace {} {{\n\n", name);
    current_ = name;
  }
  void close() {
    if (!current_.empty()) out_ += fmt::format("}}  // namespace {}\n\n", current_);
    current_.clear();
  }

 private:
  std::string& out_;
  std::string current_;
};

class Generator {
 public:
  explicit Generator(const SourceFile& file) : file_(file) { collect(file.root, definitions_); }

  GeneratedCpp run() {
    GeneratedCpp out;
    out.header_name = header_name_for(file_.path);
    out.source_name = source_name_for(file_.path);
    write_header_prologue();
    write_data_types();
    write_specialisations();
    write_interfaces();
    write_source_prologue(out.header_name);
    write_source_bodies();
    out.header = std::move(h_);
    out.source = std::move(cc_);
    return out;
  }

 private:
  bool has(DefinitionKind kind) const {
    for (const Definition* d : definitions_) {
      if (d->kind == kind) return true;
    }
    return false;
  }
  bool uses_streams() const;
  std::string banner() const {
    return fmt::format("// Generated by planet-idl from {} — do not edit.\n",
                       std::filesystem::path(file_.path).filename().string());
  }

  void write_header_prologue();
  void write_data_types();
  void write_enum(const Enum& e);
  void write_struct(const Struct& s);
  void write_exception_class(const Struct& s);
  void write_specialisations();
  void write_interfaces();
  void write_interface_description(const Interface& i);
  void write_proxy(const Interface& i);
  void write_proxy_operation(const Interface& proxied, const Interface& owner, const Operation& op);
  void write_proxy_binding_helpers();
  void write_servant_class(const Interface& i);
  void write_source_prologue(const std::string& header_name);
  void write_source_bodies();
  void write_exception_bodies(const Struct& s);
  void write_translator(const Interface& i, const Operation& op);
  void write_servant_constructor(const Interface& i);

  const SourceFile& file_;
  std::vector<const Definition*> definitions_;  // every non-module definition, in order
  std::string h_;
  std::string cc_;
};

bool Generator::uses_streams() const {
  for (const Definition* d : definitions_) {
    if (d->kind != DefinitionKind::interface) continue;
    for (const Operation& op : static_cast<const Interface*>(d)->operations) {
      if (op.result.is_stream()) return true;
      for (const Parameter& p : op.parameters) {
        if (p.type.is_stream()) return true;
      }
    }
  }
  return false;
}

// --- Header: prologue and data types ---------------------------------------------------------

void Generator::write_header_prologue() {
  h_ += banner();
  h_ += "#pragma once\n\n";
  const bool interfaces = has(DefinitionKind::interface);
  h_ += "#include <cstdint>\n";
  if (interfaces) h_ += "#include <exception>\n#include <memory>\n";
  h_ += "#include <string>\n#include <string_view>\n#include <tuple>\n";
  if (interfaces) h_ += "#include <type_traits>\n#include <utility>\n";
  h_ += "#include <vector>\n\n";
  if (interfaces) {
    h_ +=
        "#include <asio/associated_executor.hpp>\n#include <asio/async_result.hpp>\n"
        "#include <asio/dispatch.hpp>\n#include <asio/executor_work_guard.hpp>\n\n";
  }
  h_ += "#include \"icars/planet/event.h\"\n";
  if (interfaces) h_ += "#include \"icars/planet/proxy.h\"\n#include \"icars/planet/remote.h\"\n";
  h_ += "#include \"icars/planet/serializer.h\"\n";
  if (interfaces) h_ += "#include \"icars/planet/servant.h\"\n";
  if (uses_streams()) h_ += "#include \"icars/planet/stream.h\"\n";
  for (const Include& include : file_.includes) {
    h_ += fmt::format("#include \"{}\"\n", header_name_for(include.file->path));
  }
  h_ += "\n";
}

void Generator::write_data_types() {
  Namespaces ns(h_);
  for (const Definition* d : definitions_) {
    if (d->kind == DefinitionKind::interface) continue;
    ns.enter(namespace_of(*d));
    if (d->kind == DefinitionKind::enumeration) {
      write_enum(static_cast<const Enum&>(*d));
    } else if (d->kind == DefinitionKind::exception) {
      write_exception_class(static_cast<const Struct&>(*d));
    } else {
      write_struct(static_cast<const Struct&>(*d));
    }
  }
  ns.close();
}

void Generator::write_enum(const Enum& e) {
  const std::string values = join(e.enumerators, ", ", [](const Enumerator& x) {
    return fmt::format("{} = {}", x.name, x.value);
  });
  const std::string head = fmt::format("enum class {} : std::int32_t {{", e.name);
  if (head.size() + values.size() < 96) {
    h_ += fmt::format("{} {} }};\n\n", head, values);
    return;
  }
  h_ += head + "\n";
  for (const Enumerator& x : e.enumerators) h_ += fmt::format("  {} = {},\n", x.name, x.value);
  h_ += "};\n\n";
}

void Generator::write_struct(const Struct& s) {
  h_ += fmt::format("struct {} {{\n", s.name);
  for (const Field& f : s.fields) {
    h_ += fmt::format("  {} {}{};\n", wire_type(f.type), f.name, default_initialiser(f.type));
  }
  if (!s.fields.empty()) h_ += "\n";
  h_ += fmt::format("  bool operator==(const {}&) const = default;\n}};\n\n", s.name);
}

void Generator::write_exception_class(const Struct& s) {
  h_ += fmt::format("class {} : public icars::planet::RemoteException {{\n public:\n", s.name);
  // Named static_type_id so that RemoteException::type_id() stays callable on the derived class.
  h_ += fmt::format("  static constexpr std::string_view static_type_id = \"{}\";\n\n",
                    s.qualified_name);
  std::vector<std::string> params =
      map(s.fields, [](const Field& f) { return stub_param(f.type) + " " + f.name; });
  params.emplace_back("std::string message = {}");
  h_ += wrap("  ", "explicit " + s.name, params, ";\n");
  h_ +=
      "  // Reads the fields back from the exception as it arrived; throws Error(bad_data) when\n"
      "  // one is missing or has another type.\n";
  h_ += fmt::format("  explicit {}(const icars::planet::RemoteException& wire);\n", s.name);
  if (!s.fields.empty()) h_ += "\n";
  for (const Field& f : s.fields) {
    h_ += fmt::format("  {} {}() const {{ return {}_; }}\n", stub_param(f.type), f.name, f.name);
  }
  if (!s.fields.empty()) h_ += "\n private:\n";
  for (const Field& f : s.fields) {
    h_ += fmt::format("  {} {}_{};\n", wire_type(f.type), f.name, default_initialiser(f.type));
  }
  h_ += "};\n\n";
}

void Generator::write_specialisations() {
  bool any = false;
  for (const Definition* d : definitions_) {
    const DefinitionKind k = d->kind;
    if (k == DefinitionKind::interface || k == DefinitionKind::exception) continue;
    any = true;
    const std::string type = cpp_name(*d);
    h_ += fmt::format(
        "template <>\nstruct icars::planet::TypeName<{}> {{\n"
        "  static constexpr std::string_view value = \"{}\";\n}};\n",
        type, d->qualified_name);
    if (k == DefinitionKind::enumeration) continue;
    const auto& s = static_cast<const Struct&>(*d);
    const bool event = k == DefinitionKind::event;
    const std::vector<std::string> members = map(s.fields, [&](const Field& f) {
      if (event)
        return fmt::format("icars::planet::event_field(\"{}\", &{}::{})", f.name, type, f.name);
      return fmt::format("&{}::{}", type, f.name);
    });
    h_ += fmt::format("template <>\nstruct icars::planet::{}<{}> {{\n",
                      event ? "EventFields" : "ValuedFields", type);
    h_ += wrap("  ", "static constexpr auto value = std::make_tuple", members, ";\n");
    h_ += "};\n";
  }
  if (any) h_ += "\n";
}

// --- Header: interfaces ----------------------------------------------------------------------

void Generator::write_interfaces() {
  Namespaces ns(h_);
  for (const Definition* d : definitions_) {
    if (d->kind != DefinitionKind::interface) continue;
    const auto& i = static_cast<const Interface&>(*d);
    ns.enter(namespace_of(i));
    write_interface_description(i);
    write_proxy(i);
    write_servant_class(i);
  }
  ns.close();
}

std::string operation_constant(const Interface& i, const Operation& op) {
  const std::string args =
      join(op.parameters, ", ", [](const Parameter& p) { return wire_type(p.type); });
  std::string type;
  std::string init;
  if (op.oneway) {
    type = fmt::format("icars::planet::OneWay<{}>", args);
    init = fmt::format("{}{{\"{}\"}}", op.name, op.name);
  } else {
    const std::string translator =
        op.raises.empty() ? "" : fmt::format(", &{}", translator_name(i, op));
    const std::string mode = op.idempotent ? ", icars::planet::CallMode::idempotent" : "";
    type = fmt::format("icars::planet::Operation<{}({})>", wire_type(op.result), args);
    init = fmt::format("{}{{\"{}\"{}{}}}", op.name, op.name, translator, mode);
  }
  const std::string line = fmt::format("  static constexpr {} {};\n", type, init);
  if (line.size() <= kLineLimit + 1) return line;
  return fmt::format("  static constexpr {}\n      {};\n", type, init);
}

void Generator::write_interface_description(const Interface& i) {
  for (const Operation& op : i.operations) {
    if (op.raises.empty()) continue;
    h_ +=
        fmt::format("// Turns the exceptions '{}' raises into their generated classes.\n", op.name);
    h_ += fmt::format("std::exception_ptr {}(const icars::planet::RemoteException& e);\n\n",
                      translator_name(i, op));
  }
  h_ += fmt::format("// The operations of interface {}, shared by proxies and servants.\n",
                    i.qualified_name);
  h_ += fmt::format("struct {} {{\n  static constexpr std::string_view type_id = \"{}\";\n", i.name,
                    i.qualified_name);
  for (const Operation& op : i.operations) {
    h_ += operation_constant(i, op);
  }
  h_ += "};\n\n";
}

void Generator::write_proxy(const Interface& i) {
  h_ += fmt::format("// Calls a remote {}.\n", i.qualified_name);
  h_ += fmt::format("class {}Prx : public icars::planet::Proxy {{\n public:\n", i.name);
  h_ += fmt::format("  using Proxy::Proxy;\n  {}Prx() = default;\n", i.name);
  h_ += fmt::format(
      "  // Binds a reference that arrived over `via` (for a servant: current.connection).\n"
      "  {0}Prx(icars::planet::Communicator& communicator,\n"
      "      std::shared_ptr<icars::planet::Link> via,\n"
      "      const icars::planet::Ref<{0}>& ref)\n"
      "      : Proxy(communicator, std::move(via), ref.object()) {{}}\n\n",
      i.name);
  h_ += fmt::format(
      "  // A reference to this object, to pass to other operations.\n"
      "  icars::planet::Ref<{0}> ref() const {{\n"
      "    return icars::planet::Ref<{0}>(object({0}::type_id));\n  }}\n",
      i.name);
  bool binds = false;
  for (const Interface::Member& m : i.all_operations()) {
    write_proxy_operation(i, *m.owner, *m.operation);
    binds = binds || is_bound(m.operation->result);
  }
  if (binds) write_proxy_binding_helpers();
  h_ += "};\n\n";
}

// The operation constant as named from the proxy: short for the proxy's own interface (a
// nested-name lookup ignores parameters, so a parameter cannot hide it).
std::string constant_name(const Interface& proxied, const Interface& owner, const Operation& op) {
  const std::string scope = &proxied == &owner ? owner.name : cpp_name(owner);
  return scope + "::" + op.name;
}

void Generator::write_proxy_operation(const Interface& proxied, const Interface& owner,
                                      const Operation& op) {
  const std::string constant = constant_name(proxied, owner, op);
  std::vector<std::string> params =
      map(op.parameters, [](const Parameter& p) { return stub_param(p.type) + " " + p.name; });
  std::vector<std::string> call_args{constant};
  for (const Parameter& p : op.parameters) call_args.push_back(p.name);
  h_ += "\n";
  if (op.oneway) {
    h_ += wrap("  ", "void " + op.name, params, " const {\n");
    h_ += wrap("    ", "this->notify", call_args, ";\n  }\n");
    return;
  }
  const std::string result = stub_result(op.result);
  if (op.idempotent) {
    h_ += "  // Idempotent: re-sent when the link comes back; the servant may run it twice.\n";
  }
  h_ += wrap("  ", result + " " + op.name, params, " const {\n");
  const std::string ret = op.result.is_void() ? "" : "return ";
  if (is_bound(op.result)) {
    h_ += fmt::format("    return bind_result<{}>(*this, {});\n  }}\n", result,
                      wrap("", "this->call", call_args, ""));
  } else {
    h_ += wrap("    ", ret + "this->call", call_args, ";\n  }\n");
  }
  h_ += fmt::format(
      "  // Completion signature void(std::exception_ptr{}).\n  template <class Token>\n",
      op.result.is_void() ? "" : ", " + result);
  params.emplace_back("Token&& token");
  h_ += wrap("  ", "auto " + op.name + "_async", params, " const {\n");
  const std::string async =
      is_bound(op.result) ? fmt::format("async_call_bound<{}>", result) : std::string("async_call");
  const std::string args = join(op.parameters, ", ", [](const Parameter& p) { return p.name; });
  h_ += wrap("    ", "return this->" + async,
             {constant, "{" + args + "}", "std::forward<Token>(token)"}, ";\n  }\n");
}

// Private helpers of proxies whose operations return interfaces or streams: the wire result
// (a Ref or StreamRef) is bound to this proxy's communicator and link.
void Generator::write_proxy_binding_helpers() {
  h_ += R"(
 private:
  template <class Result, class Wire>
  static Result bind_result(const icars::planet::Proxy& via, const Wire& wire) {
    if constexpr (std::is_same_v<Wire, icars::planet::StreamRef>) {
      return Result::element_type::open(via.communicator(), via.link(), wire);
    } else {
      return Result(via.communicator(), via.link(), wire);
    }
  }

  template <class Result, class R, class... A, class Token>
  auto async_call_bound(const icars::planet::Operation<R(A...)>& op,
                        std::type_identity_t<std::tuple<A...>> args, Token&& token) const {
    return asio::async_initiate<Token, void(std::exception_ptr, Result)>(
        [self = *this, op](auto handler, std::tuple<A...> call_args) {
          auto work = asio::make_work_guard(
              asio::get_associated_executor(handler, self.communicator().executor()));
          self.async_call(
              op, std::move(call_args),
              [self, handler = std::move(handler), work = std::move(work)](
                  std::exception_ptr error, R wire) mutable {
                Result result;
                if (!error) {
                  try {
                    result = bind_result<Result>(self, wire);
                  } catch (...) {
                    error = std::current_exception();
                  }
                }
                asio::dispatch(work.get_executor(), [handler = std::move(handler), error,
                                                     result = std::move(result)]() mutable {
                  std::move(handler)(error, std::move(result));
                });
              });
        },
        token, std::move(args));
  }
)";
}

void Generator::write_servant_class(const Interface& i) {
  h_ += fmt::format("// Implements {}: derive from it and override every operation.\n",
                    i.qualified_name);
  h_ += fmt::format("class {}Servant : public icars::planet::Servant {{\n public:\n", i.name);
  h_ += fmt::format("  {}Servant();\n", i.name);
  for (const Interface::Member& m : i.all_operations()) {
    const Operation& op = *m.operation;
    std::vector<std::string> params =
        map(op.parameters, [](const Parameter& p) { return servant_param(p.type) + " " + p.name; });
    params.emplace_back("const icars::planet::Current& current");
    h_ += "\n";
    const std::string head = fmt::format("virtual {} {}", wire_type(op.result), op.name);
    h_ += wrap("  ", head, params, " = 0;\n");
  }
  h_ += "};\n\n";
}

// --- Source ----------------------------------------------------------------------------------

void Generator::write_source_prologue(const std::string& header_name) {
  cc_ += banner();
  cc_ += fmt::format("#include \"{}\"\n\n#include <string>\n#include <utility>\n\n", header_name);
}

void Generator::write_source_bodies() {
  Namespaces ns(cc_);
  for (const Definition* d : definitions_) {
    if (d->kind == DefinitionKind::exception) {
      ns.enter(namespace_of(*d));
      write_exception_bodies(static_cast<const Struct&>(*d));
    } else if (d->kind == DefinitionKind::interface) {
      ns.enter(namespace_of(*d));
      const auto& i = static_cast<const Interface&>(*d);
      for (const Operation& op : i.operations) {
        if (!op.raises.empty()) write_translator(i, op);
      }
      write_servant_constructor(i);
    }
  }
  ns.close();
}

void Generator::write_exception_bodies(const Struct& s) {
  std::vector<std::string> params =
      map(s.fields, [](const Field& f) { return stub_param(f.type) + " " + f.name; });
  params.emplace_back("std::string message");
  cc_ += wrap("", s.name + "::" + s.name, params, "\n");
  std::string properties = "icars::planet::Properties()";
  for (const Field& f : s.fields) {
    properties += fmt::format("\n                          .set(\"{}\", {})", f.name, f.name);
  }
  cc_ += fmt::format(
      "    : RemoteException(std::string(static_type_id), std::move(message),\n"
      "                      {})",
      properties);
  for (const Field& f : s.fields) cc_ += fmt::format(",\n      {}_({})", f.name, f.name);
  cc_ += " {}\n\n";
  cc_ += fmt::format(
      "{0}::{0}(const icars::planet::RemoteException& wire)\n    : RemoteException(wire)", s.name);
  for (const Field& f : s.fields) {
    cc_ += fmt::format(",\n      {}_(wire.properties().get<{}>(\"{}\"))", f.name, wire_type(f.type),
                       f.name);
  }
  cc_ += " {}\n\n";
}

void Generator::write_translator(const Interface& i, const Operation& op) {
  cc_ +=
      fmt::format("std::exception_ptr {}(const icars::planet::RemoteException& e) {{\n  try {{\n",
                  translator_name(i, op));
  for (const Struct* x : op.raises) {
    cc_ += fmt::format(
        "    if (e.type_id() == {0}::static_type_id) return std::make_exception_ptr({0}(e));\n",
        cpp_name(*x));
  }
  cc_ +=
      "  } catch (...) {\n"
      "    return std::current_exception();  // the exception's fields did not decode\n"
      "  }\n  return std::make_exception_ptr(e);\n}\n\n";
}

std::string servant_argument(const Parameter& p) {
  if (p.type.is_interface()) {
    return fmt::format("{}(*current.communicator, current.connection, {})",
                       proxy_class(*p.type.definition), p.name);
  }
  if (p.type.is_stream()) {
    return fmt::format(
        "icars::planet::InputStream::open(*current.communicator, "
        "current.connection, {})",
        p.name);
  }
  return p.name;
}

void Generator::write_servant_constructor(const Interface& i) {
  cc_ += fmt::format("{0}Servant::{0}Servant() : Servant(std::string({0}::type_id)) {{\n", i.name);
  for (const Interface::Member& m : i.all_operations()) {
    const Operation& op = *m.operation;
    std::vector<std::string> params = map(op.parameters, [](const Parameter& p) {
      return in_param(wire_type(p.type), is_scalar(p.type)) + " " + p.name;
    });
    params.emplace_back("const icars::planet::Current& current");
    std::vector<std::string> args = map(op.parameters, servant_argument);
    args.emplace_back("current");
    cc_ += fmt::format("  implement({},\n", constant_name(i, *m.owner, op));
    cc_ += wrap("            ", "[this]", params, " {\n");
    cc_ += wrap("              ",
                fmt::format("{}this->{}", op.result.is_void() ? "" : "return ", op.name), args,
                ";\n            });\n");
  }
  cc_ += "}\n\n";
}

}  // namespace

std::string header_name_for(std::string_view idl_path) {
  return std::filesystem::path(idl_path).stem().string() + ".planet.h";
}

std::string source_name_for(std::string_view idl_path) {
  return std::filesystem::path(idl_path).stem().string() + ".planet.cc";
}

GeneratedCpp generate_cpp(const SourceFile& file) { return Generator(file).run(); }

}  // namespace icars::planet::idl
