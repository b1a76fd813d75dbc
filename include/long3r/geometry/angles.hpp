// Angle unit conversions, defined once.
#pragma once

#include <cmath>

namespace long3r {

inline constexpr double kRadToDeg = 180.0 / M_PI;

}  // namespace long3r
