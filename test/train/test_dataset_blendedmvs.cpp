// The BlendedMVS layout: the fixture writer and the reader agree on every
// convention (world points from the read frames equal the written ones), and
// broken files are named.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

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

DatasetSource source_at(const std::string& root, const std::string& split = "train") {
  DatasetSource s;
  s.layout = "blendedmvs";
  s.root = root;
  s.split = split;
  return s;
}

// The read frame against the written one: intrinsics, pose, depth within
// depth_rel (relative) + 1e-6 m, JPEG colour, and the world points.
void expect_same_frame(const RawFrame& got, const LayoutFrame& want, double depth_rel) {
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
  // JPEG: within 3 grey levels on average (in grey, as JPEG keeps the
  // colour at half resolution, which the generated fine texture shows).
  cv::Mat grey, want_grey;
  cv::cvtColor(bgr, grey, cv::COLOR_BGR2GRAY);
  cv::cvtColor(want.bgr, want_grey, cv::COLOR_BGR2GRAY);
  EXPECT_LT(cv::norm(grey, want_grey, cv::NORM_L1) / (1.0 * w * h), 3.0);

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
      worst_depth = std::max(worst_depth, std::abs(z - zw) - depth_rel * zw);
      const Eigen::Vector3d p_cam = kw.backproject(u, v, zw);
      const Eigen::Vector3d truth = want.T_W_C * p_cam;
      const Eigen::Vector3d read = got.T_W_C * k.backproject(u, v, z);
      worst_point = std::max(worst_point, (read - truth).norm() - depth_rel * p_cam.norm());
    }
  }
  EXPECT_GT(valid, 0);
  EXPECT_LE(worst_depth, 1e-6);
  EXPECT_LE(worst_point, 1e-5);
}

const long3r::RecordedSource* find_sequence(const DatasetScan& scan, const std::string& scene) {
  for (const auto& s : scan.sequences) {
    if (s->name() == "blendedmvs/" + scene) return s.get();
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

TEST(DatasetBlendedmvs, RoundTrip) {
  const std::string root = long3r::test::scratch_dir("datasets/blendedmvs");
  const std::vector<LayoutFrame> a = long3r::synth::render_layout_frames(11, 6, 48, 40);
  const std::vector<LayoutFrame> b = long3r::synth::render_layout_frames(12, 6, 48, 40);
  long3r::synth::write_blendedmvs_sequence(root, "scene_a", a);
  long3r::synth::write_blendedmvs_sequence(root, "scene_b", b);
  // A masked copy beside an image is not a view of its own.
  fs::copy_file(fs::path(root) / "scene_a/blended_images/00000000.jpg",
                fs::path(root) / "scene_a/blended_images/00000000_masked.jpg");

  const DatasetScan scan = long3r::datasets::open_blendedmvs(source_at(root));
  EXPECT_TRUE(scan.skipped.empty()) << (scan.skipped.empty() ? "" : scan.skipped.front());
  ASSERT_EQ(scan.sequences.size(), 2u);
  EXPECT_EQ(scan.sequences[0]->name(), "blendedmvs/scene_a");
  EXPECT_EQ(scan.sequences[1]->name(), "blendedmvs/scene_b");
  for (std::size_t s = 0; s < 2; ++s) {
    const std::vector<LayoutFrame>& want = s == 0 ? a : b;
    ASSERT_EQ(scan.sequences[s]->size(), 6);
    for (int64_t i = 0; i < 6; ++i) {
      SCOPED_TRACE("sequence " + std::to_string(s) + " frame " + std::to_string(i));
      // PFM holds the float depth as written.
      expect_same_frame(scan.sequences[s]->frame(i), want[static_cast<std::size_t>(i)], 1e-7);
    }
  }
}

TEST(DatasetBlendedmvs, BrokenFilesAreNamed) {
  const std::string root = long3r::test::scratch_dir("datasets/blendedmvs_broken");
  const fs::path r(root);
  long3r::synth::write_blendedmvs_sequence(root, "scene_a",
                                           long3r::synth::render_layout_frames(21, 6, 48, 40));
  long3r::synth::write_blendedmvs_sequence(root, "scene_b",
                                           long3r::synth::render_layout_frames(22, 6, 48, 40));
  long3r::synth::write_blendedmvs_sequence(root, "scene_c",
                                           long3r::synth::render_layout_frames(23, 6, 48, 40));

  // A frame's depth missing, another's camera file truncated.
  const std::string depth = (r / "scene_a" / "rendered_depth_maps" / "00000002.pfm").string();
  const std::string cam = (r / "scene_a" / "cams" / "00000003_cam.txt").string();
  fs::remove(depth);
  fs::resize_file(cam, 30);
  // scene_b's pair.txt malformed, scene_c's naming a view without an image.
  const std::string pairs_b = (r / "scene_b" / "cams" / "pair.txt").string();
  const std::string pairs_c = (r / "scene_c" / "cams" / "pair.txt").string();
  std::ofstream(pairs_b) << "6\n0\nthree 1 0.5\n";
  std::ofstream(pairs_c) << "1\n0\n1 99 0.5\n";

  const DatasetScan scan = long3r::datasets::open_blendedmvs(source_at(root));
  ASSERT_EQ(scan.sequences.size(), 1u);
  ASSERT_EQ(scan.skipped.size(), 2u);
  EXPECT_NE(scan.skipped[0].find(pairs_b), std::string::npos) << scan.skipped[0];
  EXPECT_NE(scan.skipped[1].find(pairs_c), std::string::npos) << scan.skipped[1];
  const long3r::RecordedSource* seq = find_sequence(scan, "scene_a");
  ASSERT_NE(seq, nullptr);
  EXPECT_NO_THROW(seq->frame(1));
  expect_frame_error(*seq, 2, depth);
  expect_frame_error(*seq, 3, cam);

  // No split list: the dataset cannot be opened at all.
  try {
    long3r::datasets::open_blendedmvs(source_at(root, "val"));
    ADD_FAILURE() << "opened without val_list.txt";
  } catch (const long3r::RecordedFrameError& e) {
    EXPECT_NE(std::string(e.what()).find("val_list.txt"), std::string::npos) << e.what();
  }
}
