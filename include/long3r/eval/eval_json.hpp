// The evaluation's figures as JSON (nlohmann's to_json: `json j = stats;`),
// one form for every tool that writes them (long3r_eval's metrics.json,
// long3r_reconstruct's fusion_split.json).
#pragma once

#include <nlohmann/json.hpp>

#include "long3r/eval/eval.hpp"

namespace long3r {

// rmse, mean, median, std, min, max, sse, count.
void to_json(nlohmann::json& j, const ErrorStatistics& s);

}  // namespace long3r
