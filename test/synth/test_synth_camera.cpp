// The generator's realistic cameras (lens distortion, exposure, noise, mono)
// and the robot path (a base on the floor with the camera on a mount).
#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <sstream>

#include "long3r/dataset/tum_dataset.hpp"
#include "long3r/io/data_lines.hpp"
#include "long3r/synth/cv/sensor_image.hpp"
#include "long3r/synth/cv/tum_writer.hpp"
#include "long3r/synth/generate.hpp"
#include "long3r/synth/geometry.hpp"
#include "long3r/synth/render.hpp"
#include "support/cv_test_support.hpp"
#include "support/test_support.hpp"

using namespace long3r;
using namespace long3r::synth;

namespace {

using test::read_file;
using test::scratch_dir;

// A lens like a wide webcam's: strong barrel, some tangential (OpenCV's order).
LensDistortion webcam_lens() {
  LensDistortion d;
  d.k1 = -0.28;
  d.k2 = 0.09;
  d.p1 = 0.0012;
  d.p2 = -0.0008;
  d.k3 = -0.012;
  return d;
}

cv::Mat camera_matrix(const PinholeIntrinsics& k) {
  return (cv::Mat_<double>(3, 3) << k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1);
}

// FNV-1a over a sequence folder: relative paths in order, decoded pixels of
// PNGs (independent of the PNG encoder's version), raw bytes of the rest.
uint64_t folder_digest(const std::string& dir) {
  std::vector<std::string> files;
  for (const auto& e : std::filesystem::recursive_directory_iterator(dir)) {
    if (e.is_regular_file()) files.push_back(std::filesystem::relative(e.path(), dir).string());
  }
  std::sort(files.begin(), files.end());
  uint64_t h = 1469598103934665603ull;
  auto add = [&](const void* data, size_t n) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (size_t i = 0; i < n; ++i) h = (h ^ p[i]) * 1099511628211ull;
  };
  for (const std::string& rel : files) {
    add(rel.data(), rel.size());
    const std::string path = dir + "/" + rel;
    if (rel.size() > 4 && rel.substr(rel.size() - 4) == ".png") {
      const cv::Mat img = cv::imread(path, cv::IMREAD_UNCHANGED);
      const int header[3] = {img.type(), img.rows, img.cols};
      add(header, sizeof(header));
      for (int r = 0; r < img.rows; ++r) add(img.ptr(r), img.cols * img.elemSize());
    } else {
      const std::string bytes = read_file(path);
      add(bytes.data(), bytes.size());
    }
  }
  return h;
}

bool is_planar(const Scene& scene, int surface_id) {
  if (surface_id < 0) return false;
  if (surface_id < 16) return true;
  return scene.shapes[surface_id / 16 - 1].type == ShapeType::kBox;
}

}  // namespace

TEST(SynthCamera, DefaultOutputIsWhatItWasBeforeCameraEffects) {
  // Digests of folders written by the generator before lens, sensor and robot
  // support existed (same configs through long3r_synth): with every effect
  // off the files are the same, pixel for pixel and byte for byte. A
  // deliberate change of the renderer or the scene updates these numbers.
  SequenceConfig walk = test::sequence_config(3, TrajectoryType::kWalk, 6, 64, 48);
  SequenceConfig super = test::sequence_config(9, TrajectoryType::kWalk, 3, 50, 40);
  super.intrinsics.fx = 40;
  super.intrinsics.fy = 44;
  super.intrinsics.cx = 20;
  super.intrinsics.cy = 21;
  RenderOptions two;
  two.supersample = 2;
  const std::string d1 = scratch_dir("synth_digest_walk"), d2 = scratch_dir("synth_digest_ss");
  write_tum_sequence(generate_sequence(walk), d1);
  write_tum_sequence(generate_sequence(super), d2, two);
  EXPECT_EQ(folder_digest(d1), 0xa7b774f8c72aac93ull) << std::hex << folder_digest(d1);
  EXPECT_EQ(folder_digest(d2), 0x5069eb59483cc4a3ull) << std::hex << folder_digest(d2);
}

