// A sequence written as a ScanNet scene in the layout Spann3R reads
// (src/long3r/train/cv/datasets/scannet.cpp has the layout): JPEG colour at
// twice the depth's size (ScanNet's colour camera has more pixels than its
// depth camera), 16-bit millimetre depth, camera-to-world pose text files,
// the intrinsics of both images, and the scene added to
// splits/scannetv2_train.txt.
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <cstdio>
#include <filesystem>
#include <sstream>
#include <stdexcept>

#include "long3r/synth/cv/dataset_layouts.hpp"
#include "long3r/synth/cv/layouts/layout_files.hpp"

namespace long3r::synth {

namespace {

namespace fs = std::filesystem;

void write_matrix(const std::string& path, const Eigen::Matrix4d& m) {
  std::ostringstream out;
  out.precision(17);
  for (int r = 0; r < 4; ++r) {
    out << m(r, 0) << " " << m(r, 1) << " " << m(r, 2) << " " << m(r, 3) << "\n";
  }
  layouts::write_text(path, out.str());
}

// ScanNet's intrinsic_*.txt: K in the top-left corner of a 4 x 4 identity.
Eigen::Matrix4d k4(const PinholeIntrinsics& k) {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.topLeftCorner<3, 3>() = k.matrix();
  return m;
}

}  // namespace

void write_scannet_sequence(const std::string& root, const std::string& name,
                            const std::vector<LayoutFrame>& frames) {
  if (frames.empty()) throw std::invalid_argument("write_scannet_sequence: no frames");
  const fs::path dir = fs::path(root) / "scans" / name;
  for (const char* sub : {"intrinsic", "sensor_data"}) layouts::make_dirs((dir / sub).string());
  // One K per scene, as in ScanNet.
  const PinholeIntrinsics& k = frames.front().intrinsics;
  for (const LayoutFrame& f : frames) {
    if (f.intrinsics.fx != k.fx || f.intrinsics.fy != k.fy || f.intrinsics.cx != k.cx ||
        f.intrinsics.cy != k.cy) {
      throw std::invalid_argument("write_scannet_sequence: a scene has one camera (intrinsics)");
    }
  }
  write_matrix((dir / "intrinsic" / "intrinsic_depth.txt").string(), k4(k));
  // The colour image's K, twice the size with the pixel centres aligned
  // (c' = 2 (c + 0.5) - 0.5); written as ScanNet has it, not read.
  PinholeIntrinsics kc = k;
  kc.fx *= 2.0;
  kc.fy *= 2.0;
  kc.cx = 2.0 * (k.cx + 0.5) - 0.5;
  kc.cy = 2.0 * (k.cy + 0.5) - 0.5;
  write_matrix((dir / "intrinsic" / "intrinsic_color.txt").string(), k4(kc));

  const fs::path data = dir / "sensor_data";
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const LayoutFrame& f = frames[i];
    char stem[32];
    std::snprintf(stem, sizeof(stem), "frame-%06zu", i);
    const std::string image = (data / (std::string(stem) + ".color.jpg")).string();
    const std::string depth = (data / (std::string(stem) + ".depth.png")).string();
    // Each pixel doubled (nearest), so that the reader's area resize back
    // to the depth's size gives the frame's colour again, JPEG aside.
    cv::Mat big;
    cv::resize(f.bgr, big, cv::Size(2 * f.bgr.cols, 2 * f.bgr.rows), 0, 0, cv::INTER_NEAREST);
    layouts::write_image(image, big, {cv::IMWRITE_JPEG_QUALITY, 95});
    layouts::write_image(depth, layouts::depth_mm(f.depth_m));
    write_matrix((data / (std::string(stem) + ".pose.txt")).string(), f.T_W_C.matrix());
  }

  // In the "train" split, once however often the scene is written.
  layouts::list_once((fs::path(root) / "splits" / "scannetv2_train.txt").string(), name);
}

}  // namespace long3r::synth
