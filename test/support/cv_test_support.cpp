#include "support/cv_test_support.hpp"

#include <ATen/core/Tensor.h>
#include <ATen/ops/from_blob.h>
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <stdexcept>

#include "long3r/synth/cv/sensor_image.hpp"

namespace long3r::test {

cv::Mat pointmap_from_depth(const PinholeIntrinsics& k, const Eigen::Isometry3d& T,
                            const std::function<double(int u, int v)>& depth) {
  cv::Mat pts(k.height, k.width, CV_32FC3, cv::Scalar::all(NAN));
  for (int v = 0; v < k.height; ++v) {
    for (int u = 0; u < k.width; ++u) {
      const double d = depth(u, v);
      if (!(d > 0.0)) continue;
      const Eigen::Vector3d X = T * k.backproject(u, v, d);
      pts.at<cv::Vec3f>(v, u) = cv::Vec3f(static_cast<float>(X.x()), static_cast<float>(X.y()),
                                          static_cast<float>(X.z()));
    }
  }
  return pts;
}

cv::Mat egg_crate_image(int width, int height) {
  cv::Mat img(height, width, CV_8UC3);
  for (int v = 0; v < height; ++v)
    for (int u = 0; u < width; ++u) {
      const double waves = std::sin(2.0 * M_PI * u / 24.0) * std::sin(2.0 * M_PI * v / 24.0);
      img.at<cv::Vec3b>(v, u) =
          cv::Vec3b(static_cast<uchar>(u * 255 / width), static_cast<uchar>(v * 255 / height),
                    cv::saturate_cast<uchar>(128.0 + 110.0 * waves));
    }
  return img;
}

ReconstructionConfig gt_reconstruction_config() {
  ReconstructionConfig c;
  c.preprocess.width = c.preprocess.height = kGtSize;
  c.pnp.min_inliers = 30;
  c.map.voxel_size_m = 0.05;
  // The pipeline around the model's own poses (the fakes' pointmaps are
  // exact); the tracker's tests set keyframes themselves.
  c.pose_method = PoseMethod::kModel;
  return c;
}

GtSequence make_sequence(int frames) {
  synth::SequenceConfig c;
  c.seed = 3;
  c.trajectory.frames = frames;
  c.trajectory.speed = 0.05;
  c.intrinsics = PinholeIntrinsics::from_hfov(kGtSize, kGtSize, 70.0);
  GtSequence g;
  g.seq = synth::generate_sequence(c);
  for (int k = 0; k < frames; ++k) {
    const synth::RenderedFrame f = synth::render_frame(g.seq.scene, g.seq.poses[k], c.intrinsics);
    const Eigen::Isometry3d T = g.seq.poses[0].inverse() * g.seq.poses[k];
    g.bgr.push_back(synth::bgr_image(f));
    const cv::Mat depth = synth::depth_image(f);
    g.pts_W0.push_back(
        pointmap_from_depth(c.intrinsics, T, [&](int u, int v) { return depth.at<float>(v, u); }));
    g.T_0_k.push_back(T);
  }
  return g;
}

std::optional<StreamOutput> FakeModel::push(const at::Tensor& image) {
  EXPECT_EQ(image.dim(), 4);
  EXPECT_EQ(image.size(2), kGtSize);
  EXPECT_EQ(image.size(3), kGtSize);
  const int64_t k = n_++;
  if (k == 0) return std::nullopt;
  return output(k - 1, false);
}

StateDict FakeModel::stream_state() const {
  StateDict state;
  put_int(state, "frames", n_);
  return state;
}

void FakeModel::restore_stream_state(const StateDict& state) {
  n_ = StateReader(state, "fake model state")
           .integer("frames", 0, static_cast<int64_t>(pts_->size()));
}

std::optional<StreamOutput> FakeModel::peek_last() {
  if (n_ == 0) return std::nullopt;
  return output(n_ - 1, true);
}

StreamOutput FakeModel::output(int64_t k, bool coarse) {
  StreamOutput o;
  o.frame_index = k;
  o.from_coarse_head = coarse;
  cv::Mat p = (*pts_)[static_cast<std::size_t>(k)].clone();
  cv::Mat conf(kGtSize, kGtSize, CV_32FC1);
  for (int i = 0; i < kGtSize * kGtSize; ++i) {
    conf.at<float>(i) = std::isfinite(p.at<cv::Vec3f>(i)[2]) ? 10.f : 1.f;
  }
  o.pts3d = at::from_blob(p.data, {1, kGtSize, kGtSize, 3}, at::kFloat).clone();
  o.conf = at::from_blob(conf.data, {1, kGtSize, kGtSize}, at::kFloat).clone();
  o.stats.mem_short_tokens = 7;
  return o;
}

FramePrecision millimetre_depth_precision(FramePrecision::Colour colour, double point_slack_m) {
  FramePrecision p;
  p.depth_abs_m = 0.5e-3 + 1e-6;
  p.point_slack_m = point_slack_m;
  p.colour = colour;
  return p;
}

FramePrecision relative_depth_precision(double depth_rel) {
  FramePrecision p;
  p.depth_rel = depth_rel;
  p.depth_slack_m = 1e-6;
  p.colour = FramePrecision::Colour::kMeanGrey;
  return p;
}

void expect_frame_matches(const RawFrame& read, const synth::LayoutFrame& truth,
                          const FramePrecision& p) {
  const int h = truth.depth_m.rows, w = truth.depth_m.cols;
  ASSERT_EQ(read.depth.sizes().vec(), (std::vector<int64_t>{h, w}));
  ASSERT_EQ(read.bgr.sizes().vec(), (std::vector<int64_t>{h, w, 3}));
  const PinholeIntrinsics& k = read.intrinsics;
  const PinholeIntrinsics& kt = truth.intrinsics;
  EXPECT_NEAR(k.fx, kt.fx, 1e-6 * kt.fx);
  EXPECT_NEAR(k.fy, kt.fy, 1e-6 * kt.fy);
  // Relative to the smaller of the focal length and the centre itself: a
  // centre off by a fraction of a pixel, or off in its own digits, shows.
  EXPECT_NEAR(k.cx, kt.cx, 1e-6 * std::min(kt.fx, std::abs(kt.cx)));
  EXPECT_NEAR(k.cy, kt.cy, 1e-6 * std::min(kt.fy, std::abs(kt.cy)));
  EXPECT_EQ(k.width, w);
  EXPECT_EQ(k.height, h);
  EXPECT_LT((read.T_W_C.matrix() - truth.T_W_C.matrix()).cwiseAbs().maxCoeff(), 1e-6);

  const at::Tensor bgr_t = read.bgr.contiguous();
  const at::Tensor depth_t = read.depth.contiguous();
  const cv::Mat bgr(h, w, CV_8UC3, bgr_t.data_ptr<uint8_t>());
  const cv::Mat depth(h, w, CV_32F, depth_t.data_ptr<float>());
  switch (p.colour) {
    case FramePrecision::Colour::kExact:
      EXPECT_EQ(cv::norm(bgr, truth.bgr, cv::NORM_INF), 0.0);
      break;
    case FramePrecision::Colour::kMeanBgr:
      EXPECT_LT(cv::norm(bgr, truth.bgr, cv::NORM_L1) / (3.0 * w * h), p.colour_levels);
      break;
    case FramePrecision::Colour::kMeanGrey: {
      cv::Mat grey, truth_grey;
      cv::cvtColor(bgr, grey, cv::COLOR_BGR2GRAY);
      cv::cvtColor(truth.bgr, truth_grey, cv::COLOR_BGR2GRAY);
      EXPECT_LT(cv::norm(grey, truth_grey, cv::NORM_L1) / (1.0 * w * h), p.colour_levels);
      break;
    }
  }

  // Worst excess over the encoding's error, of the depth and of the world
  // points (a depth error dz moves a point along its ray by dz |p| / z).
  int64_t valid = 0, spurious = 0, missing = 0;
  double worst_depth = 0.0, worst_point = 0.0;
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      const double z = depth.at<float>(v, u), zt = truth.depth_m.at<float>(v, u);
      if (!(std::isfinite(zt) && zt > 0.0)) {
        if (z != 0.0) ADD_FAILURE() << "depth " << z << " where none, at " << u << ", " << v;
        spurious += z != 0.0;
        continue;
      }
      if (!(z > 0.0)) {
        if (missing++ == 0) ADD_FAILURE() << "no depth, at " << u << ", " << v;
        continue;
      }
      ++valid;
      const double error = p.depth_abs_m + p.depth_rel * zt;
      worst_depth = std::max(worst_depth, std::abs(z - zt) - error);
      const Eigen::Vector3d p_cam = kt.backproject(u, v, zt);
      const Eigen::Vector3d truth_point = truth.T_W_C * p_cam;
      const Eigen::Vector3d read_point = read.T_W_C * k.backproject(u, v, z);
      worst_point =
          std::max(worst_point, (read_point - truth_point).norm() - error * p_cam.norm() / zt);
    }
  }
  EXPECT_EQ(spurious, 0);
  EXPECT_EQ(missing, 0);
  EXPECT_GT(valid, h * w / 2);
  EXPECT_LE(worst_depth, p.depth_slack_m);
  EXPECT_LE(worst_point, p.point_slack_m);
}