TEST(SynthCamera, EffectsLeaveSceneAndPathAlone) {
  SequenceConfig plain = test::sequence_config(4, TrajectoryType::kWalk, 30, 64, 48);
  SequenceConfig fancy = plain;
  fancy.distortion = webcam_lens();
  fancy.sensor.read_noise = 2.0;
  fancy.sensor.exposure_drift = 0.2;
  fancy.sensor.exposure_step_prob = 0.1;
  fancy.sensor.exposure_step = 0.3;
  fancy.sensor.mono = true;
  const Sequence a = generate_sequence(plain), b = generate_sequence(fancy);
  ASSERT_EQ(a.poses.size(), b.poses.size());
  for (size_t i = 0; i < a.poses.size(); ++i) EXPECT_TRUE(a.poses[i].isApprox(b.poses[i], 0.0));
  ASSERT_EQ(a.scene.shapes.size(), b.scene.shapes.size());
  for (size_t i = 0; i < a.scene.shapes.size(); ++i) {
    EXPECT_EQ(a.scene.shapes[i].center, b.scene.shapes[i].center);
  }
  for (double g : a.exposure) EXPECT_EQ(g, 1.0);
}

TEST(SynthCamera, DistortedRenderUndistortsToThePinholeRender) {
  // Rendered through the lens, then undistorted by OpenCV with the same
  // coefficients, a frame must match the pinhole render of the same pose.
  // cv::undistort resamples bilinearly, which no render can match exactly on
  // textures and edges: the tolerance is that resampling error itself,
  // measured on the same scene by rendering the pinhole camera shifted by a
  // sub-pixel offset and remapping it back (about 3.3 grey levels on
  // average here; the undistorted frame is at 1.8). The lens ignored, or k1
  // 20 % off, must be clearly worse.
  SequenceConfig cfg = test::sequence_config(11, TrajectoryType::kWalk, 1, 160, 120);
  const Sequence seq = generate_sequence(cfg);
  const PinholeIntrinsics& k = cfg.intrinsics;
  RenderOptions opt;
  opt.supersample = 3;
  const LensDistortion lens = webcam_lens();
  const LensRays rays(k, lens, opt.supersample);
  const cv::Mat distorted = bgr_image(render_frame(seq.scene, seq.poses[0], rays, opt));
  const cv::Mat pinhole = bgr_image(render_frame(seq.scene, seq.poses[0], k, opt));
  const cv::Mat K = camera_matrix(k);

  // Compare where the undistortion samples well inside the distorted image.
  cv::Mat map_x, map_y;
  cv::initUndistortRectifyMap(K, lens.coefficients(), cv::noArray(), K, pinhole.size(), CV_32FC1,
                              map_x, map_y);
  cv::Mat inside(pinhole.size(), CV_8U, cv::Scalar(0));
  for (int v = 0; v < inside.rows; ++v) {
    for (int u = 0; u < inside.cols; ++u) {
      const float x = map_x.at<float>(v, u), y = map_y.at<float>(v, u);
      inside.at<uint8_t>(v, u) = x >= 3 && y >= 3 && x <= k.width - 4 && y <= k.height - 4;
    }
  }
  ASSERT_GT(cv::countNonZero(inside), k.width * k.height / 2);
  auto mean_error = [&](const cv::Mat& image) {
    cv::Mat diff, grey;
    cv::absdiff(image, pinhole, diff);
    cv::cvtColor(diff, grey, cv::COLOR_BGR2GRAY);
    return cv::mean(grey, inside)[0];
  };
  auto undistorted = [&](const std::vector<double>& D) {
    cv::Mat out;
    cv::undistort(distorted, out, K, D);
    return mean_error(out);
  };
  PinholeIntrinsics shifted_k = k;
  shifted_k.cx += 0.37;
  shifted_k.cy += 0.61;
  const cv::Mat shifted = bgr_image(render_frame(seq.scene, seq.poses[0], shifted_k, opt));
  cv::Mat back_x(pinhole.size(), CV_32F), back_y(pinhole.size(), CV_32F), back;
  for (int v = 0; v < back_x.rows; ++v) {
    for (int u = 0; u < back_x.cols; ++u) {
      back_x.at<float>(v, u) = u + 0.37f;
      back_y.at<float>(v, u) = v + 0.61f;
    }
  }
  cv::remap(shifted, back, back_x, back_y, cv::INTER_LINEAR);
  const double resampling = mean_error(back);

  const double right = undistorted(lens.coefficients());
  std::vector<double> off = lens.coefficients();
  off[0] *= 1.2;
  const double wrong_k1 = undistorted(off);
  const double ignored = undistorted({0, 0, 0, 0, 0});
  EXPECT_LT(right, resampling) << "grey levels";
  EXPECT_GT(wrong_k1, 1.5 * right);
  EXPECT_GT(ignored, 4.0 * right);
}

