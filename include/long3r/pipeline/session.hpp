// Session files: a reconstruction's whole state in one file, so that mapping
// stops and continues later (another run, another day) in the same world
// frame, memory and map (LiveSession::save / load).
//
// The file is safetensors (self-describing, validated like a checkpoint,
// written atomically):
//   metadata  format "long3r_session", format_version "2" (version 1, read
//             too, is the same without the keyframes);
//             model.variant, model.config (JSON), model.weights (fingerprint,
//             ModelShell::weights_fingerprint); input_width, input_height,
//             voxel_size_m: what the saved state is only valid for; frames,
//             map_points, path_poses, scale: a summary for people and tools;
//   tensors   the state dict (state_dict.hpp): "reconstruction.*" (the
//             model's stream, map, path, tracker, intrinsics, scale, and
//             where they are on: the occupancy as OctoMap's .ot bytes, the
//             surface's kept frames; "reconstruction.keyframes.*": the
//             keyframe tracker's kept keyframes, keyframe_state.hpp),
//             "live.*" (the scale estimate),
//             "ended_maps.*" and "ended.*" (what ended streams left: their
//             points; their occupancy and surface with where they ended).
//             Parts a file lacks (older files, or saved with them off)
//             start empty.
// Other settings (thresholds, PnP, scale source) may change between runs:
// they act on frames to come, not on what the file holds.
#pragma once

#include <map>
#include <stdexcept>
#include <string>

#include "long3r/model/loading/state_dict.hpp"
#include "long3r/model/network/streaming.hpp"

namespace long3r {

// A session file that cannot be written or loaded: the message names the
// file and the problem.
class SessionError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

constexpr const char* kSessionFormat = "long3r_session";
constexpr const char* kSessionFormatVersion = "2";
// The oldest version this build reads (1: before the kept keyframes).
constexpr const char* kSessionFormatVersionOldest = "1";

// What a saved state is only valid for.
struct SessionIdentity {
  ModelIdentity model;
  int input_width = 0, input_height = 0;  // model input size (the token grid)
  double voxel_size_m = 0.0;              // of the map
};

// Writes state and identity (plus `summary` metadata) atomically: on any
// error the file at path is untouched. Throws SessionError.
void write_session(const std::string& path, const SessionIdentity& identity, const StateDict& state,
                   const std::map<std::string, std::string>& summary = {});

// Reads a session file and checks it against `expected`: SessionError for a
// file that is not a session, of another format version, damaged (anything
// the safetensors reader refuses) or made by another model or configuration,
// naming the difference (for a model configuration, the fields that differ).
StateDict read_session(const std::string& path, const SessionIdentity& expected);

// The metadata of a session file (its identity and summary), validated as a
// session but not checked against a model. Throws SessionError.
std::map<std::string, std::string> read_session_metadata(const std::string& path);

}  // namespace long3r
