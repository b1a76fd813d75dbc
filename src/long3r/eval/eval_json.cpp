#include "long3r/eval/eval_json.hpp"

namespace long3r {

void to_json(nlohmann::json& j, const ErrorStatistics& s) {
  j = {{"rmse", s.rmse}, {"mean", s.mean}, {"median", s.median}, {"std", s.std},
       {"min", s.min},   {"max", s.max},   {"sse", s.sse},       {"count", s.count}};
}

}  // namespace long3r