TEST(SynthCamera, DistortedDepthIsRegisteredToItsPixels) {
  // Pixel (u, v) of the distorted depth holds the z-depth of the point on the
  // ray that OpenCV undistorts (u, v) to: that point, looked up in the
  // pinhole render of the same pose (on planar surfaces, where inverse depth
  // interpolates exactly), has the same depth.
  SequenceConfig cfg = test::sequence_config(12, TrajectoryType::kWalk, 1, 128, 96);
  const Sequence seq = generate_sequence(cfg);
  const PinholeIntrinsics& k = cfg.intrinsics;
  const LensDistortion lens = webcam_lens();
  const RenderedFrame d = render_frame(seq.scene, seq.poses[0], LensRays(k, lens));
  const RenderedFrame p = render_frame(seq.scene, seq.poses[0], k);
  const cv::Mat d_depth = depth_image(d), d_id = surface_id_image(d);
  const cv::Mat p_depth = depth_image(p), p_id = surface_id_image(p);
  std::vector<cv::Point2d> pixels, rays;
  for (int v = 0; v < k.height; ++v) {
    for (int u = 0; u < k.width; ++u) pixels.emplace_back(u, v);
  }
  cv::undistortPoints(pixels, rays, camera_matrix(k), lens.coefficients(), cv::noArray(),
                      cv::noArray(), cv::TermCriteria(cv::TermCriteria::COUNT, 200, 0));
  int checked = 0;
  double worst = 0.0, moved = 0.0;
  for (size_t i = 0; i < pixels.size(); ++i) {
    const int u = static_cast<int>(pixels[i].x), v = static_cast<int>(pixels[i].y);
    const int id = d_id.at<int32_t>(v, u);
    const double z = d_depth.at<float>(v, u);
    if (!is_planar(seq.scene, id) || !(z > 0)) continue;
    const double pu = k.fx * rays[i].x + k.cx, pv = k.fy * rays[i].y + k.cy;
    const int u0 = static_cast<int>(std::floor(pu)), v0 = static_cast<int>(std::floor(pv));
    if (u0 < 0 || v0 < 0 || u0 + 1 >= k.width || v0 + 1 >= k.height) continue;
    bool same = true;
    double inv = 0.0;
    for (int dy = 0; dy < 2; ++dy) {
      for (int dx = 0; dx < 2; ++dx) {
        if (p_id.at<int32_t>(v0 + dy, u0 + dx) != id) same = false;
        const double w = (dx ? pu - u0 : 1 - (pu - u0)) * (dy ? pv - v0 : 1 - (pv - v0));
        inv += w / p_depth.at<float>(v0 + dy, u0 + dx);
      }
    }
    if (!same) continue;
    worst = std::max(worst, std::abs(1.0 / inv - z));
    moved = std::max(moved, std::abs(p_depth.at<float>(v, u) - z));
    ++checked;
  }
  EXPECT_GT(checked, k.width * k.height / 3);
  EXPECT_LT(worst, 1e-4) << "metres";
  EXPECT_GT(moved, 0.05) << "the lens must move what a pixel sees";
}

