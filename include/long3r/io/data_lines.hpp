// The lines of a text data file (TUM lists, trajectories, calibration and
// pose files, .xyz clouds).
#pragma once

#include <string>
#include <utility>
#include <vector>

namespace long3r {

// The lines of `path` with '#' comments and blank lines dropped and commas
// made spaces, each with its 1-based line number for error messages. Throws
// std::runtime_error when the file cannot be opened.
std::vector<std::pair<int, std::string>> data_lines(const std::string& path);

}  // namespace long3r
