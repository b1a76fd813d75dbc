// The ScanNet layout: the fixture writer and the reader agree on every
// convention (world points from the read frames equal the written ones, the
// larger colour image resized to the depth's size), and broken files are
// named.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include <opencv2/core.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "long3r/synth/dataset_layouts.hpp"
#include "long3r/train/datasets/dataset_io.hpp"
#include "support/test_support.hpp"

namespace fs = std::filesystem;
using long3r::DatasetSource;
using long3r::RawFrame;
using long3r::datasets::DatasetScan;
using long3r::synth::LayoutFrame;

namespace {

// 16-bit millimetres: half a millimetre of rounding.
constexpr double kDepthTol = 0.5e-3 + 1e-6;

DatasetSource source_at(const std::string& root, const std::string& split = "train") {
  DatasetSource s;
  s.layout = "scannet";
  s.root = root;
  s.split = split;
  return s;
}

// The read frame against the written one: intrinsics, pose, depth within
// kDepthTol, JPEG colour (written at twice the size, read back at the
// depth's), and the world points.
void expect_same_frame(const RawFrame& got, const LayoutFrame& want) {
  const int h = want.depth_m.rows, w = want.depth_m.cols;
  ASSERT_EQ(got.depth.size(0), h);
  ASSERT_EQ(got.depth.size(1), w);
  ASSERT_EQ(got.bgr.size(0), h);
  ASSERT_EQ(got.bgr.size(1), w);
  const auto& k = got.intrinsics;
  const auto& kw = want.intrinsics;
  EXPECT_NEAR(k.fx, kw.fx, 1e-6 * kw.fx);
  EXPECT_NEAR(k.fy, kw.fy, 1e-6 * kw.fy);
  EXPECT_NEAR(k.cx, kw.cx, 1e-6 * kw.fx);
  EXPECT_NEAR(k.cy, kw.cy, 1e-6 * kw.fy);
  EXPECT_EQ(k.width, w);
  EXPECT_EQ(k.height, h);
  EXPECT_LT((got.T_W_C.matrix() - want.T_W_C.matrix()).cwiseAbs().maxCoeff(), 1e-6);

  const at::Tensor depth_t = got.depth.contiguous();
  const at::Tensor bgr_t = got.bgr.contiguous();
  const cv::Mat depth(h, w, CV_32F, depth_t.data_ptr<float>());
  const cv::Mat bgr(h, w, CV_8UC3, bgr_t.data_ptr<uint8_t>());
  EXPECT_LT(cv::norm(bgr, want.bgr, cv::NORM_L1) / (3.0 * w * h), 3.0);  // JPEG

  int64_t valid = 0;
  double worst_depth = 0, worst_point = 0;
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      const double z = depth.at<float>(v, u), zw = want.depth_m.at<float>(v, u);
      const bool want_valid = std::isfinite(zw) && zw > 0.0;
      if (!want_valid) {
        EXPECT_EQ(z, 0.0) << "at " << u << ", " << v;
        continue;
      }
      ASSERT_GT(z, 0.0) << "at " << u << ", " << v;
      ++valid;
      worst_depth = std::max(worst_depth, std::abs(z - zw));
      const Eigen::Vector3d p_cam = kw.backproject(u, v, zw);
      const Eigen::Vector3d truth = want.T_W_C * p_cam;
      const Eigen::Vector3d read = got.T_W_C * k.backproject(u, v, z);
      // A depth error dz moves the point along its ray by dz |p| / z.
      worst_point = std::max(worst_point, (read - truth).norm() - kDepthTol * p_cam.norm() / zw);
    }
  }
  EXPECT_GT(valid, 0);
  EXPECT_LE(worst_depth, kDepthTol);
  EXPECT_LE(worst_point, 1e-5);
}

const long3r::RecordedSource* find_sequence(const DatasetScan& scan, const std::string& scene) {
  for (const auto& s : scan.sequences) {
    if (s->name() == "scannet/" + scene) return s.get();
  }
  return nullptr;
}

// frame(i) throws RecordedFrameError naming `path`.
void expect_frame_error(const long3r::RecordedSource& seq, int64_t i, const std::string& path) {
  try {
    seq.frame(i);
    ADD_FAILURE() << "frame " << i << " read without error";
  } catch (const long3r::RecordedFrameError& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
  }
}

}  // namespace