TEST(SynthCamera, LensRaysRefuseAnUninvertibleLens) {
  // The webcam lens on a 100 degree image: the model's radius peaks (at
  // r = 2, distorted radius 1.1) before the corners (distorted radius 1.46),
  // so no ray reaches them.
  EXPECT_THROW(LensRays(PinholeIntrinsics::from_hfov(64, 48, 100.0), webcam_lens()),
               std::invalid_argument);
  const PinholeIntrinsics k = PinholeIntrinsics::from_hfov(64, 48, 70.0);
  const LensRays ok(k, webcam_lens(), 2);
  EXPECT_EQ(ok.supersample(), 2);
  // Pinhole pixel size is 1/f; barrel distortion widens the corner pixels.
  EXPECT_GT(ok.pixel_size(0, 0), ok.pixel_size(32, 24));
  EXPECT_NEAR(LensRays(k, LensDistortion{}).pixel_size(5, 7), 1.0 / k.fx, 1e-9);
  const Sequence seq =
      generate_sequence(test::sequence_config(1, TrajectoryType::kWalk, 1, 64, 48));
  EXPECT_THROW(render_frame(seq.scene, seq.poses[0], ok), std::invalid_argument);  // supersample 1
}

TEST(SynthCamera, SensorNoiseHasItsModelledSpreadAndIsSeeded) {
  SensorConfig s;
  s.read_noise = 3.0;
  s.shot_noise = 0.1;
  const cv::Mat flat(200, 200, CV_8UC3, cv::Scalar(40, 120, 200));
  const cv::Mat a = apply_sensor(flat, s, 7, 3), b = apply_sensor(flat, s, 7, 3);
  EXPECT_EQ(cv::norm(a, b, cv::NORM_INF), 0.0) << "same seed and frame, same noise";
  EXPECT_GT(cv::norm(a, apply_sensor(flat, s, 7, 4), cv::NORM_L1), 0.0) << "other frame";
  EXPECT_GT(cv::norm(a, apply_sensor(flat, s, 8, 3), cv::NORM_L1), 0.0) << "other seed";
  std::vector<cv::Mat> channels;
  cv::split(a, channels);
  const int level[3] = {40, 120, 200};
  for (int c = 0; c < 3; ++c) {
    cv::Scalar mean, stddev;
    cv::meanStdDev(channels[c], mean, stddev);
    const double expected = std::sqrt(9.0 + 0.1 * level[c]);
    EXPECT_NEAR(mean[0], level[c], 0.1) << "channel " << c;
    EXPECT_NEAR(stddev[0], expected, 0.04 * expected) << "channel " << c;  // 40000 samples
  }
  // Off: the rendered image itself, untouched.
  const cv::Mat same = apply_sensor(flat, SensorConfig{}, 7, 3);
  EXPECT_EQ(same.data, flat.data);
  // Mono: one channel, OpenCV's luma; with noise on top.
  SensorConfig mono;
  mono.mono = true;
  cv::Mat grey;
  cv::cvtColor(flat, grey, cv::COLOR_BGR2GRAY);
  const cv::Mat m = apply_sensor(flat, mono, 7, 3);
  ASSERT_EQ(m.type(), CV_8UC1);
  EXPECT_EQ(cv::norm(m, grey, cv::NORM_INF), 0.0);
  mono.read_noise = 2.0;
  EXPECT_GT(cv::norm(apply_sensor(flat, mono, 7, 3), grey, cv::NORM_L1), 0.0);
}

