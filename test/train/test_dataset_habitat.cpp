// The Habitat layout (CroCo's generator): the fixture writer and the reader
// agree on every convention (world points from the read frames equal the
// written ones), and broken files are named.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <stdexcept>
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
  s.layout = "habitat";
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

const long3r::RecordedSource* find_sequence(const DatasetScan& scan, const std::string& group) {
  for (const auto& s : scan.sequences) {
    if (s->name() == "habitat/" + group) return s.get();
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

TEST(DatasetHabitat, RoundTrip) {
  const std::string root = long3r::test::scratch_dir("datasets/habitat");
  // Two groups of 5 views in each of two scenes of two datasets.
  const std::vector<LayoutFrame> a = long3r::synth::render_layout_frames(31, 10, 48, 40);
  const std::vector<LayoutFrame> b = long3r::synth::render_layout_frames(32, 10, 48, 40);
  long3r::synth::write_habitat_sequence(root, "gibson/scene_a", a);
  long3r::synth::write_habitat_sequence(root, "mp3d/scene_b", b);
  EXPECT_THROW(long3r::synth::write_habitat_sequence(
                   root, "mp3d/scene_c", long3r::synth::render_layout_frames(33, 7, 48, 40)),
               std::invalid_argument);

  const DatasetScan scan = long3r::datasets::open_habitat(source_at(root));
  EXPECT_TRUE(scan.skipped.empty()) << (scan.skipped.empty() ? "" : scan.skipped.front());
  ASSERT_EQ(scan.sequences.size(), 4u);
  const char* names[] = {"gibson/scene_a/00000000", "gibson/scene_a/00000001",
                         "mp3d/scene_b/00000000", "mp3d/scene_b/00000001"};
  for (std::size_t s = 0; s < 4; ++s) {
    EXPECT_EQ(scan.sequences[s]->name(), std::string("habitat/") + names[s]);
    const std::vector<LayoutFrame>& want = s < 2 ? a : b;
    ASSERT_EQ(scan.sequences[s]->size(), 5);
    for (int64_t i = 0; i < 5; ++i) {
      SCOPED_TRACE("sequence " + std::to_string(s) + " view " + std::to_string(i + 1));
      // Half-float EXR: 11 significant bits, within 1e-3 relative.
      expect_same_frame(scan.sequences[s]->frame(i),
                        want[static_cast<std::size_t>(5 * (s % 2) + i)], 1e-3);
    }
  }
  // No split file: every split is the whole folder.
  EXPECT_EQ(long3r::datasets::open_habitat(source_at(root, "test")).sequences.size(), 4u);
}

TEST(DatasetHabitat, BrokenFilesAreNamed) {
  const std::string root = long3r::test::scratch_dir("datasets/habitat_broken");
  const fs::path r(root);
  long3r::synth::write_habitat_sequence(root, "gibson/scene_a",
                                        long3r::synth::render_layout_frames(41, 10, 48, 40));

  // View 3 of group 0 without its depth, view 2 of group 1 with a truncated
  // camera file.
  const std::string depth = (r / "gibson" / "scene_a" / "00000000_3_depth.exr").string();
  const std::string params = (r / "gibson" / "scene_a" / "00000001_2_camera_params.json").string();
  fs::remove(depth);
  fs::resize_file(params, 40);
  // View 4 of a third group without its camera file: that group is left out.
  long3r::synth::write_habitat_sequence(root, "gibson/scene_a",
                                        long3r::synth::render_layout_frames(42, 5, 48, 40));
  const std::string lost = (r / "gibson" / "scene_a" / "00000002_4_camera_params.json").string();
  fs::remove(lost);

  const DatasetScan scan = long3r::datasets::open_habitat(source_at(root));
  ASSERT_EQ(scan.sequences.size(), 2u);
  ASSERT_EQ(scan.skipped.size(), 1u);
  EXPECT_NE(scan.skipped[0].find(lost), std::string::npos) << scan.skipped[0];
  const long3r::RecordedSource* g0 = find_sequence(scan, "gibson/scene_a/00000000");
  const long3r::RecordedSource* g1 = find_sequence(scan, "gibson/scene_a/00000001");
  ASSERT_NE(g0, nullptr);
  ASSERT_NE(g1, nullptr);
  EXPECT_NO_THROW(g0->frame(1));
  expect_frame_error(*g0, 2, depth);
  expect_frame_error(*g1, 1, params);

  // No root: the dataset cannot be opened at all.
  const std::string none = (r / "nowhere").string();
  try {
    long3r::datasets::open_habitat(source_at(none));
    ADD_FAILURE() << "opened a missing folder";
  } catch (const long3r::RecordedFrameError& e) {
    EXPECT_NE(std::string(e.what()).find(none), std::string::npos) << e.what();
  }
}
