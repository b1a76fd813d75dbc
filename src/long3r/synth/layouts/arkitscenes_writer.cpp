// Frames written as an ARKitScenes raw low-resolution video (the layout that
// train/datasets/arkitscenes.cpp reads, as Spann3R does):
//   <root>/raw/Training/<name>/lowres_wide/<name>_<ts>.png, lowres_depth/ (uint16
//   millimetres), lowres_wide_intrinsics/<name>_<ts>.pincam, lowres_wide.traj.
#include <Eigen/Geometry>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>
#include <system_error>
#include <vector>

#include "long3r/synth/dataset_layouts.hpp"

namespace long3r::synth {

namespace {

void write_png(const std::string& path, const cv::Mat& image) {
  bool ok = false;
  try {
    ok = cv::imwrite(path, image);
  } catch (const cv::Exception&) {
    ok = false;
  }
  if (!ok) throw std::runtime_error(path + ": cannot be written");
}

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
    std::error_code ec;
    std::filesystem::create_directories(dir + sub, ec);
    if (ec) throw std::runtime_error(dir + sub + ": cannot be created (" + ec.message() + ")");
  }
  const std::string traj_path = dir + "/lowres_wide.traj";
  std::ofstream traj(traj_path);
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const LayoutFrame& f = frames[i];
    // 10 Hz from 1000 s; the file names carry 3 decimals.
    const double ts = 1000.0 + 0.1 * static_cast<double>(i);
    const std::string stem = name + "_" + number("%.3f", ts);
    write_png(dir + "/lowres_wide/" + stem + ".png", f.bgr);

    cv::Mat depth_mm(f.depth_m.size(), CV_16U);
    for (int r = 0; r < depth_mm.rows; ++r) {
      const float* d = f.depth_m.ptr<float>(r);
      uint16_t* o = depth_mm.ptr<uint16_t>(r);
      for (int c = 0; c < depth_mm.cols; ++c) {
        const double mm = std::isfinite(d[c]) && d[c] > 0.0f ? std::round(d[c] * 1000.0) : 0.0;
        o[c] = static_cast<uint16_t>(std::min(mm, 65535.0));
      }
    }
    write_png(dir + "/lowres_depth/" + stem + ".png", depth_mm);

    const std::string pincam_path = dir + "/lowres_wide_intrinsics/" + stem + ".pincam";
    std::ofstream pincam(pincam_path);
    const PinholeIntrinsics& k = f.intrinsics;
    pincam << f.depth_m.cols << ' ' << f.depth_m.rows << ' ' << number("%.17g", k.fx) << ' '
           << number("%.17g", k.fy) << ' ' << number("%.17g", k.cx) << ' ' << number("%.17g", k.cy)
           << '\n';
    if (!pincam.flush()) throw std::runtime_error(pincam_path + ": cannot be written");

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
  if (!traj.flush()) throw std::runtime_error(traj_path + ": cannot be written");
}

}  // namespace long3r::synth
