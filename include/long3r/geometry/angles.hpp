// Angle unit conversions, defined once.
#pragma once

#include <cmath>

namespace long3r {

inline constexpr double kRadToDeg = 180.0 / M_PI;
inline constexpr double kDegToRad = M_PI / 180.0;

}  // namespace long3r
