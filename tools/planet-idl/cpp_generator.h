// planet-idl C++ generator: the C++ mapping of one checked IDL file (docs/idl.md, "C++ mapping").
//
// For `x.idl` it produces `x.planet.h` (types, TypeName/ValuedFields/EventFields
// specialisations, interface descriptions, proxies and servant bases; templates inline) and
// `x.planet.cc` (exception constructors, exception translators and servant constructors). The
// output depends only on the AST, so regenerating an unchanged file yields identical bytes.
#pragma once

#include <string>

#include "ast.h"

namespace icars::planet::idl {

struct GeneratedCpp {
  std::string header_name;  // "x.planet.h"
  std::string source_name;  // "x.planet.cc"
  std::string header;
  std::string source;
};

// The generated file names for an IDL path: "dir/x.idl" -> "x.planet.h" / "x.planet.cc".
std::string header_name_for(std::string_view idl_path);
std::string source_name_for(std::string_view idl_path);

GeneratedCpp generate_cpp(const SourceFile& file);

}  // namespace icars::planet::idl
