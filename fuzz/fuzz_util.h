// Helpers shared by the fuzz targets: invariant checks and a way to see why inputs are rejected.
#pragma once

#include <cstdio>
#include <cstdlib>

namespace icars_fuzz {

// A broken invariant is a bug the fuzzer must report: print what broke and abort.
inline void check(bool ok, const char* target, const char* what) {
  if (ok) return;
  std::fprintf(stderr, "%s: broken invariant: %s\n", target, what);
  std::abort();
}

// With ICARS_FUZZ_VERBOSE set, prints the error an input was (correctly) rejected with; useful
// to see how far a seed gets, e.g. `ICARS_FUZZ_VERBOSE=1 payload_fuzz_replay corpus/payload_fuzz`.
inline void note_rejected(const char* target, const char* error) {
  static const bool verbose = std::getenv("ICARS_FUZZ_VERBOSE") != nullptr;
  if (verbose) std::fprintf(stderr, "%s: rejected: %s\n", target, error);
}

}  // namespace icars_fuzz
