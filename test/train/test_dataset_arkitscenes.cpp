// The ARKitScenes layout: generated videos written as Spann3R's raw
// low-resolution ARKitScenes folders read back with their depth, intrinsics
// and poses, and broken files named.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include <opencv2/core.hpp>

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

long3r::DatasetSource arkit_source(const std::string& root) {
  long3r::DatasetSource s;
  s.layout = "arkitscenes";
  s.root = root;
  s.split = "train";
  return s;
}

// The writer's file stem of frame i: timestamps 1000.000 + 0.1 i.
std::string stem(const std::string& video, int i) {
  char ts[32];
  std::snprintf(ts, sizeof(ts), "%.3f", 1000.0 + 0.1 * i);
  return video + "_" + ts;
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

// A read frame against the written one: uint16 millimetre depth (half a
// millimetre), lossless PNG colour, intrinsics and pose from full-precision
// text; every valid pixel's world point within the depth's precision along
// its ray.
void expect_same_frame(const long3r::RawFrame& got, const long3r::synth::LayoutFrame& want) {
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
  EXPECT_EQ(cv::norm(got_bgr, want.bgr, cv::NORM_INF), 0.0);

  const at::Tensor depth = got.depth.contiguous();
  const float* z = depth.data_ptr<float>();
  const double depth_tol = 0.5e-3 + 1e-6;
  int64_t valid = 0, validity_differs = 0, depth_off = 0, point_off = 0;
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      const double zg = z[v * w + u], zw = want.depth_m.at<float>(v, u);
      if ((zg > 0.0) != (zw > 0.0)) ++validity_differs;
      if (!(zg > 0.0 && zw > 0.0)) continue;
      ++valid;
      if (std::abs(zg - zw) > depth_tol) ++depth_off;
      const Eigen::Vector3d p = got.T_W_C * k.backproject(u, v, zg);
      const Eigen::Vector3d q = want.T_W_C * kw.backproject(u, v, zw);
      const double ray = kw.backproject(u, v, 1.0).norm();
      if ((p - q).norm() > depth_tol * ray + 1e-6) ++point_off;
    }
  }
  EXPECT_GT(valid, h * w / 2);
  EXPECT_EQ(validity_differs, 0);
  EXPECT_EQ(depth_off, 0);
  EXPECT_EQ(point_off, 0);
}

}  // namespace

TEST(DatasetArkitscenes, RoundTrip) {
  const std::string root = long3r::test::scratch_dir("datasets/arkitscenes/round_trip");
  const auto a = long3r::synth::render_layout_frames(11, 6, 48, 40);
  const auto b = long3r::synth::render_layout_frames(12, 6, 48, 40);
  long3r::synth::write_arkitscenes_sequence(root, "41069021", a);
  long3r::synth::write_arkitscenes_sequence(root, "41069022", b);

  const long3r::datasets::DatasetScan scan = long3r::datasets::open_dataset(arkit_source(root));
  ASSERT_EQ(scan.sequences.size(), 2u);
  EXPECT_TRUE(scan.skipped.empty()) << scan.skipped.front();
  for (const auto& [video, frames] : {std::pair{"41069021", &a}, std::pair{"41069022", &b}}) {
    const long3r::RecordedSource* seq = find_sequence(scan, std::string("arkitscenes/") + video);
    ASSERT_NE(seq, nullptr) << video;
    ASSERT_EQ(seq->size(), 6);
    for (int i = 0; i < 6; ++i) {
      SCOPED_TRACE(std::string(video) + " frame " + std::to_string(i));
      expect_same_frame(seq->frame(i), (*frames)[static_cast<std::size_t>(i)]);
    }
  }
}

TEST(DatasetArkitscenes, BrokenFilesAreNamed) {
  const std::string root = long3r::test::scratch_dir("datasets/arkitscenes/broken");
  const std::string split = root + "/raw/Training";
  EXPECT_THROW(long3r::datasets::open_arkitscenes(arkit_source(root)), long3r::RecordedFrameError);

  long3r::synth::write_arkitscenes_sequence(root, "41069021",
                                            long3r::synth::render_layout_frames(21, 4, 48, 40));
  long3r::synth::write_arkitscenes_sequence(root, "41069022",
                                            long3r::synth::render_layout_frames(22, 4, 48, 40));
  // Frame 1's depth truncated, frame 2's intrinsics gone: those frames are
  // unreadable, named, and the others still read.
  const std::string depth = split + "/41069021/lowres_depth/" + stem("41069021", 1) + ".png";
  long3r::test::write_file(depth, long3r::test::read_file(depth).substr(0, 40));
  const std::string pincam =
      split + "/41069021/lowres_wide_intrinsics/" + stem("41069021", 2) + ".pincam";
  ASSERT_TRUE(fs::remove(pincam));
  // The other video's trajectory is corrupt: it is left out, named.
  const std::string traj = split + "/41069022/lowres_wide.traj";
  long3r::test::write_file(traj, "1000.000 0.1 0.2 x 1 2 3\n");

  const long3r::datasets::DatasetScan scan = long3r::datasets::open_arkitscenes(arkit_source(root));
  ASSERT_EQ(scan.sequences.size(), 1u);
  EXPECT_EQ(scan.sequences[0]->name(), "arkitscenes/41069021");
  ASSERT_EQ(scan.skipped.size(), 1u);
  EXPECT_NE(scan.skipped[0].find(traj), std::string::npos) << scan.skipped[0];

  const long3r::RecordedSource& seq = *scan.sequences[0];
  ASSERT_EQ(seq.size(), 4);
  EXPECT_NO_THROW(seq.frame(0));
  EXPECT_NO_THROW(seq.frame(3));
  const std::string depth_error = frame_error(seq, 1);
  EXPECT_NE(depth_error.find(depth), std::string::npos) << depth_error;
  const std::string pincam_error = frame_error(seq, 2);
  EXPECT_NE(pincam_error.find(pincam), std::string::npos) << pincam_error;

  // Without its trajectory file, a video is left out too.
  ASSERT_TRUE(fs::remove(traj));
  const long3r::datasets::DatasetScan again =
      long3r::datasets::open_arkitscenes(arkit_source(root));
  EXPECT_EQ(again.sequences.size(), 1u);
  ASSERT_EQ(again.skipped.size(), 1u);
  EXPECT_NE(again.skipped[0].find(traj), std::string::npos) << again.skipped[0];
}
