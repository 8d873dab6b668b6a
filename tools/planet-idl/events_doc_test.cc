// The events page (planet-idl --events-doc): what a condition sees of every IDL type, the
// comments it takes as documentation, who delivers each event; and docs/events.md, which must
// be exactly what the compiler writes for idl/*.idl now.
#include "events_doc.h"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

#include "parser.h"

namespace icars::planet::idl {
namespace {

namespace fs = std::filesystem;

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

// The page for `main.idl` (and the files it includes, from `files`).
std::string page(std::map<std::string, std::string> files) {
  MemoryReader reader(std::move(files));
  const Program program = parse_program("main.idl", {}, reader);
  return generate_events_doc({program.main});
}
std::string page(const std::string& text) { return page({{"main.idl", text}}); }

bool has(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

TEST(EventsDoc, EveryIdlTypeShowsWhatAConditionSees) {
  const auto doc = page(R"(
    module m {
      enum Color { red, green };
      valued Point { double x; double y; };
      event Everything {
        bool flag; byte b; short s; int i; long l; float f; double d; string text;
        binary audio; sequence<int> list; Color color; Point where;
      };
    };
  )");
  for (const auto* row :
       {"| `flag` | `bool` | bool |", "| `b` | `byte` | number |", "| `s` | `short` | number |",
        "| `i` | `int` | number |", "| `l` | `long` | number |", "| `f` | `float` | number |",
        "| `d` | `double` | number |", "| `text` | `string` | string |",
        "| `audio` | `binary` | absent |", "| `list` | `sequence<int>` | absent |",
        "| `color` | `m::Color` | absent |", "| `where` | `m::Point` | absent |"}) {
    EXPECT_TRUE(has(doc, row)) << row << "\n" << doc;
  }
  EXPECT_TRUE(has(doc, "\n## Everything\n\n`m::Everything`, in `main.idl`.\n")) << doc;
  EXPECT_TRUE(has(doc,
                  "| [`Everything`](#everything) | `main.idl` | flag, b, s, i, l, f, d, text, "
                  "audio, list, color, where |"))
      << doc;
}

TEST(EventsDoc, CommentsAboveAnEventAndAfterAFieldDocumentThem) {
  const auto doc = page(R"(
    module m {
      // --- Sensors ------------------------------------------------------------------
      // Someone sat down or got up:
      // one event per change.
      event Seat {
        string furniture;  // what it watches: "sofa" | "bed"
        bool occupied;     // somebody is on it,
                           // as the pressure mat says
        long time_ms; string where;  // two fields on a line: the comment is the last one's
      };

      event Bare { int n; };
    };
  )");
  EXPECT_TRUE(
      has(doc, "`m::Seat`, in `main.idl`. Someone sat down or got up: one event per change.\n"))
      << doc;
  EXPECT_TRUE(
      has(doc, "| `furniture` | `string` | string | what it watches: \"sofa\" \\| \"bed\" |"))
      << doc;
  EXPECT_TRUE(
      has(doc, "| `occupied` | `bool` | bool | somebody is on it, as the pressure mat says |"))
      << doc;
  EXPECT_TRUE(has(doc, "| `time_ms` | `long` | number |  |")) << doc;
  EXPECT_TRUE(has(
      doc, "| `where` | `string` | string | two fields on a line: the comment is the last one's |"))
      << doc;
  EXPECT_TRUE(has(doc, "`m::Bare`, in `main.idl`.\n")) << doc;
  EXPECT_FALSE(has(doc, "Sensors")) << "a section rule is no event's documentation\n" << doc;
}

TEST(EventsDoc, NamesTheListenersThatDeliverAnEventAndWhoTakesThem) {
  const auto doc = page({{"main.idl", R"(
    include "listeners.idl";
    module m {
      interface Sensor { void subscribe(m::SeatListener listener); void unsubscribe(m::SeatListener l); };
    };
  )"},
                         {"listeners.idl", R"(
    module m {
      event Seat { bool occupied; };
      interface SeatListener { oneway void on_seat(Seat seat); };
    };
  )"}});
  // Seat is declared in an included file: only main.idl's events are listed.
  EXPECT_FALSE(has(doc, "## Seat")) << doc;
  EXPECT_TRUE(has(doc, "No events are declared.")) << doc;

  const auto with_event = page(R"(
    module m {
      event Seat { bool occupied; };
      interface SeatListener { oneway void on_seat(Seat seat); };
      interface Sensor { void subscribe(SeatListener listener); void unsubscribe(SeatListener l); };
      interface Sofa : Sensor { bool occupied(); };
    };
  )");
  EXPECT_TRUE(
      has(with_event,
          "\nDelivered to `SeatListener.on_seat`; a `SeatListener` is taken by `Sensor.subscribe`, "
          "`Sensor.unsubscribe`.\n"))
      << with_event;
}

TEST(EventsDoc, ListsOnlyEventsInFileAndSourceOrderThroughNestedModules) {
  MemoryReader reader(
      {{"a.idl",
        "module a { event First { int n; }; valued V { int n; }; exception E { string why; };\n"
        "  module inner { event Second { bool b; }; }; };"},
       {"b.idl", "event Third { string s; };"}});
  const Program a = parse_program("a.idl", {}, reader);
  const Program b = parse_program("b.idl", {}, reader);
  const auto doc = generate_events_doc({a.main, b.main});
  const auto first = doc.find("## First"), second = doc.find("## Second"),
             third = doc.find("## Third");
  ASSERT_NE(third, std::string::npos) << doc;
  EXPECT_LT(first, second);
  EXPECT_LT(second, third);
  EXPECT_TRUE(has(doc, "`a::inner::Second`, in `a.idl`.")) << doc;
  EXPECT_TRUE(has(doc, "`Third`, in `b.idl`.")) << doc;
  EXPECT_FALSE(has(doc, "## V")) << doc;
  EXPECT_FALSE(has(doc, "## E")) << doc;
  EXPECT_TRUE(
      has(doc, "Generated by `planet-idl --events-doc` from `a.idl`, `b.idl`: do not edit."))
      << doc;
  EXPECT_EQ(doc, generate_events_doc({a.main, b.main}))
      << "the same input must give the same bytes";
}

std::string read(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

// docs/events.md is what `planet-idl --events-doc` writes for idl/*.idl (in name order), run in
// the source directory as the events_doc target runs it.
TEST(EventsDoc, TheCheckedInDocsEventsMdIsCurrent) {
  const fs::path source = ICARS_SOURCE_DIR;
  std::vector<std::string> idl;
  for (const auto& entry : fs::directory_iterator(source / "idl")) {
    if (entry.path().extension() == ".idl")
      idl.push_back("idl/" + entry.path().filename().string());
  }
  std::sort(idl.begin(), idl.end());
  ASSERT_FALSE(idl.empty());
  const fs::path out =
      fs::temp_directory_path() / ("events_doc_test_" + std::to_string(::getpid()) + ".md");
  std::string command = "cd '" + source.string() +
                        "' && '" PLANET_IDL_EXECUTABLE "' --events-doc '" + out.string() + "'";
  std::string inputs;
  for (const auto& f : idl) inputs += " " + f;
  command += inputs + " 2>&1";
  const int status = std::system(command.c_str());
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << command;
  const auto generated = read(out);
  fs::remove(out);
  const auto checked_in = read(source / "docs/events.md");
  if (generated == checked_in) return;
  std::istringstream g(generated), c(checked_in);
  std::string gl, cl;
  int line = 0;
  while (true) {
    const bool more_g = static_cast<bool>(std::getline(g, gl)),
               more_c = static_cast<bool>(std::getline(c, cl));
    ++line;
    if (!more_g && !more_c) break;
    if (!more_g || !more_c || gl != cl) break;
  }
  ADD_FAILURE() << "docs/events.md is out of date with idl/*.idl (first difference at line " << line
                << ":\n  checked in: " << cl << "\n  generated:  " << gl
                << "\n). Regenerate it with `cmake --build <build dir> --target events_doc`, or "
                   "from the source "
                   "directory: planet-idl --events-doc docs/events.md"
                << inputs;
}

}  // namespace
}  // namespace icars::planet::idl
