// A stand-in for libFuzzer's main: runs LLVMFuzzerTestOneInput once on every file named on the
// command line, recursing into directories (in sorted order, so runs are repeatable).
// `-timeout=N` (default 10) fails an input that takes more than N seconds of CPU time, so an
// input kept because it once hung the fuzzer stays a failure until the hang is fixed.
//
// This is how the seed corpus and every past crashing input are replayed by the ordinary test
// run, with whatever sanitizers the build uses. A crash names the input on stderr before it
// happens; a missing path or an empty set of inputs is an error, so a renamed corpus directory
// cannot pass silently.
#include <algorithm>
#include <ctime>
#include <cstdlib>
#include <cstring>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);

namespace {

namespace fs = std::filesystem;

std::vector<std::uint8_t> read_file(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s FILE_OR_DIR...\n  runs the fuzz target on every file\n",
                 argv[0]);
    return 2;
  }
  std::vector<fs::path> files;
  double timeout_s = 10;
  for (int i = 1; i < argc; ++i) {
    if (std::strncmp(argv[i], "-timeout=", 9) == 0) {
      timeout_s = std::atof(argv[i] + 9);
      continue;
    }
    const fs::path arg(argv[i]);
    if (fs::is_directory(arg)) {
      for (const auto& entry : fs::recursive_directory_iterator(arg)) {
        if (entry.is_regular_file()) files.push_back(entry.path());
      }
    } else if (fs::is_regular_file(arg)) {
      files.push_back(arg);
    } else {
      std::fprintf(stderr, "replay: no file or directory '%s'\n", argv[i]);
      return 1;
    }
  }
  std::sort(files.begin(), files.end());
  if (files.empty()) {
    std::fprintf(stderr, "replay: no inputs found in the given paths\n");
    return 1;
  }
  int slow = 0;
  for (const fs::path& file : files) {
    std::fprintf(stderr, "replay: %s\n", file.string().c_str());
    const std::vector<std::uint8_t> data = read_file(file);
    // An empty vector's data() may be null; libFuzzer passes a valid pointer for empty inputs.
    static const std::uint8_t kEmpty = 0;
    const std::clock_t start = std::clock();
    LLVMFuzzerTestOneInput(data.empty() ? &kEmpty : data.data(), data.size());
    const double took = static_cast<double>(std::clock() - start) / CLOCKS_PER_SEC;
    if (took > timeout_s) {
      std::fprintf(stderr, "replay: %s took %.1f s of CPU time (limit %.0f s)\n",
                   file.string().c_str(), took, timeout_s);
      ++slow;
    }
  }
  if (slow != 0) {
    std::fprintf(stderr, "replay: %d of %zu inputs exceeded the time limit\n", slow, files.size());
    return 1;
  }
  std::printf("replay: %zu inputs ran without a crash\n", files.size());
  return 0;
}
