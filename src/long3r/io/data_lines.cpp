#include "long3r/io/data_lines.hpp"

#include <algorithm>
#include <fstream>
#include <stdexcept>

namespace long3r {

std::vector<std::pair<int, std::string>> data_lines(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot open " + path);
  std::vector<std::pair<int, std::string>> out;
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    const size_t hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    std::replace(line.begin(), line.end(), ',', ' ');
    if (line.find_first_not_of(" \t\r\n") == std::string::npos) continue;
    out.emplace_back(number, line);
  }
  return out;
}

}  // namespace long3r
