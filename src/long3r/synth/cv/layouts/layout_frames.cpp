// Generated frames for the dataset-layout writers; see
// include/long3r/synth/cv/dataset_layouts.hpp.
#include <stdexcept>

#include "long3r/synth/cv/dataset_layouts.hpp"
#include "long3r/synth/cv/sensor_image.hpp"
#include "long3r/synth/generate.hpp"
#include "long3r/synth/render.hpp"

namespace long3r::synth {

std::vector<LayoutFrame> render_layout_frames(uint64_t seed, int frames, int width, int height) {
  if (frames < 1 || width < 8 || height < 8) {
    throw std::invalid_argument("render_layout_frames: need frames >= 1 and an image of 8 x 8+");
  }
  SequenceConfig c;
  c.seed = seed;
  c.intrinsics = PinholeIntrinsics::from_hfov(width, height, 65.0);
  // Off the centre, and fx != fy, so that a reader swapping or re-centring
  // them is caught.
  c.intrinsics.fy *= 1.05;
  c.intrinsics.cx += 0.07 * width;
  c.intrinsics.cy -= 0.05 * height;
  c.trajectory.type = TrajectoryType::kWalk;
  c.trajectory.frames = frames;
  const Sequence seq = generate_sequence(c);
  std::vector<LayoutFrame> out;
  for (int i = 0; i < frames; ++i) {
    const RenderedFrame r =
        render_frame(seq.scene, seq.poses[static_cast<std::size_t>(i)], c.intrinsics);
    LayoutFrame f;
    f.bgr = bgr_image(r).clone();
    f.depth_m = depth_image(r).clone();
    f.intrinsics = c.intrinsics;
    f.T_W_C = seq.poses[static_cast<std::size_t>(i)];
    out.push_back(std::move(f));
  }
  return out;
}

}  // namespace long3r::synth