TEST(SynthCamera, ExposureDriftsAndStepsWithinItsBounds) {
  std::vector<double> stamps;
  for (int i = 0; i < 3000; ++i) stamps.push_back(100.0 + i / 30.0);
  SensorConfig s;
  EXPECT_EQ(exposure_gains(s, 1, stamps), std::vector<double>(stamps.size(), 1.0));
  s.exposure_drift = 0.25;
  const std::vector<double> drift = exposure_gains(s, 1, stamps);
  EXPECT_EQ(drift, exposure_gains(s, 1, stamps));
  EXPECT_NE(drift, exposure_gains(s, 2, stamps));
  const auto [lo, hi] = std::minmax_element(drift.begin(), drift.end());
  EXPECT_GE(*lo, 0.75);
  EXPECT_LE(*hi, 1.25);
  EXPECT_LT(*lo, 0.9);  // 100 s covers the slow waves
  EXPECT_GT(*hi, 1.1);
  double worst_step = 0.0;
  for (size_t i = 1; i < drift.size(); ++i) {
    worst_step = std::max(worst_step, std::abs(drift[i] - drift[i - 1]));
  }
  EXPECT_LT(worst_step, 0.01) << "slow: under 1 % per frame";
  s.exposure_drift = 0.0;
  s.exposure_step_prob = 0.01;
  s.exposure_step = 0.5;
  const std::vector<double> steps = exposure_gains(s, 1, stamps);
  int changes = 0;
  for (size_t i = 1; i < steps.size(); ++i) changes += steps[i] != steps[i - 1];
  EXPECT_GT(changes, 10);  // about 30 expected
  EXPECT_LT(changes, 60);
  for (double g : steps) {
    EXPECT_GE(g, 1.0 / 1.5 - 1e-12);
    EXPECT_LE(g, 1.5 + 1e-12);
  }
  // Rendered with a gain: darker and brighter, black stays black.
  const Sequence seq =
      generate_sequence(test::sequence_config(2, TrajectoryType::kWalk, 1, 48, 32));
  RenderOptions dim, bright;
  dim.gain = 0.5f;
  bright.gain = 1.5f;
  const cv::Mat base = bgr_image(render_frame(seq.scene, seq.poses[0], seq.config.intrinsics));
  EXPECT_LT(
      cv::mean(bgr_image(render_frame(seq.scene, seq.poses[0], seq.config.intrinsics, dim)))[1],
      0.9 * cv::mean(base)[1]);
  EXPECT_GT(
      cv::mean(bgr_image(render_frame(seq.scene, seq.poses[0], seq.config.intrinsics, bright)))[1],
      1.1 * cv::mean(base)[1]);
}

TEST(SynthCamera, WrittenSequenceCarriesTheEffects) {
  SequenceConfig cfg = test::sequence_config(6, TrajectoryType::kWalk, 4, 64, 48);
  cfg.distortion = webcam_lens();
  cfg.sensor.mono = true;
  cfg.sensor.read_noise = 1.5;
  cfg.sensor.shot_noise = 0.05;
  cfg.sensor.exposure_drift = 0.1;
  const std::string d1 = scratch_dir("synth_effects_1"), d2 = scratch_dir("synth_effects_2");
  RenderOptions one, three;
  one.threads = 1;
  three.threads = 3;
  write_tum_sequence(generate_sequence(cfg), d1, one);
  write_tum_sequence(generate_sequence(cfg), d2, three);
  EXPECT_EQ(folder_digest(d1), folder_digest(d2)) << "deterministic for any thread count";
  const CameraCalibration c = read_camera_calibration(d1 + "/calibration.txt");
  EXPECT_EQ(c.distortion_model, "plumb_bob");
  EXPECT_EQ(c.distortion, cfg.distortion.coefficients());  // bit for bit
  EXPECT_THROW(TumDataset::open(d1), std::runtime_error);  // no silent pinhole reading
  TumDatasetOptions lenses;
  lenses.allow_distortion = true;
  const TumDataset ds = TumDataset::open(d1, lenses);
  ASSERT_EQ(ds.size(), 4u);
  const cv::Mat grey = cv::imread(ds.frame(0).rgb_path, cv::IMREAD_UNCHANGED);
  EXPECT_EQ(grey.type(), CV_8UC1);
  EXPECT_EQ(test::folder_entries(d1).size(), 8u);  // + exposure.txt
  const Sequence seq = generate_sequence(cfg);
  const auto lines = data_lines(d1 + "/exposure.txt");
  ASSERT_EQ(lines.size(), 4u);
  for (size_t i = 0; i < 4; ++i) {
    std::istringstream ss(lines[i].second);
    double t = 0, g = 0;
    ss >> t >> g;
    EXPECT_NEAR(t, seq.stamps[i], 1e-6);
    EXPECT_NEAR(g, seq.exposure[i], 1e-8);
  }
}

