#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>

#include <filesystem>
#include <fstream>

#include "long3r/dataset/tum_dataset.hpp"
#include "long3r/synth/cv/sensor_image.hpp"
#include "long3r/synth/cv/tum_writer.hpp"
#include "long3r/synth/generate.hpp"
#include "long3r/synth/render.hpp"
#include "support/test_support.hpp"

using namespace long3r;

namespace {

using test::scratch_dir;
using test::write_file;

}  // namespace

TEST(TumDataset, RoundTripsWhatTheGeneratorWrites) {
  synth::SequenceConfig cfg;
  cfg.seed = 13;
  cfg.trajectory.frames = 6;
  cfg.intrinsics = PinholeIntrinsics::from_hfov(80, 60, 65.0);
  cfg.start_time = 1305031102.175304;  // a TUM-like epoch stamp
  const synth::Sequence seq = synth::generate_sequence(cfg);
  const std::string dir = scratch_dir("tum_roundtrip");
  synth::write_tum_sequence(seq, dir);

  const TumDataset ds = TumDataset::open(dir);
  ASSERT_EQ(ds.size(), 6u);
  ASSERT_TRUE(ds.calibration().has_value());
  const PinholeIntrinsics& k = *ds.calibration();
  EXPECT_NEAR(k.fx, cfg.intrinsics.fx, 1e-6);
  EXPECT_NEAR(k.fy, cfg.intrinsics.fy, 1e-6);
  EXPECT_EQ(k.cx, cfg.intrinsics.cx);
  EXPECT_EQ(k.cy, cfg.intrinsics.cy);
  EXPECT_EQ(k.width, 80);
  EXPECT_EQ(k.height, 60);
  EXPECT_EQ(ds.ground_truth().size(), 6u);
  for (size_t i = 0; i < ds.size(); ++i) {
    const TumFrame& f = ds.frame(i);
    EXPECT_NEAR(f.stamp, seq.stamps[i], 1e-6);
    ASSERT_FALSE(f.depth_path.empty());
    ASSERT_TRUE(f.pose.has_value());
    EXPECT_LT((f.pose->translation() - seq.poses[i].translation()).norm(), 2e-9);
    EXPECT_LT((f.pose->linear() - seq.poses[i].linear()).norm(), 1e-8);

    const synth::RenderedFrame r = synth::render_frame(seq.scene, seq.poses[i], cfg.intrinsics);
    const cv::Mat rgb = ds.load_rgb(i);
    ASSERT_EQ(rgb.type(), CV_8UC3);
    EXPECT_EQ(cv::norm(rgb, synth::bgr_image(r), cv::NORM_INF), 0.0)
        << "colour differs at frame " << i;
    const cv::Mat depth = ds.load_depth(i);
    ASSERT_EQ(depth.type(), CV_32FC1);
    // 16-bit PNG at 5000 per metre: half a step of rounding.
    EXPECT_LE(cv::norm(depth, synth::depth_image(r), cv::NORM_INF), 0.5 / 5000.0 + 1e-6)
        << "frame " << i;
  }
  const PoseTrajectory t = ds.frame_trajectory();
  EXPECT_EQ(t.size(), 6u);
}

