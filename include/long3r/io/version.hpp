// Version of the long3r core library.
#pragma once

namespace long3r {

const char* version();

}  // namespace long3r
