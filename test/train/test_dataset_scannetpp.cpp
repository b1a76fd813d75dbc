// The ScanNet++ layout: the fixture writer and the reader agree on every
// convention (world points from the read frames equal the written ones, the
// poses stored in OpenGL camera axes), and broken files are named.
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
  s.layout = "scannetpp";
  s.root = root;
  s.split = split;
  return s;
}

fs::path dslr_of(const std::string& root, const std::string& scene) {
  return fs::path(root) / "data" / scene / "dslr";
}

void write_json(const fs::path& path, const nlohmann::json& j) {
  std::ofstream(path) << j.dump(2) << "\n";
}

// The read frame against the written one: intrinsics, pose, depth within
// kDepthTol, JPEG colour, and the world points.
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
    if (s->name() == "scannetpp/" + scene) return s.get();
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

TEST(DatasetScannetpp, RoundTrip) {
  const std::string root = long3r::test::scratch_dir("datasets/scannetpp");
  const std::vector<LayoutFrame> a = long3r::synth::render_layout_frames(51, 6, 48, 40);
  const std::vector<LayoutFrame> b = long3r::synth::render_layout_frames(52, 6, 48, 40);
  long3r::synth::write_scannetpp_sequence(root, "0a5c013435", a);
  long3r::synth::write_scannetpp_sequence(root, "1ada7a0617", b);
  // The frames come sorted by name whatever the lists' order; a test image
  // (in transforms, not in "train") is not one of them.
  const fs::path lists = dslr_of(root, "0a5c013435") / "train_test_lists.json";
  nlohmann::json l = long3r::datasets::read_json(lists.string());
  std::reverse(l["train"].begin(), l["train"].end());
  l["test"].push_back(l["train"][0]);
  l["train"].erase(0);
  write_json(lists, l);

  const DatasetScan scan = long3r::datasets::open_scannetpp(source_at(root));
  EXPECT_TRUE(scan.skipped.empty()) << (scan.skipped.empty() ? "" : scan.skipped.front());
  ASSERT_EQ(scan.sequences.size(), 2u);
  EXPECT_EQ(scan.sequences[0]->name(), "scannetpp/0a5c013435");
  EXPECT_EQ(scan.sequences[1]->name(), "scannetpp/1ada7a0617");
  // Sequence a lost its last frame to "test".
  ASSERT_EQ(scan.sequences[0]->size(), 5);
  ASSERT_EQ(scan.sequences[1]->size(), 6);
  for (std::size_t s = 0; s < 2; ++s) {
    const std::vector<LayoutFrame>& want = s == 0 ? a : b;
    for (int64_t i = 0; i < scan.sequences[s]->size(); ++i) {
      SCOPED_TRACE("sequence " + std::to_string(s) + " frame " + std::to_string(i));
      expect_same_frame(scan.sequences[s]->frame(i), want[static_cast<std::size_t>(i)]);
    }
  }
  // With every frame in "train": 6 frames.
  long3r::synth::write_scannetpp_sequence(root, "0a5c013435", a);
  EXPECT_EQ(long3r::datasets::open_scannetpp(source_at(root)).sequences.at(0)->size(), 6);
}

TEST(DatasetScannetpp, BrokenFilesAreNamed) {
  const std::string root = long3r::test::scratch_dir("datasets/scannetpp_broken");
  long3r::synth::write_scannetpp_sequence(root, "scene_a",
                                          long3r::synth::render_layout_frames(61, 6, 48, 40));
  long3r::synth::write_scannetpp_sequence(root, "scene_b",
                                          long3r::synth::render_layout_frames(62, 6, 48, 40));
  long3r::synth::write_scannetpp_sequence(root, "scene_c",
                                          long3r::synth::render_layout_frames(63, 6, 48, 40));

  // scene_a: a frame's depth missing, another's pose not a rigid transform.
  const fs::path dslr_a = dslr_of(root, "scene_a");
  const std::string depth = (dslr_a / "undistorted_depths" / "DSC00002.png").string();
  const std::string tf_a = (dslr_a / "nerfstudio" / "transforms_undistorted.json").string();
  fs::remove(depth);
  nlohmann::json tf = long3r::datasets::read_json(tf_a);
  ASSERT_EQ(tf["frames"][3]["file_path"], "DSC00003.JPG");
  for (int r = 0; r < 3; ++r) tf["frames"][3]["transform_matrix"][r][0] = 2.0;
  write_json(tf_a, tf);
  // scene_b: its transforms truncated; scene_c: a train image without a
  // frame in the transforms.
  const std::string tf_b =
      (dslr_of(root, "scene_b") / "nerfstudio" / "transforms_undistorted.json").string();
  fs::resize_file(tf_b, fs::file_size(tf_b) / 2);
  const std::string lists_c = (dslr_of(root, "scene_c") / "train_test_lists.json").string();
  nlohmann::json l = long3r::datasets::read_json(lists_c);
  l["train"].push_back("DSC09999.JPG");
  write_json(lists_c, l);

  const DatasetScan scan = long3r::datasets::open_scannetpp(source_at(root));
  ASSERT_EQ(scan.sequences.size(), 1u);
  ASSERT_EQ(scan.skipped.size(), 2u);
  EXPECT_NE(scan.skipped[0].find(tf_b), std::string::npos) << scan.skipped[0];
  EXPECT_NE(scan.skipped[1].find(lists_c), std::string::npos) << scan.skipped[1];
  const long3r::RecordedSource* seq = find_sequence(scan, "scene_a");
  ASSERT_NE(seq, nullptr);
  EXPECT_EQ(seq->size(), 6);
  EXPECT_NO_THROW(seq->frame(1));
  expect_frame_error(*seq, 2, depth);
  expect_frame_error(*seq, 3, tf_a);

  // No split list: the dataset cannot be opened at all.
  try {
    long3r::datasets::open_scannetpp(source_at(root, "val"));
    ADD_FAILURE() << "opened without nvs_sem_val.txt";
  } catch (const long3r::RecordedFrameError& e) {
    EXPECT_NE(std::string(e.what()).find("nvs_sem_val.txt"), std::string::npos) << e.what();
  }
}