void expect_sequence_matches(const RecordedSource& seq,
                             const std::vector<synth::LayoutFrame>& truth, const FramePrecision& p,
                             std::size_t first) {
  ASSERT_LE(first + static_cast<std::size_t>(seq.size()), truth.size()) << seq.name();
  for (int64_t i = 0; i < seq.size(); ++i) {
    SCOPED_TRACE(seq.name() + " frame " + std::to_string(i));
    expect_frame_matches(seq.frame(i), truth[first + static_cast<std::size_t>(i)], p);
  }
}

DatasetSource layout_source(const std::string& layout, const std::string& root,
                            const std::string& split) {
  DatasetSource s;
  s.layout = layout;
  s.root = root;
  s.split = split;
  return s;
}

datasets::DatasetScan open_layout(const std::string& layout, const std::string& root,
                                  const std::string& split) {
  return datasets::open_dataset(layout_source(layout, root, split));
}

const RecordedSource* find_sequence(const datasets::DatasetScan& scan, const std::string& name) {
  for (const auto& s : scan.sequences) {
    if (s->name() == name) return s.get();
  }
  return nullptr;
}

void expect_error_naming(const std::function<void()>& act, const std::string& text) {
  try {
    act();
  } catch (const RecordedFrameError& e) {
    EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
    return;
  }
  ADD_FAILURE() << "no RecordedFrameError naming " << text;
}

void truncate_file(const std::string& path, std::uintmax_t bytes) {
  if (std::filesystem::file_size(path) <= bytes) {
    throw std::invalid_argument(path + ": not longer than " + std::to_string(bytes) + " bytes");
  }
  std::filesystem::resize_file(path, bytes);
}

void delete_file(const std::string& path) {
  if (!std::filesystem::remove(path)) throw std::invalid_argument(path + ": no file to delete");
}

synth::SequenceConfig sequence_config(std::uint64_t seed, synth::TrajectoryType type, int frames,
                                      int w, int h) {
  synth::SequenceConfig c;
  c.seed = seed;
  c.trajectory.type = type;
  c.trajectory.frames = frames;
  c.intrinsics = PinholeIntrinsics::from_hfov(w, h, 70.0);
  return c;
}

}  // namespace long3r::test