TEST(DatasetScannet, RoundTrip) {
  const std::string root = long3r::test::scratch_dir("datasets/scannet");
  const std::vector<LayoutFrame> a = long3r::synth::render_layout_frames(31, 6, 48, 40);
  const std::vector<LayoutFrame> b = long3r::synth::render_layout_frames(32, 6, 48, 40);
  long3r::synth::write_scannet_sequence(root, "scene0000_00", a);
  long3r::synth::write_scannet_sequence(root, "scene0001_00", b);
  // Written again: the split list names it once.
  long3r::synth::write_scannet_sequence(root, "scene0001_00", b);
  // SimpleRecon's optional smaller colour copy is not a frame of its own.
  const fs::path data_a = fs::path(root) / "scans/scene0000_00/sensor_data";
  fs::copy_file(data_a / "frame-000000.color.jpg", data_a / "frame-000000.color.512.png");

  const DatasetScan scan = long3r::datasets::open_scannet(source_at(root));
  EXPECT_TRUE(scan.skipped.empty()) << (scan.skipped.empty() ? "" : scan.skipped.front());
  ASSERT_EQ(scan.sequences.size(), 2u);
  EXPECT_EQ(scan.sequences[0]->name(), "scannet/scene0000_00");
  EXPECT_EQ(scan.sequences[1]->name(), "scannet/scene0001_00");
  for (std::size_t s = 0; s < 2; ++s) {
    const std::vector<LayoutFrame>& want = s == 0 ? a : b;
    ASSERT_EQ(scan.sequences[s]->size(), 6);
    for (int64_t i = 0; i < 6; ++i) {
      SCOPED_TRACE("sequence " + std::to_string(s) + " frame " + std::to_string(i));
      expect_same_frame(scan.sequences[s]->frame(i), want[static_cast<std::size_t>(i)]);
    }
  }
}

TEST(DatasetScannet, BrokenFilesAreNamed) {
  const std::string root = long3r::test::scratch_dir("datasets/scannet_broken");
  const fs::path r(root);
  long3r::synth::write_scannet_sequence(root, "scene_a",
                                        long3r::synth::render_layout_frames(41, 6, 48, 40));
  long3r::synth::write_scannet_sequence(root, "scene_b",
                                        long3r::synth::render_layout_frames(42, 6, 48, 40));
  // Listed, never written.
  std::ofstream(r / "splits" / "scannetv2_train.txt", std::ios::app) << "scene_gone\n";

  // scene_a: a frame's depth missing, another's pose truncated, a third's
  // pose -inf (as ScanNet's frames with lost tracking).
  const fs::path data = r / "scans" / "scene_a" / "sensor_data";
  const std::string depth = (data / "frame-000002.depth.png").string();
  const std::string pose = (data / "frame-000003.pose.txt").string();
  const std::string lost = (data / "frame-000004.pose.txt").string();
  fs::remove(depth);
  fs::resize_file(pose, 10);
  std::ofstream(lost) << "-inf -inf -inf -inf\n-inf -inf -inf -inf\n"
                         "-inf -inf -inf -inf\n0 0 0 1\n";
  // scene_b: no depth intrinsics.
  const std::string k_b = (r / "scans" / "scene_b" / "intrinsic" / "intrinsic_depth.txt").string();
  fs::remove(k_b);

  const DatasetScan scan = long3r::datasets::open_scannet(source_at(root));
  ASSERT_EQ(scan.sequences.size(), 1u);
  ASSERT_EQ(scan.skipped.size(), 2u);
  EXPECT_NE(scan.skipped[0].find(k_b), std::string::npos) << scan.skipped[0];
  EXPECT_NE(scan.skipped[1].find((r / "scans" / "scene_gone").string()), std::string::npos)
      << scan.skipped[1];
  const long3r::RecordedSource* seq = find_sequence(scan, "scene_a");
  ASSERT_NE(seq, nullptr);
  EXPECT_EQ(seq->size(), 6);
  EXPECT_NO_THROW(seq->frame(1));
  expect_frame_error(*seq, 2, depth);
  expect_frame_error(*seq, 3, pose);
  expect_frame_error(*seq, 4, lost);

  // No split list: the dataset cannot be opened at all.
  try {
    long3r::datasets::open_scannet(source_at(root, "val"));
    ADD_FAILURE() << "opened without scannetv2_val.txt";
  } catch (const long3r::RecordedFrameError& e) {
    EXPECT_NE(std::string(e.what()).find("scannetv2_val.txt"), std::string::npos) << e.what();
  }
}
