#include "long3r/geometry/statistics.hpp"

#include <algorithm>
#include <cstddef>
#include <iterator>

namespace long3r {

double median(std::vector<double> values) {
  if (values.empty()) return 0.0;
  const std::size_t n = values.size();
  const auto mid = values.begin() + static_cast<std::ptrdiff_t>(n / 2);
  std::nth_element(values.begin(), mid, values.end());
  const double upper = *mid;
  if (n % 2 == 1) return upper;
  return 0.5 * (*std::max_element(values.begin(), mid) + upper);
}

}  // namespace long3r
