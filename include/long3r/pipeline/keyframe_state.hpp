// The keyframe tracker's kept keyframes in saved states (sessions;
// state_dict.hpp), so that a loaded session relocalises by images:
//   version      1 (a later layout is refused by name)
//   offsets      int64 [keyframes + 1]: keyframe i owns features
//                offsets[i] .. offsets[i + 1] of the tensors below
//   T_W_K        float64 [keyframes, 4, 4]
//   pixels       float32 [features, 2]: full-resolution image pixels
//   bearings     float32 [features, 3]: unit rays in K
//   points       float32 [features, 3]: in K, the stream's scale; NaN: none
//   descriptors  uint8 [features, 32]: ORB
#pragma once

#include <deque>
#include <string>
#include <vector>

#include "long3r/model/loading/state_dict.hpp"
#include "long3r/tracking/keyframe_tracker.hpp"

namespace long3r {

// Adds the keyframes to `out` under `prefix` ("keyframes.").
void put_keyframes(StateDict& out, const std::string& prefix,
                   const std::deque<KeptKeyframe>& keyframes);
// The keyframes under r's prefix; StateError naming the entry for anything
// put_keyframes() would not have written (another version, lengths that do
// not add up, rays that are not unit, poses that are not rigid).
std::vector<KeptKeyframe> read_keyframes(const StateReader& r);

}  // namespace long3r