TEST(SynthRobot, CameraIsTheBaseTimesTheMount) {
  SequenceConfig cfg = test::sequence_config(5, TrajectoryType::kRobot, 1500, 64, 48);
  cfg.trajectory.mount.z = 1.35;
  cfg.trajectory.mount.pitch_deg = 14.0;
  const Sequence seq = generate_sequence(cfg);
  ASSERT_EQ(seq.base_poses.size(), seq.poses.size());
  const Eigen::Isometry3d mount = cfg.trajectory.mount.base_to_optical();
  // The mount: camera 0.2 m ahead and 1.35 m up, looking forward and 14 deg down, no roll.
  EXPECT_LT((mount.translation() - Eigen::Vector3d(0.2, 0.0, 1.35)).norm(), 1e-12);
  const Eigen::Vector3d forward = mount.linear().col(2), right = mount.linear().col(0);
  EXPECT_NEAR(std::asin(-forward.z()) * 180 / M_PI, 14.0, 1e-9);
  EXPECT_NEAR(forward.y(), 0.0, 1e-12);
  EXPECT_NEAR(right.z(), 0.0, 1e-12) << "no roll";
  EXPECT_NEAR(right.y(), -1.0, 1e-12) << "image right is the robot's right";
  const Eigen::Isometry3d link = cfg.trajectory.mount.base_to_camera_link();
  EXPECT_TRUE((link * camera_link_to_optical()).isApprox(mount, 1e-15));
  double travelled = 0.0, worst_turn = 0.0, worst_slip = 0.0;
  for (size_t i = 0; i < seq.poses.size(); ++i) {
    const Eigen::Isometry3d& B = seq.base_poses[i];
    EXPECT_TRUE((B * mount).isApprox(seq.poses[i], 1e-15)) << i;
    EXPECT_EQ(B.translation().z(), 0.0);
    EXPECT_NEAR(B.linear()(2, 2), 1.0, 1e-15) << "roll and pitch are zero";
    if (i > 0) {
      const Eigen::Isometry3d step = seq.base_poses[i - 1].inverse() * B;
      travelled += step.translation().norm();
      // Wheeled, no side slip: a step of constant curvature leaves at half its
      // turn (exact on the runs and arcs, close where one meets the other).
      const double turn = Eigen::AngleAxisd(step.linear()).angle();
      const double leave = std::atan2(step.translation().y(), step.translation().x());
      worst_slip = std::max(worst_slip, std::abs(std::abs(leave) - 0.5 * turn));
      worst_turn = std::max(worst_turn, turn * 180 / M_PI);
    }
  }
  EXPECT_NEAR(travelled, cfg.trajectory.speed * 1499, 0.01 * cfg.trajectory.speed * 1499);
  EXPECT_LE(worst_turn, cfg.trajectory.max_yaw_rate_deg);
  EXPECT_GT(worst_turn, 0.5 * cfg.trajectory.max_yaw_rate_deg) << "it does turn";
  EXPECT_LT(worst_slip * 180 / M_PI, 0.2);
  // Furniture keeps the clearance from the robot's body, not only from the camera.
  for (const Eigen::Isometry3d& B : seq.base_poses) {
    const Eigen::Vector3d body = B.translation() + Eigen::Vector3d(0, 0, 0.6);
    for (const Shape& s : seq.scene.shapes) {
      ASSERT_GE(s.distance(body), 0.85 * cfg.trajectory.clearance) << s.label;
    }
  }
}

