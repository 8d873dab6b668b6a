// The parser: the AST it builds for every construct, name lookup through enclosing modules
// and includes, every semantic rule with the exact location and wording of its error, and
// robustness against truncated, garbage and deeply nested input.
#include "parser.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <fstream>
#include <map>
#include <random>
#include <sstream>

namespace icars::planet::idl {
namespace {

namespace fs = std::filesystem;

// Files served from memory, by normalised path.
class MemoryReader final : public SourceReader {
 public:
  explicit MemoryReader(std::map<std::string, std::string> files) : files_(std::move(files)) {}
  std::optional<std::string> read(const fs::path& path) override {
    const auto it = files_.find(path.lexically_normal().string());
    if (it == files_.end()) return std::nullopt;
    return it->second;
  }

 private:
  std::map<std::string, std::string> files_;
};

Program parse(std::map<std::string, std::string> files, ParseOptions options = {}) {
  MemoryReader reader(std::move(files));
  return parse_program("main.idl", options, reader);
}
Program parse(const std::string& text) { return parse({{"main.idl", text}}); }

std::string error_of(std::map<std::string, std::string> files, ParseOptions options = {}) {
  try {
    parse(std::move(files), std::move(options));
  } catch (const CompileError& e) {
    return e.what();
  }
  return "no error";
}
std::string error_of(const std::string& text) { return error_of({{"main.idl", text}}); }

template <class T>
const T& definition(const Module& m, std::size_t index) {
  return dynamic_cast<const T&>(*m.definitions.at(index));
}

TEST(Parser, BuildsTheTreeOfEveryConstruct) {
  const Program program = parse(R"(
    module a {
      module b {
        enum Color { red, green = 5, blue, black = -2, white = 0x10, };
        valued Pose { double x; sequence<sequence<Color>> grid; };
        event Sound { double level; };
        exception Missing { int channel; string why; };
        interface Base { string id(); };
        interface TV : Base {
          int set_channel(int channel) raises (Missing);
          oneway void log(string text);
          TV self();
          stream record(Pose at, binary data);
        };
      }
    }
  )");
  const Module& a = definition<Module>(program.main->root, 0);
  const Module& b = definition<Module>(a, 0);
  EXPECT_EQ(b.qualified_name, "a::b");
  const Enum& color = definition<Enum>(b, 0);
  EXPECT_EQ(color.qualified_name, "a::b::Color");
  std::vector<std::int32_t> values;
  for (const Enumerator& e : color.enumerators) values.push_back(e.value);
  EXPECT_EQ(values, (std::vector<std::int32_t>{0, 5, 6, -2, 16}));
  const Struct& pose = definition<Struct>(b, 1);
  EXPECT_EQ(pose.kind, DefinitionKind::valued);
  EXPECT_EQ(pose.fields.at(1).type.to_idl(), "sequence<sequence<a::b::Color>>");
  EXPECT_EQ(definition<Struct>(b, 2).kind, DefinitionKind::event);
  EXPECT_EQ(definition<Struct>(b, 3).fields.size(), 2u);
  const Interface& tv = definition<Interface>(b, 5);
  ASSERT_EQ(tv.bases.size(), 1u);
  EXPECT_EQ(tv.bases[0]->name, "Base");
  ASSERT_EQ(tv.operations.size(), 4u);
  const Operation& set_channel = tv.operations[0];
  EXPECT_EQ(set_channel.result.to_idl(), "int");
  EXPECT_EQ(set_channel.parameters.at(0).name, "channel");
  ASSERT_EQ(set_channel.raises.size(), 1u);
  EXPECT_EQ(set_channel.raises[0]->qualified_name, "a::b::Missing");
  EXPECT_TRUE(tv.operations[1].oneway);
  EXPECT_TRUE(tv.operations[2].result.is_interface());
  EXPECT_EQ(&tv.operations[2].result.interface(), &tv);
  EXPECT_TRUE(tv.operations[3].result.is_stream());
  const auto all = tv.all_operations();
  ASSERT_EQ(all.size(), 5u);
  EXPECT_EQ(all[0].operation->name, "id");
  EXPECT_EQ(all[0].owner->name, "Base");
}

TEST(Parser, IdempotentMarksATwoWayOperation) {
  const Program program = parse(R"(
    exception Full { int max; };
    interface TV {
      idempotent void set_volume(int volume) raises (Full);
      idempotent int volume();
      void volume_up();
      oneway void log(string text);
    };
  )");
  const Interface& tv = definition<Interface>(program.main->root, 1);
  ASSERT_EQ(tv.operations.size(), 4u);
  EXPECT_TRUE(tv.operations[0].idempotent);
  EXPECT_FALSE(tv.operations[0].oneway);
  ASSERT_EQ(tv.operations[0].raises.size(), 1u);
  EXPECT_TRUE(tv.operations[1].idempotent);
  EXPECT_EQ(tv.operations[1].result.to_idl(), "int");
  EXPECT_FALSE(tv.operations[2].idempotent);
  EXPECT_FALSE(tv.operations[3].idempotent);
  EXPECT_TRUE(tv.operations[3].oneway);
}

TEST(Parser, LooksNamesUpThroughEnclosingModulesInnermostFirst) {
  const Program program = parse(R"(
    valued P { int outer; };
    module a {
      valued P { int inner; };
      module b {
        valued Q { P near; ::P far; a::P qualified; };
      }
    }
  )");
  const Module& b = definition<Module>(definition<Module>(program.main->root, 1), 1);
  const Struct& q = definition<Struct>(b, 0);
  EXPECT_EQ(q.fields[0].type.to_idl(), "a::P");
  EXPECT_EQ(q.fields[1].type.to_idl(), "P");
  EXPECT_EQ(q.fields[2].type.to_idl(), "a::P");
}

// ICARS's own IDL nests its modules in `icars`, so the generated code is in namespace icars;
// anywhere else the name stays reserved.
TEST(Parser, IcarsNamesOnlyAnOutermostModule) {
  const Program program = parse(
      "module icars { module home { valued P { int x; }; }; }\n"
      "module app { valued Q { icars::home::P p; }; }");
  const Module& app = definition<Module>(program.main->root, 1);
  EXPECT_EQ(definition<Struct>(app, 0).fields[0].type.to_idl(), "icars::home::P");
  EXPECT_EQ(error_of("module a { module icars { } }"),
            "main.idl:1:19: error: 'icars' is reserved for the C++ mapping, expected a module "
            "name other than std, icars and asio");
  EXPECT_EQ(error_of("valued icars { int x; };"),
            "main.idl:1:8: error: 'icars' is reserved for the C++ mapping, expected a name for "
            "the valued other than std, icars and asio");
}

TEST(Parser, ReopenedModulesShareTheirNames) {
  const Program program =
      parse("module a { valued P { int x; }; }\nmodule a { valued Q { P p; }; }");
  EXPECT_EQ(program.main->root.definitions.size(), 2u);
  EXPECT_EQ(error_of("module a { valued P { int x; }; }\nmodule a { valued P { int y; }; }"),
            "main.idl:2:19: error: 'a::P' is already defined as valued at main.idl:1:19, "
            "expected a name not yet used in this module");
}

TEST(Parser, IncludesAreParsedOnceAndFoundInImportDirectories) {
  ParseOptions options;
  options.import_dirs = {"lib"};
  const Program program =
      parse({{"main.idl", "include \"left.idl\";\ninclude \"right.idl\";\nvalued M { geo::P p; };"},
             {"left.idl", "include \"geo.idl\";"},
             {"right.idl", "include \"geo.idl\";"},
             {"lib/geo.idl", "module geo { valued P { int x; }; }"}},
            options);
  ASSERT_EQ(program.files.size(), 4u);
  EXPECT_EQ(program.files[0]->path, "lib/geo.idl");
  EXPECT_EQ(program.main->includes.size(), 2u);
  EXPECT_EQ(program.main->includes[0].file->path, "left.idl");
}

TEST(Parser, IncludesAreResolvedNextToTheIncludingFileFirst) {
  const Program program = parse({{"main.idl", "include \"sub/a.idl\";"},
                                 {"sub/a.idl", "include \"b.idl\";"},
                                 {"sub/b.idl", "valued B { int x; };"}});
  EXPECT_EQ(program.files[0]->path, "sub/b.idl");
}

TEST(Parser, ReportsIncludeProblems) {
  EXPECT_EQ(error_of("include \"nope.idl\";"),
            "main.idl:1:9: error: cannot find include file \"nope.idl\" (searched nope.idl), "
            "expected a file next to the including file or in an import directory (-I)");
  EXPECT_EQ(
      error_of({{"main.idl", "include \"a.idl\";"}, {"a.idl", "// a\ninclude \"main.idl\";"}}),
      "a.idl:2:9: error: include cycle main.idl -> a.idl -> main.idl, expected files that "
      "do not include each other");
  EXPECT_EQ(error_of("valued A { int x; };\ninclude \"a.idl\";"),
            "main.idl:2:1: error: include after a definition, expected includes only at the top "
            "of the file, before any definition");
  EXPECT_EQ(error_of({{"main.idl", "include \"a.idl\";\nvalued A { int x; };"},
                      {"a.idl", "valued A { int y; };"}}),
            "main.idl:2:8: error: 'A' is already defined as valued at a.idl:1:8, expected a name "
            "not yet used in this module");
  try {
    MemoryReader empty({});
    parse_program("missing.idl", {}, empty);
    FAIL();
  } catch (const CompileError& e) {
    EXPECT_STREQ(e.what(),
                 "missing.idl: error: cannot read 'missing.idl', expected a readable IDL file");
  }
}

struct BadCase {
  const char* text;
  const char* error;
};

class ParserError : public ::testing::TestWithParam<BadCase> {};

TEST_P(ParserError, NamesTheProblemAndWhatWasExpected) {
  EXPECT_EQ(error_of(GetParam().text), GetParam().error);
}

INSTANTIATE_TEST_SUITE_P(
    Rules, ParserError,
    ::testing::Values(
        BadCase{"valued P { Unknown x; };",
                "main.idl:1:12: error: unknown type 'Unknown', expected a builtin type or the "
                "name of an enum, valued, event or interface defined before this point"},
        BadCase{"valued P { int x }",
                "main.idl:1:18: error: unexpected '}', expected ';' after the field"},
        BadCase{"valued P { int x; }",
                "main.idl:1:20: error: unexpected end of file, expected ';' after the valued"},
        BadCase{"valued P { sequence int> x; };",
                "main.idl:1:21: error: unexpected 'int', expected '<' after 'sequence'"},
        BadCase{
            "valued P { sequence<int x; };",
            "main.idl:1:25: error: unexpected 'x', expected '>' after the sequence's element type"},
        BadCase{"valued P { sequence<void> x; };",
                "main.idl:1:21: error: 'void' cannot be a sequence element, expected a data type "
                "(bool, byte, short, int, long, float, double, string, binary, a sequence, an "
                "enum, a valued or an event)"},
        BadCase{"interface I { oneway int f(); };",
                "main.idl:1:22: error: oneway operation 'f' returns 'int', expected 'void' (a "
                "oneway call has no reply to carry a result)"},
        BadCase{"exception E {}; interface I { oneway void f() raises (E); };",
                "main.idl:1:47: error: oneway operation 'f' raises exceptions, expected ';' (a "
                "oneway call has no reply to carry an exception)"},
        BadCase{"interface I { idempotent oneway void f(); };",
                "main.idl:1:15: error: an operation is both 'idempotent' and 'oneway', expected "
                "one of them (a oneway call has no reply to wait for, so it is never sent "
                "again)"},
        BadCase{"interface I { oneway idempotent void f(); };",
                "main.idl:1:15: error: an operation is both 'idempotent' and 'oneway', expected "
                "one of them (a oneway call has no reply to wait for, so it is never sent "
                "again)"},
        BadCase{"interface I { void idempotent(); };",
                "main.idl:1:20: error: 'idempotent' is a keyword of the IDL, expected an "
                "operation name"},
        BadCase{"valued V { int x; }; interface I { void f() raises (V); };",
                "main.idl:1:53: error: 'V' is a valued, not an exception, expected the name of an "
                "exception defined before this point"},
        BadCase{"interface I { void f() raises (Nope); };",
                "main.idl:1:32: error: unknown exception 'Nope', expected the name of an "
                "exception defined before this point"},
        BadCase{"valued class { int x; };",
                "main.idl:1:8: error: 'class' is a C++ keyword, expected a name for the valued "
                "that is not a C++ keyword"},
        BadCase{"valued P { int int; };",
                "main.idl:1:16: error: 'int' is a keyword of the IDL, expected a field name"},
        BadCase{"module std { }",
                "main.idl:1:8: error: 'std' is reserved for the C++ mapping, expected a module "
                "name other than std, icars and asio"},
        BadCase{"valued P { int x_; };",
                "main.idl:1:16: error: 'x_' starts or ends with '_' or contains '__', expected a "
                "field name without them (C++ and the generated code use them)"},
        BadCase{"enum E { a = 2147483648 };",
                "main.idl:1:14: error: enum value 2147483648 is out of range, expected values "
                "from -2147483648 to 2147483647"},
        BadCase{"enum E { a = -2147483648, b = 2147483647, c };",
                "main.idl:1:43: error: enumerator 'c' would have the value 2147483648, which "
                "does not fit in 32 bits, expected values from -2147483648 to 2147483647"},
        BadCase{"enum E { a = 1, b = 1 };",
                "main.idl:1:17: error: enumerator 'b' has the value 1 of 'a', expected distinct "
                "values in enum 'E'"},
        BadCase{"enum E { a, a };",
                "main.idl:1:13: error: enumerator 'a' is already declared at main.idl:1:10, "
                "expected a name not yet used in enum 'E'"},
        BadCase{"enum E { };", "main.idl:1:10: error: unexpected '}', expected an enumerator name"},
        BadCase{"valued P { };",
                "main.idl:1:12: error: valued 'P' has no fields, expected at least one field (an "
                "empty valued cannot be told apart on the wire)"},
        BadCase{"interface { };",
                "main.idl:1:11: error: unexpected '{', expected an interface name"},
        BadCase{"module a { valued P { int x; };",
                "main.idl:1:32: error: unexpected end of file, expected '}' to close module 'a' "
                "opened at main.idl:1:8"},
        BadCase{"}",
                "main.idl:1:1: error: unexpected '}', expected a definition (module, enum, "
                "valued, event, exception or interface)"},
        BadCase{"valued P { int x; int x; };",
                "main.idl:1:23: error: field 'x' is already declared at main.idl:1:16, expected a "
                "name not yet used in valued 'P'"},
        BadCase{"valued P { int P; };",
                "main.idl:1:16: error: field 'P' has the name of its valued, expected another "
                "field name"},
        BadCase{"exception E { string message; };",
                "main.idl:1:22: error: field name 'message' is used by the exception's C++ "
                "class, expected a name other than message, type_id, static_type_id, what, kind, "
                "properties and remote_message"},
        BadCase{"interface I { void f(); int f(); };",
                "main.idl:1:29: error: operation 'f' is already declared at main.idl:1:20, "
                "expected a name not yet used in interface 'I'"},
        BadCase{"interface I { void f(); void f_async(); };",
                "main.idl:1:30: error: operation 'f_async' clashes with the asynchronous method "
                "generated for 'f', expected a name that does not differ from another "
                "operation's by '_async'"},
        BadCase{"interface I { void call(); };",
                "main.idl:1:20: error: operation name 'call' is used by the generated C++ "
                "classes, expected another name (not call, async_call, notify, ref, "
                "communicator, link, path, object, timeout, with_timeout, set_timeout, bound, "
                "implement, dispatch, type_id, has_method, bind_result, async_call_bound or the "
                "interface's own names)"},
        BadCase{"interface I { void f(int a, int a); };",
                "main.idl:1:33: error: parameter 'a' is already declared at main.idl:1:26, "
                "expected a name not yet used in operation 'f'"},
        BadCase{"interface I { void f(int current); };",
                "main.idl:1:26: error: parameter name 'current' is used by the generated "
                "methods, expected a name other than current and token"},
        BadCase{"interface I { void f(int IPrx); };",
                "main.idl:1:26: error: parameter name 'IPrx' ends like a generated class name, "
                "expected a name that does not end in Prx or Servant"},
        BadCase{"interface I { void f(void v); };",
                "main.idl:1:22: error: 'void' cannot be a parameter type, expected a data type "
                "(bool, byte, short, int, long, float, double, string, binary, a sequence, an "
                "enum, a valued or an event), an interface or stream"},
        BadCase{"interface I { void f(); }; valued P { I i; };",
                "main.idl:1:39: error: 'I' cannot be the type of a field (streams and interfaces "
                "are only passed as parameters and results), expected a data type (bool, byte, "
                "short, int, long, float, double, string, binary, a sequence, an enum, a valued "
                "or an event)"},
        BadCase{"valued P { sequence<stream> s; };",
                "main.idl:1:21: error: 'stream' cannot be a sequence element (streams and "
                "interfaces are only passed as parameters and results), expected a data type "
                "(bool, byte, short, int, long, float, double, string, binary, a sequence, an "
                "enum, a valued or an event)"},
        BadCase{"exception E {}; interface I { E f(); };",
                "main.idl:1:31: error: 'E' is an exception, which only raises (...) may name, "
                "expected a data type or an interface"},
        BadCase{"module m { } valued P { m x; };",
                "main.idl:1:25: error: 'm' is a module, not a type, expected a type"},
        BadCase{"valued P { int x; }; interface I : P { };",
                "main.idl:1:36: error: 'P' is a valued, not an interface, expected the name of an "
                "interface defined before this point"},
        BadCase{"interface A { void f(); }; interface B { int f(); }; interface C : A, B { };",
                "main.idl:1:64: error: interface 'C' inherits two operations named 'f' (from 'A' "
                "and 'B'), expected base interfaces whose operation names differ"},
        BadCase{"interface TV { }; valued TVPrx { int x; };",
                "main.idl:1:26: error: 'TVPrx' is the name of a class generated for interface "
                "'TV', expected another name"},
        BadCase{"valued TVServant { int x; }; interface TV { };",
                "main.idl:1:40: error: interface 'TV' generates the class 'TVServant', already "
                "defined at main.idl:1:8, expected an interface name whose Prx and Servant "
                "classes are free"},
        BadCase{"valued P { int x; }; valued Q { P::x y; };",
                "main.idl:1:33: error: unknown type 'P::x', expected a builtin type or the name "
                "of an enum, valued, event or interface defined before this point"},
        BadCase{"valued P { P self; };",
                "main.idl:1:12: error: unknown type 'P', expected a builtin type or the name of "
                "an enum, valued, event or interface defined before this point"}));

std::string read_file(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

// Every prefix of a good fixture either parses or fails with a CompileError; nothing else.
TEST(ParserRobustness, EveryTruncationOfTheFixturesFailsCleanly) {
  const fs::path dir = PLANET_IDL_TESTDATA;
  const std::string geometry = read_file(dir / "imports/geometry.idl");
  const std::string types = read_file(dir / "types.idl");
  for (const std::string name : {"types.idl", "home.idl"}) {
    const std::string text = read_file(dir / name);
    ASSERT_FALSE(text.empty()) << name;
    for (std::size_t n = 0; n < text.size(); ++n) {
      ParseOptions options;
      options.import_dirs = {"imports"};
      try {
        parse({{"main.idl", text.substr(0, n)},
               {"types.idl", types},
               {"imports/geometry.idl", geometry}},
              options);
      } catch (const CompileError&) {
      }
    }
  }
}

TEST(ParserRobustness, RandomBytesFailCleanly) {
  std::mt19937 random(12345);
  std::uniform_int_distribution<int> byte(0, 255);
  const std::string alphabet = "module{}<>;,:=-()sequence int valued interface x\n/*\"";
  std::uniform_int_distribution<std::size_t> pick(0, alphabet.size() - 1);
  for (int round = 0; round < 2000; ++round) {
    std::string text(static_cast<std::size_t>(round % 200), ' ');
    for (char& c : text) {
      c = round % 2 ? static_cast<char>(byte(random)) : alphabet[pick(random)];
    }
    try {
      parse(text);
    } catch (const CompileError&) {
    }
  }
}

TEST(ParserRobustness, DeepNestingIsAnErrorNotAStackOverflow) {
  std::string modules;
  for (int i = 0; i < 100000; ++i) modules += "module m {";
  EXPECT_EQ(error_of(modules).substr(0, 69),
            "main.idl:1:321: error: modules nested deeper than 32 levels, expected");
  std::string sequences = "valued P { ";
  for (int i = 0; i < 100000; ++i) sequences += "sequence<";
  EXPECT_NE(error_of(sequences).find("sequences nested deeper than 32 levels"), std::string::npos);
  std::string ok = "valued P { ";
  for (int i = 0; i < 32; ++i) ok += "sequence<";
  ok += "int";
  ok += std::string(32, '>');
  ok += " x; };";
  EXPECT_NO_THROW(parse(ok));
  std::map<std::string, std::string> chain;
  for (int i = 0; i < 100; ++i) {
    chain[i == 0 ? "main.idl" : std::to_string(i) + ".idl"] =
        fmt::format("include \"{}.idl\";", i + 1);
  }
  EXPECT_NE(error_of(chain).find("includes nested deeper than 32 files"), std::string::npos);
}

}  // namespace
}  // namespace icars::planet::idl
