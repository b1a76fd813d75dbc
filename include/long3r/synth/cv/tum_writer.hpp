// Generated sequences written as TUM RGB-D folders (library long3r_synth_cv),
// which long3r_reconstruct, long3r_eval, the dataset reader and
// scripts/tum_to_bag.py read like recorded data.
#pragma once

#include <functional>
#include <string>

#include "long3r/synth/generate.hpp"
#include "long3r/synth/render.hpp"

namespace long3r::synth {

struct WriteStats {
  int frames = 0;
  double render_seconds = 0.0;  // wall time spent rendering
  double write_seconds = 0.0;   // wall time spent encoding and writing files
};

// Writes the TUM layout (see tum_dataset.hpp) into `dir` (created):
// rgb/<t>.png (colour, or grey with sensor.mono), depth/<t>.png (uint16,
// metres * 5000, 0 beyond 13.1 m, registered to the image's pixels), rgb.txt,
// depth.txt, groundtruth.txt, calibration.txt (with the plumb_bob
// coefficients when distorted), plus scene.json (config and scene
// description). <t> is the timestamp with 6 decimals. Robot paths add
// base_groundtruth.txt (T_W_B, TUM format) and camera_mount.txt (T_B_C, the
// optical frame in base_link); exposure effects add exposure.txt ("timestamp
// gain"). `progress(i, n)` is called after each image when given.
// image_every > 1 renders and lists only every image_every-th frame from the
// first (a camera slower than the path's sampling, the same images as the
// full write at those frames) while the ground truth and the exposure keep
// every frame, as a motion-capture system records more often than the camera.
WriteStats write_tum_sequence(const Sequence& sequence, const std::string& dir,
                              const RenderOptions& options = {},
                              const std::function<void(int, int)>& progress = {},
                              int image_every = 1);

// Depth PNG scale shared with the TUM reader's default.
constexpr double kTumDepthFactor = 5000.0;

}  // namespace long3r::synth