TEST(SynthRobot, ASlowerCameraGetsEveryNthImageAndTheWholeGroundTruth) {
  // A robot path whose ground truth keeps every frame while the camera
  // images every third one, with the sensor's noise (seeded by frame index).
  SequenceConfig cfg = test::sequence_config(9, TrajectoryType::kRobot, 8, 48, 36);
  cfg.sensor.read_noise = 1.5;
  const Sequence seq = generate_sequence(cfg);
  const std::string all = scratch_dir("synth_every_1"), third = scratch_dir("synth_every_3");
  write_tum_sequence(seq, all);
  std::vector<std::pair<int, int>> progress;
  const WriteStats st = write_tum_sequence(
      seq, third, {}, [&](int i, int n) { progress.emplace_back(i, n); }, 3);
  EXPECT_EQ(st.frames, 3);  // frames 0, 3, 6 of 8
  EXPECT_EQ(progress, (std::vector<std::pair<int, int>>{{1, 3}, {2, 3}, {3, 3}}));
  for (const char* f : {"groundtruth.txt", "base_groundtruth.txt", "camera_mount.txt",
                        "calibration.txt", "scene.json"}) {
    EXPECT_EQ(read_file(all + "/" + f), read_file(third + "/" + f)) << f;
  }
  const TumDataset a = TumDataset::open(all), b = TumDataset::open(third);
  ASSERT_EQ(a.size(), 8u);
  ASSERT_EQ(b.size(), 3u);
  for (size_t k = 0; k < b.size(); ++k) {
    const auto& fa = a.frame(3 * k);
    const auto& fb = b.frame(k);
    EXPECT_EQ(fa.stamp, fb.stamp);
    ASSERT_TRUE(fb.pose.has_value());
    for (auto path : {&TumFrame::rgb_path, &TumFrame::depth_path}) {
      const cv::Mat ia = cv::imread(fa.*path, cv::IMREAD_UNCHANGED);
      const cv::Mat ib = cv::imread(fb.*path, cv::IMREAD_UNCHANGED);
      ASSERT_EQ(ia.size(), ib.size());
      EXPECT_EQ(cv::norm(ia, ib, cv::NORM_INF), 0.0) << "frame " << 3 * k;
    }
  }
  EXPECT_THROW(write_tum_sequence(seq, scratch_dir("synth_every_0"), {}, {}, 0),
               std::invalid_argument);
}

TEST(SynthRobot, WritesBaseGroundTruthAndMount) {
  SequenceConfig cfg = test::sequence_config(8, TrajectoryType::kRobot, 5, 64, 48);
  const Sequence seq = generate_sequence(cfg);
  const std::string dir = scratch_dir("synth_robot_files");
  write_tum_sequence(seq, dir);
  const PoseTrajectory cam = read_tum_trajectory(dir + "/groundtruth.txt");
  const PoseTrajectory base = read_tum_trajectory(dir + "/base_groundtruth.txt");
  const Eigen::Isometry3d mount = read_pose_file(dir + "/camera_mount.txt");
  ASSERT_EQ(cam.size(), 5u);
  ASSERT_EQ(base.size(), 5u);
  for (size_t i = 0; i < 5; ++i) {
    EXPECT_EQ(base.stamps[i], cam.stamps[i]);
    const Eigen::Isometry3d composed = base.poses[i] * mount;
    EXPECT_LT((composed.translation() - cam.poses[i].translation()).norm(), 1e-8);
    EXPECT_LT((composed.linear() - cam.poses[i].linear()).norm(), 1e-8);
  }
  EXPECT_LT((mount.matrix() - cfg.trajectory.mount.base_to_optical().matrix()).norm(), 1e-8);
  // A mount the room cannot hold is refused.
  cfg.trajectory.mount.z = 0.2;  // below the clearance
  EXPECT_THROW(generate_sequence(cfg), std::invalid_argument);
}
