// `icars merge-traces`: the traces of the servers of one logical mediating server (icars serve
// --trace, each record naming its server) merged into one timeline, in the house's time.
#pragma once

#include <string>
#include <vector>

namespace icars::app {

// Writes the records of `files` to `output` ("" or "-": stdout) ordered by the machine's time
// when every record has it ("wall_us", written by icars serve: several servers' house clocks
// differ by up to a poll of the house's), by the house's time ("t") otherwise; records of equal
// time in the order of the files given and of their lines. A record without
// "server" is given its file's name (without directory and extension). Returns the exit code:
// 0, or 2 for a file that cannot be read or a line that is not a JSON object with a time (named
// with its file and line).
int merge_traces(const std::vector<std::string>& files, const std::string& output);

}  // namespace icars::app