TEST(TumDataset, TrajectoryAndCalibrationFiles) {
  const std::string dir = scratch_dir("tum_files");
  PoseTrajectory t;
  for (int i = 0; i < 3; ++i) {
    Eigen::Isometry3d p = Eigen::Isometry3d::Identity();
    p.linear() =
        Eigen::AngleAxisd(0.4 * i + 2.5, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    p.translation() = Eigen::Vector3d(i, -i, 0.5);
    t.stamps.push_back(10.0 + i);
    t.poses.push_back(p);
  }
  write_tum_trajectory(dir + "/t.txt", t, "test");
  const PoseTrajectory r = read_tum_trajectory(dir + "/t.txt");
  ASSERT_EQ(r.size(), 3u);
  for (size_t i = 0; i < 3; ++i) {
    EXPECT_EQ(r.stamps[i], t.stamps[i]);
    EXPECT_LT((r.poses[i].matrix() - t.poses[i].matrix()).norm(), 1e-8);
  }
  // Unnormalised quaternions are normalised; commas accepted; bad lines rejected.
  write_file(dir + "/u.txt", "# c\n1.0, 0,0,0, 0,0,0,2\n\n");
  EXPECT_LT(
      (read_tum_trajectory(dir + "/u.txt").poses[0].linear() - Eigen::Matrix3d::Identity()).norm(),
      1e-12);
  write_file(dir + "/bad.txt", "1.0 0 0 0 0 0 0\n");
  EXPECT_THROW(read_tum_trajectory(dir + "/bad.txt"), std::runtime_error);
  EXPECT_THROW(read_tum_trajectory(dir + "/missing.txt"), std::runtime_error);

  write_file(dir + "/calib4.txt", "# fx fy cx cy\n525.0 526.0 319.5 239.5\n");
  const PinholeIntrinsics k4 = read_calibration_file(dir + "/calib4.txt");
  EXPECT_EQ(k4.fx, 525.0);
  EXPECT_EQ(k4.cy, 239.5);
  EXPECT_EQ(k4.width, 0);
  write_file(dir + "/calib_bad.txt", "525 0 1 1\n");
  EXPECT_THROW(read_calibration_file(dir + "/calib_bad.txt"), std::runtime_error);
}

TEST(TumDataset, CalibrationRoundTripsWithAndWithoutDistortion) {
  const std::string dir = scratch_dir("tum_calibration");
  PinholeIntrinsics k;
  k.fx = 525.25;
  k.fy = 526.5;
  k.cx = 319.75;
  k.cy = 239.125;
  k.width = 640;
  k.height = 480;
  // Without distortion: the file of earlier versions, byte for byte.
  write_calibration_file(dir + "/plain.txt", k);
  EXPECT_EQ(test::read_file(dir + "/plain.txt"),
            "# pinhole intrinsics in pixels; pixel centres at integer coordinates\n"
            "# fx fy cx cy width height\n525.25 526.5 319.75 239.125 640 480\n");
  const CameraCalibration plain = read_camera_calibration(dir + "/plain.txt");
  EXPECT_EQ(plain.distortion_model, "");
  EXPECT_TRUE(plain.distortion.empty());
  EXPECT_FALSE(plain.distorted());
  EXPECT_EQ(read_calibration_file(dir + "/plain.txt").fx, 525.25);

  // With: every coefficient comes back bit for bit, whatever the model.
  const CameraCalibration lens{k, "plumb_bob", {-0.28, 0.0912345678901234, 1.5e-4, -7e-5, 0.1 / 3}};
  write_camera_calibration(dir + "/lens.txt", lens);
  const CameraCalibration back = read_camera_calibration(dir + "/lens.txt");
  EXPECT_EQ(back.distortion_model, "plumb_bob");
  EXPECT_EQ(back.distortion, lens.distortion);
  EXPECT_EQ(back.intrinsics.width, 640);
  EXPECT_EQ(back.intrinsics.fy, 526.5);
  EXPECT_TRUE(back.distorted());
  // A pinhole reader refuses it rather than dropping the lens.
  EXPECT_THROW(read_calibration_file(dir + "/lens.txt"), std::runtime_error);
  const CameraCalibration fisheye{k, "equidistant", {0.1, -0.02, 0.003, -0.0004}};
  write_camera_calibration(dir + "/fisheye.txt", fisheye);
  EXPECT_EQ(read_camera_calibration(dir + "/fisheye.txt").distortion, fisheye.distortion);
  // A model with all-zero coefficients is a pinhole camera.
  write_file(dir + "/zeros.txt", "500 500 320 240 640 480 plumb_bob 0 0 0 0 0\n");
  EXPECT_EQ(read_calibration_file(dir + "/zeros.txt").cx, 320.0);

  // Bad files: unknown model, too few or too many coefficients, non-finite.
  for (const char* bad : {"500 500 320 240 640 480 fisheye 0.1 0 0 0\n",
                          "500 500 320 240 640 480 plumb_bob 0.1 0 0 0\n",
                          "500 500 320 240 640 480 plumb_bob 0.1 0 0 0 0 0\n",
                          "500 500 320 240 640 480 plumb_bob nan 0 0 0 0\n"}) {
    write_file(dir + "/bad.txt", bad);
    EXPECT_THROW(read_camera_calibration(dir + "/bad.txt"), std::runtime_error) << bad;
  }
  EXPECT_THROW(write_camera_calibration(dir + "/x.txt", CameraCalibration{k, "plumb_bob", {0.1}}),
               std::invalid_argument);
  EXPECT_THROW(distortion_coefficient_count("fisheye"), std::invalid_argument);
  EXPECT_EQ(distortion_coefficient_count("rational_polynomial"), 8);
}

TEST(TumDataset, PoseFileRoundTrips) {
  const std::string dir = scratch_dir("tum_pose_file");
  Eigen::Isometry3d p = Eigen::Isometry3d::Identity();
  p.linear() = Eigen::AngleAxisd(2.0, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  p.translation() = Eigen::Vector3d(0.2, -0.05, 1.3);
  write_pose_file(dir + "/mount.txt", p, "a mount");
  EXPECT_LT((read_pose_file(dir + "/mount.txt").matrix() - p.matrix()).norm(), 1e-8);
  write_file(dir + "/two.txt", "0 0 0 0 0 0 1\n0 0 0 0 0 0 1\n");
  EXPECT_THROW(read_pose_file(dir + "/two.txt"), std::runtime_error);
  write_file(dir + "/short.txt", "0 0 0 0 0 1\n");
  EXPECT_THROW(read_pose_file(dir + "/short.txt"), std::runtime_error);
}

TEST(TumDataset, AssociationIsTumsGreedyClosestFirst) {
  // a[1] and b[0] are closest, so a[0] stays unmatched although within range.
  auto m = associate_timestamps({0.0, 0.01}, {0.006}, 0.02);
  ASSERT_EQ(m.size(), 1u);
  EXPECT_EQ(m[0], std::make_pair(1, 0));
  // Strictly below max_diff; result sorted by a.
  m = associate_timestamps({0.3, 0.1, 0.2}, {0.205, 0.32, 0.1001}, 0.02);
  ASSERT_EQ(m.size(), 2u);
  EXPECT_EQ(m[0], std::make_pair(1, 2));
  EXPECT_EQ(m[1], std::make_pair(2, 0));
  // Offset applies to b.
  m = associate_timestamps({1.0}, {0.5}, 0.01, 0.5);
  ASSERT_EQ(m.size(), 1u);
}

TEST(TumDataset, OpensHandWrittenTumFolder) {
  // rgb at 30 Hz, depth slightly off and one missing, ground truth at 100 Hz.
  const std::string dir = scratch_dir("tum_hand");
  std::filesystem::create_directories(dir + "/rgb");
  write_file(dir + "/rgb.txt",
             "# color\n1.000 rgb/a.png\n1.033 rgb/b.png\n1.066 rgb/c.png\n5.0 rgb/d.png\n");
  write_file(dir + "/depth.txt", "1.002 depth/a.png\n1.064 depth/c.png\n");
  std::string gt = "# timestamp tx ty tz qx qy qz qw\n";
  for (int i = 0; i < 20; ++i)
    gt += std::to_string(0.995 + 0.01 * i) + " " + std::to_string(i) + " 0 0 0 0 0 1\n";
  write_file(dir + "/groundtruth.txt", gt);
  TumDataset ds = TumDataset::open(dir);
  ASSERT_EQ(ds.size(), 4u);
  EXPECT_FALSE(ds.calibration().has_value());
  EXPECT_EQ(ds.frame(0).depth_path, (std::filesystem::path(dir) / "depth/a.png").string());
  EXPECT_TRUE(ds.frame(1).depth_path.empty());
  EXPECT_EQ(ds.frame(2).depth_stamp, 1.064);
  ASSERT_TRUE(ds.frame(1).pose.has_value());
  EXPECT_NEAR(ds.frame(1).pose_stamp, 1.035, 1e-9);  // nearest of 1.025 / 1.035
  EXPECT_NEAR(ds.frame(1).pose->translation().x(), 4.0, 1e-12);
  EXPECT_FALSE(ds.frame(3).pose.has_value());  // 5.0 s has no ground truth
  EXPECT_THROW(ds.load_depth(1), std::runtime_error);
  EXPECT_THROW(ds.load_rgb(0), std::runtime_error);  // listed but not on disk

  TumDatasetOptions strict;
  strict.require_depth = true;
  strict.require_pose = true;
  EXPECT_EQ(TumDataset::open(dir, strict).size(), 2u);
  EXPECT_THROW(TumDataset::open(dir + "/nope"), std::runtime_error);
}

TEST(TumDataset, ImageFolderInNaturalOrder) {
  const std::string dir = scratch_dir("image_folder");
  const cv::Mat img(4, 5, CV_8UC3, cv::Scalar(1, 2, 3));
  for (const char* n : {"frame10.png", "frame2.png", "frame1.PNG", "frame02b.jpg"}) {
    cv::imwrite(dir + "/" + n, img);
  }
  write_file(dir + "/notes.txt", "not an image");
  const ImageFolder f = ImageFolder::open(dir);
  ASSERT_EQ(f.size(), 4u);
  auto name = [&](size_t i) { return std::filesystem::path(f.path(i)).filename().string(); };
  EXPECT_EQ(name(0), "frame1.PNG");
  EXPECT_EQ(name(1), "frame2.png");
  EXPECT_EQ(name(2), "frame02b.jpg");
  EXPECT_EQ(name(3), "frame10.png");
  EXPECT_EQ(f.load(1).size(), cv::Size(5, 4));
  EXPECT_TRUE(natural_less("a9", "a10"));
  EXPECT_FALSE(natural_less("a10", "a9"));
  EXPECT_TRUE(natural_less("a", "ab"));
}
