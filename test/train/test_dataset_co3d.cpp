// The Co3D layout: generated sequences written as DUSt3R's preprocessed
// Co3D-v2 (npz cameras, depth relative to each frame's maximum, object masks)
// read back with their depth, intrinsics and poses, the background masked,
// and broken files named.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "long3r/synth/dataset_layouts.hpp"
#include "long3r/train/datasets/dataset_io.hpp"
#include "support/test_support.hpp"

namespace fs = std::filesystem;

namespace {

long3r::DatasetSource co3d_source(const std::string& root, bool mask_background = true) {
  long3r::DatasetSource s;
  s.layout = "co3d";
  s.root = root;
  s.split = "train";
  s.mask_background = mask_background;
  return s;
}

// The writer's file stem of frame i (Co3D numbers frames from 1).
std::string stem(int i) {
  char text[32];
  std::snprintf(text, sizeof(text), "frame%06d", i + 1);
  return text;
}

const long3r::RecordedSource* find_sequence(const long3r::datasets::DatasetScan& scan,
                                            const std::string& name) {
  for (const auto& s : scan.sequences) {
    if (s->name() == name) return s.get();
  }
  return nullptr;
}

// what() of the RecordedFrameError that reading frame i throws; "" if none.
std::string frame_error(const long3r::RecordedSource& seq, int64_t i) {
  try {
    seq.frame(i);
  } catch (const long3r::RecordedFrameError& e) {
    return e.what();
  }
  return "";
}

// A read frame against the written one, whose depth is valid only where
// `mask` (empty: everywhere) is foreground. Depth is stored in 65535 steps
// of the frame's largest depth (half a step of error); intrinsics and pose
// as float32 (1e-6 relative is well within); colour as JPEG.
void expect_same_frame(const long3r::RawFrame& got, const long3r::synth::LayoutFrame& want,
                       const cv::Mat& mask) {
  const int h = want.depth_m.rows, w = want.depth_m.cols;
  ASSERT_EQ(got.depth.sizes().vec(), (std::vector<int64_t>{h, w}));
  ASSERT_EQ(got.bgr.sizes().vec(), (std::vector<int64_t>{h, w, 3}));
  const long3r::PinholeIntrinsics& k = got.intrinsics;
  const long3r::PinholeIntrinsics& kw = want.intrinsics;
  EXPECT_NEAR(k.fx, kw.fx, 1e-6 * kw.fx);
  EXPECT_NEAR(k.fy, kw.fy, 1e-6 * kw.fy);
  EXPECT_NEAR(k.cx, kw.cx, 1e-6 * std::abs(kw.cx));
  EXPECT_NEAR(k.cy, kw.cy, 1e-6 * std::abs(kw.cy));
  EXPECT_EQ(k.width, w);
  EXPECT_EQ(k.height, h);
  EXPECT_LT((got.T_W_C.matrix() - want.T_W_C.matrix()).cwiseAbs().maxCoeff(), 1e-6);

  const at::Tensor bgr = got.bgr.contiguous();
  const cv::Mat got_bgr(h, w, CV_8UC3, const_cast<uint8_t*>(bgr.data_ptr<uint8_t>()));
  // JPEG: compared in grey levels, since its colour is stored at half
  // resolution, which on these small noisy images costs several levels per
  // channel.
  cv::Mat got_grey, want_grey;
  cv::cvtColor(got_bgr, got_grey, cv::COLOR_BGR2GRAY);
  cv::cvtColor(want.bgr, want_grey, cv::COLOR_BGR2GRAY);
  EXPECT_LT(cv::norm(got_grey, want_grey, cv::NORM_L1) / (h * w), 3.0);

  double maximum_depth = 0.0;
  cv::minMaxLoc(want.depth_m, nullptr, &maximum_depth);
  const double depth_tol = 0.5 * maximum_depth / 65535.0 + 1e-6 * maximum_depth;
  const at::Tensor depth = got.depth.contiguous();
  const float* z = depth.data_ptr<float>();
  int64_t valid = 0, validity_differs = 0, depth_off = 0, point_off = 0;
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      const bool foreground = mask.empty() || mask.at<uint8_t>(v, u) > 25;
      const double zg = z[v * w + u];
      const double zw = foreground ? want.depth_m.at<float>(v, u) : 0.0;
      if ((zg > 0.0) != (zw > 0.0)) ++validity_differs;
      if (!(zg > 0.0 && zw > 0.0)) continue;
      ++valid;
      if (std::abs(zg - zw) > depth_tol) ++depth_off;
      const Eigen::Vector3d p = got.T_W_C * k.backproject(u, v, zg);
      const Eigen::Vector3d q = want.T_W_C * kw.backproject(u, v, zw);
      const double ray = kw.backproject(u, v, 1.0).norm();
      if ((p - q).norm() > depth_tol * ray + 1e-5) ++point_off;
    }
  }
  EXPECT_GT(valid, h * w / 2);
  EXPECT_EQ(validity_differs, 0);
  EXPECT_EQ(depth_off, 0);
  EXPECT_EQ(point_off, 0);
}

}  // namespace

