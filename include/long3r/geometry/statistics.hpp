// Robust statistics shared by the tracker, the scale estimates and the
// evaluation, written once.
#pragma once

#include <vector>

namespace long3r {

// The median (numpy's: the mean of the middle pair for an even count); 0 for
// an empty input. Takes its argument by value: it is reordered.
double median(std::vector<double> values);

}  // namespace long3r
