#include "long3r/io/version.hpp"

namespace long3r {

const char* version() { return "0.1.0"; }

}  // namespace long3r
