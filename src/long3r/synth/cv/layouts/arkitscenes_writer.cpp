// Frames written as an ARKitScenes raw low-resolution video (the layout that
// train/cv/datasets/arkitscenes.cpp reads, as Spann3R does):
//   <root>/raw/Training/<name>/lowres_wide/<name>_<ts>.png, lowres_depth/ (uint16
//   millimetres), lowres_wide_intrinsics/<name>_<ts>.pincam, lowres_wide.traj.
#include <Eigen/Geometry>
#include <opencv2/imgcodecs.hpp>

#include <cstdio>
#include <sstream>
#include <string>
#include <vector>

#include "long3r/synth/cv/dataset_layouts.hpp"
#include "long3r/synth/cv/layouts/layout_files.hpp"

namespace long3r::synth {

namespace {

std::string number(const char* format, double v) {
  char text[64];
  std::snprintf(text, sizeof(text), format, v);
  return text;
}

}  // namespace

void write_arkitscenes_sequence(const std::string& root, const std::string& name,
                                const std::vector<LayoutFrame>& frames) {
  const std::string dir = root + "/raw/Training/" + name;
  for (const char* sub : {"/lowres_wide", "/lowres_depth", "/lowres_wide_intrinsics"}) {
    layouts::make_dirs(dir + sub);
  }
  std::ostringstream traj;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const LayoutFrame& f = frames[i];
    // 10 Hz from 1000 s; the file names carry 3 decimals.
    const double ts = 1000.0 + 0.1 * static_cast<double>(i);
    const std::string stem = name + "_" + number("%.3f", ts);
    layouts::write_image(dir + "/lowres_wide/" + stem + ".png", f.bgr);
    layouts::write_image(dir + "/lowres_depth/" + stem + ".png", layouts::depth_mm(f.depth_m));

    const PinholeIntrinsics& k = f.intrinsics;
    layouts::write_text(dir + "/lowres_wide_intrinsics/" + stem + ".pincam",
                        std::to_string(f.depth_m.cols) + ' ' + std::to_string(f.depth_m.rows) +
                            ' ' + number("%.17g", k.fx) + ' ' + number("%.17g", k.fy) + ' ' +
                            number("%.17g", k.cx) + ' ' + number("%.17g", k.cy) + '\n');

    // World to camera as a rotation vector and translation. The trajectory's
    // clock is finer than the names' (a fraction of a millisecond off), as
    // in the real data, so the reader must round it.
    const Eigen::Isometry3d T_C_W = f.T_W_C.inverse();
    const Eigen::AngleAxisd aa(T_C_W.rotation());
    const Eigen::Vector3d r = aa.angle() * aa.axis();
    const Eigen::Vector3d t = T_C_W.translation();
    traj << number("%.6f", ts + 0.0003);
    for (int j = 0; j < 3; ++j) traj << ' ' << number("%.17g", r[j]);
    for (int j = 0; j < 3; ++j) traj << ' ' << number("%.17g", t[j]);
    traj << '\n';
  }
  layouts::write_text(dir + "/lowres_wide.traj", traj.str());
}

}  // namespace long3r::synth