TEST(DatasetCo3d, RoundTrip) {
  const std::string root = long3r::test::scratch_dir("datasets/co3d/round_trip");
  const auto a = long3r::synth::render_layout_frames(31, 6, 48, 40);
  const auto b = long3r::synth::render_layout_frames(32, 6, 48, 40);
  long3r::synth::write_co3d_sequence(root, "apple/110_13051_23361", a);
  long3r::synth::write_co3d_sequence(root, "teddybear/34_1403_4393", b);

  const long3r::datasets::DatasetScan scan = long3r::datasets::open_dataset(co3d_source(root));
  ASSERT_EQ(scan.sequences.size(), 2u);
  EXPECT_TRUE(scan.skipped.empty()) << scan.skipped.front();
  for (const auto& [name, frames] :
       {std::pair{"apple/110_13051_23361", &a}, std::pair{"teddybear/34_1403_4393", &b}}) {
    const long3r::RecordedSource* seq = find_sequence(scan, std::string("co3d/") + name);
    ASSERT_NE(seq, nullptr) << name;
    ASSERT_EQ(seq->size(), 6);
    for (int i = 0; i < 6; ++i) {
      SCOPED_TRACE(std::string(name) + " frame " + std::to_string(i));
      // The fixture's mask leaves out a band: the reader must drop its depth.
      const std::string mask_path = root + "/" + name + "/masks/" + stem(i) + ".png";
      const cv::Mat mask = cv::imread(mask_path, cv::IMREAD_UNCHANGED);
      ASSERT_EQ(mask.type(), CV_8UC1) << mask_path;
      const int background = mask.rows * mask.cols - cv::countNonZero(mask);
      EXPECT_GT(background, 0);
      EXPECT_LT(background, mask.rows * mask.cols / 4);
      expect_same_frame(seq->frame(i), (*frames)[static_cast<std::size_t>(i)], mask);
    }
  }

  // Without mask_background, the depth is kept everywhere.
  const long3r::datasets::DatasetScan unmasked =
      long3r::datasets::open_co3d(co3d_source(root, false));
  const long3r::RecordedSource* seq = find_sequence(unmasked, "co3d/apple/110_13051_23361");
  ASSERT_NE(seq, nullptr);
  for (int i = 0; i < 6; ++i) {
    SCOPED_TRACE("unmasked frame " + std::to_string(i));
    expect_same_frame(seq->frame(i), a[static_cast<std::size_t>(i)], cv::Mat());
  }
}

TEST(DatasetCo3d, BrokenFilesAreNamed) {
  const std::string root = long3r::test::scratch_dir("datasets/co3d/broken");
  const std::string list = root + "/selected_seqs_train.json";
  try {
    long3r::datasets::open_co3d(co3d_source(root));
    ADD_FAILURE() << "no split list, no error";
  } catch (const long3r::RecordedFrameError& e) {
    EXPECT_NE(std::string(e.what()).find(list), std::string::npos) << e.what();
  }

  long3r::synth::write_co3d_sequence(root, "apple/seq_a",
                                     long3r::synth::render_layout_frames(41, 4, 48, 40));
  long3r::synth::write_co3d_sequence(root, "apple/seq_b",
                                     long3r::synth::render_layout_frames(42, 4, 48, 40));
  const std::string a = root + "/apple/seq_a";
  // Frame 1's depth truncated, frame 2's cameras gone, frame 3's mask gone.
  const std::string depth = a + "/depths/" + stem(1) + ".jpg.geometric.png";
  long3r::test::write_file(depth, long3r::test::read_file(depth).substr(0, 40));
  const std::string meta = a + "/images/" + stem(2) + ".npz";
  ASSERT_TRUE(fs::remove(meta));
  const std::string mask = a + "/masks/" + stem(3) + ".png";
  ASSERT_TRUE(fs::remove(mask));
  // seq_b has lost its images folder: left out, named.
  const std::string b_images = root + "/apple/seq_b/images";
  ASSERT_GT(fs::remove_all(b_images), 0u);

  const long3r::datasets::DatasetScan scan = long3r::datasets::open_co3d(co3d_source(root));
  ASSERT_EQ(scan.sequences.size(), 1u);
  EXPECT_EQ(scan.sequences[0]->name(), "co3d/apple/seq_a");
  ASSERT_EQ(scan.skipped.size(), 1u);
  EXPECT_NE(scan.skipped[0].find(b_images), std::string::npos) << scan.skipped[0];

  const long3r::RecordedSource& seq = *scan.sequences[0];
  ASSERT_EQ(seq.size(), 4);
  EXPECT_NO_THROW(seq.frame(0));
  const std::string depth_error = frame_error(seq, 1);
  EXPECT_NE(depth_error.find(depth), std::string::npos) << depth_error;
  const std::string meta_error = frame_error(seq, 2);
  EXPECT_NE(meta_error.find(meta), std::string::npos) << meta_error;
  const std::string mask_error = frame_error(seq, 3);
  EXPECT_NE(mask_error.find(mask), std::string::npos) << mask_error;
  // The mask is only read to mask the background.
  const long3r::datasets::DatasetScan unmasked =
      long3r::datasets::open_co3d(co3d_source(root, false));
  ASSERT_EQ(unmasked.sequences.size(), 1u);
  EXPECT_NO_THROW(unmasked.sequences[0]->frame(3));

  // A sequence's entry in the split list that is not a list of frame
  // numbers: that sequence is left out, named with the list.
  long3r::test::write_file(list, R"({"apple": {"seq_a": [1, 2, 3, 4], "seq_b": "frames"}})");
  const long3r::datasets::DatasetScan listed = long3r::datasets::open_co3d(co3d_source(root));
  EXPECT_EQ(listed.sequences.size(), 1u);
  ASSERT_EQ(listed.skipped.size(), 1u);
  EXPECT_NE(listed.skipped[0].find(list), std::string::npos) << listed.skipped[0];
  EXPECT_NE(listed.skipped[0].find("seq_b"), std::string::npos) << listed.skipped[0];
}
