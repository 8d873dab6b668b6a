// planet-idl: the PLANET IDL compiler (docs/idl.md).
//
//   planet-idl [-I dir]... --output-dir DIR [--depfile FILE] file.idl...
//   planet-idl [-I dir]... --events-doc FILE.md file.idl...
//
// Writes DIR/<stem>.planet.h and DIR/<stem>.planet.cc for every input, and/or FILE.md, the
// Markdown page of the inputs' events (docs/events.md is one). Errors go to stderr as
// `file:line:column: error: ...`; the exit code is 1 when any input failed, 2 for bad usage.
#include <CLI/CLI.hpp>
#include <exception>
#include <iostream>

#include "driver.h"

int main(int argc, char** argv) {
  namespace idl = icars::planet::idl;
  CLI::App app{"planet-idl: compiles PLANET IDL files into C++ (see docs/idl.md)"};
  idl::DriverOptions options;
  app.add_option("-I,--import-dir", options.import_dirs,
                 "A directory searched for included files, after the including file's own");
  app.add_option("-o,--output-dir", options.output_dir,
                 "Where <stem>.planet.h and <stem>.planet.cc are written");
  app.add_option("--events-doc", options.events_doc,
                 "Also (or only) write a Markdown page of the inputs' events and their fields");
  app.add_option("--depfile", options.depfile,
                 "Also write a Makefile-style dependency file naming every IDL file read");
  app.add_option("files", options.inputs, "The IDL files to compile")->required();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }
  if (options.output_dir.empty() && options.events_doc.empty()) {
    std::cerr << "planet-idl: error: nothing to write, expected --output-dir DIR (C++), "
                 "--events-doc FILE.md (the events' page) or both\n";
    return 2;
  }
  try {
    return idl::run_driver(options, std::cerr);
  } catch (const std::exception& e) {
    std::cerr << "planet-idl: error: " << e.what() << '\n';
    return 1;
  }
}
