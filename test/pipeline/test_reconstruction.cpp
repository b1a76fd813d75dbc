// Reconstruction pipeline: plumbing checked against exact ground truth with a
// fake model that returns the generator's pointmaps, and the real (random
// weight) Spann3R model end to end.
#include <ATen/core/Tensor.h>
#include <ATen/ops/from_blob.h>
#include <gtest/gtest.h>

#include <cmath>
#include <deque>
#include <opencv2/imgproc.hpp>

#include "long3r/eval/eval.hpp"
#include "long3r/io/safetensors_header.hpp"
#include "long3r/model/network/model_config.hpp"
#include "long3r/model/network/spann3r_model.hpp"
#include "long3r/pipeline/reconstruction.hpp"
#include "long3r/synth/cv/sensor_image.hpp"
#include "support/cv_test_support.hpp"

namespace long3r {
namespace {

constexpr int kSize = test::kGtSize;
using test::FakeModel;
using test::GtSequence;
using test::make_sequence;

TEST(Reconstruction, FakeModelPosesMatchGroundTruth) {
  const GtSequence g = make_sequence(6);
  Reconstruction rec(std::make_unique<FakeModel>(&g.pts_W0), test::gt_reconstruction_config());
  rec.set_calibration(g.seq.config.intrinsics);
  std::vector<FrameResult> results;
  for (size_t k = 0; k < g.bgr.size(); ++k) {
    auto r = rec.push(g.bgr[k], "bgr8", 0.1 * k);
    EXPECT_EQ(r.has_value(), k > 0);
    if (r) results.push_back(std::move(*r));
  }
  auto last = rec.flush();
  ASSERT_TRUE(last.has_value());
  EXPECT_TRUE(last->from_coarse_head);
  results.push_back(std::move(*last));
  ASSERT_EQ(results.size(), g.bgr.size());
  for (size_t k = 0; k < results.size(); ++k) {
    const FrameResult& r = results[k];
    EXPECT_EQ(r.frame_index, static_cast<int64_t>(k));
    EXPECT_DOUBLE_EQ(r.stamp, 0.1 * k);
    ASSERT_TRUE(r.pose.ok()) << k << ": " << r.pose.message;
    EXPECT_TRUE(r.added_to_map);
    EXPECT_EQ(r.model.mem_short_tokens, 7);
    EXPECT_EQ(r.intrinsics_source, IntrinsicsSource::kCalibration);
    EXPECT_NEAR(r.intrinsics.fx, g.seq.config.intrinsics.fx, 1e-9);
    const Eigen::Isometry3d d = g.T_0_k[k].inverse() * r.pose.T_W_C;
    EXPECT_LT(d.translation().norm(), 1e-3) << k;
    EXPECT_LT(Eigen::AngleAxisd(d.rotation()).angle(), 1e-3) << k;
    // Points in the camera frame: z-depth must be positive where finite.
    ASSERT_EQ(r.points_C.type(), CV_32FC3);
    const cv::Vec3f c = r.points_C.at<cv::Vec3f>(kSize / 2, kSize / 2);
    if (std::isfinite(c[2])) {
      EXPECT_GT(c[2], 0.f);
    }
  }
  EXPECT_GT(rec.map().size(), 100u);
  EXPECT_EQ(rec.trajectory().size(), g.bgr.size());
}

// A pause in the input: flush() gives the pending frame now, and the frames
// after the pause continue the same stream (world frame, map, trajectory).
TEST(Reconstruction, FlushIsAPauseNotAnEnd) {
  const GtSequence g = make_sequence(7);
  Reconstruction rec(std::make_unique<FakeModel>(&g.pts_W0), test::gt_reconstruction_config());
  rec.set_calibration(g.seq.config.intrinsics);
  std::vector<FrameResult> results;
  auto take = [&](std::optional<FrameResult> r) {
    if (r) results.push_back(std::move(*r));
  };
  EXPECT_FALSE(rec.flush().has_value());  // nothing pushed
  for (int k = 0; k < 3; ++k) take(rec.push(g.bgr[k], "bgr8", 0.1 * k));
  ASSERT_EQ(results.size(), 2u);
  take(rec.flush());  // frame 2, early
  ASSERT_EQ(results.size(), 3u);
  EXPECT_TRUE(results.back().from_coarse_head);
  EXPECT_FALSE(rec.flush().has_value());  // nothing pending any more
  const size_t map_before = rec.map().size();
  take(rec.push(g.bgr[3], "bgr8", 10.0));  // after the pause: frame 2 is not returned again
  EXPECT_EQ(results.size(), 3u);
  for (int k = 4; k < 7; ++k) take(rec.push(g.bgr[k], "bgr8", 10.0 + 0.1 * k));
  take(rec.flush());
  ASSERT_EQ(results.size(), g.bgr.size());
  for (size_t k = 0; k < results.size(); ++k) {
    EXPECT_EQ(results[k].frame_index, static_cast<int64_t>(k));
    ASSERT_TRUE(results[k].pose.ok()) << k;
    // One world frame across the pause: camera 0's.
    const Eigen::Isometry3d d = g.T_0_k[k].inverse() * results[k].pose.T_W_C;
    EXPECT_LT(d.translation().norm(), 1e-3) << k;
  }
  EXPECT_GE(rec.map().size(), map_before);
  EXPECT_EQ(rec.trajectory().size(), g.bgr.size());
  EXPECT_EQ(rec.frames_pushed(), 7);
}

// A metric scale set mid-stream: what was built is rescaled at once, what
// comes after is in the new scale; the stream stays one.
TEST(Reconstruction, SetScaleRescalesTheStream) {
  const GtSequence g = make_sequence(6);
  Reconstruction rec(std::make_unique<FakeModel>(&g.pts_W0), test::gt_reconstruction_config());
  rec.set_calibration(g.seq.config.intrinsics);
  std::vector<FrameResult> results;
  for (int k = 0; k < 3; ++k) {
    if (auto r = rec.push(g.bgr[k], "bgr8", 0.1 * k)) results.push_back(std::move(*r));
  }
  ASSERT_EQ(results.size(), 2u);
  const Eigen::Vector3d before = rec.trajectory()[1].second.translation();
  const std::size_t points_before = rec.map().size();
  rec.set_scale(2.0);
  EXPECT_DOUBLE_EQ(rec.scale(), 2.0);
  EXPECT_TRUE(rec.trajectory()[1].second.translation().isApprox(2.0 * before));
  EXPECT_GT(rec.map().size(), 0u);
  EXPECT_LE(rec.map().size(), points_before);  // the same voxel size holds fewer, larger points
  for (int k = 3; k < 6; ++k) {
    if (auto r = rec.push(g.bgr[k], "bgr8", 0.1 * k)) results.push_back(std::move(*r));
  }
  results.push_back(*rec.flush());
  ASSERT_EQ(results.size(), 6u);
  for (int k = 2; k < 6; ++k) {
    const FrameResult& r = results[k];
    EXPECT_DOUBLE_EQ(r.scale, 2.0);
    ASSERT_TRUE(r.pose.ok());
    EXPECT_LT((r.pose.T_W_C.translation() - 2.0 * g.T_0_k[k].translation()).norm(), 2e-3) << k;
    ASSERT_TRUE(r.pose.covariance.has_value());
  }
  EXPECT_THROW(rec.set_scale(-1.0), std::invalid_argument);
  rec.reset();
  EXPECT_DOUBLE_EQ(rec.scale(), 1.0);
}

// surface.enabled: every mapped frame goes into the fused surface too, in the
// stream's world; sessions keep it, set_scale() rebuilds it at the new
// scale, reset() clears it.
TEST(Reconstruction, FusesMappedFramesIntoTheSurface) {
  if (!TsdfVolume::available()) GTEST_SKIP() << "built without Open3D";
  const GtSequence g = make_sequence(8);
  ReconstructionConfig config = test::gt_reconstruction_config();
  config.surface.enabled = true;
  config.surface.tsdf.voxel_size_m = 0.05;
  config.surface.tsdf.truncation_m = 0.2;
  config.surface.tsdf.min_weight = 2.0f;
  Reconstruction rec(std::make_unique<FakeModel>(&g.pts_W0), config);
  rec.set_calibration(g.seq.config.intrinsics);
  for (size_t k = 0; k < g.bgr.size(); ++k) rec.push(g.bgr[k], "bgr8", 0.1 * k);
  ASSERT_TRUE(rec.flush().has_value());
  EXPECT_EQ(rec.surface().frames_kept(), g.bgr.size());
  // Within a voxel of the true points (camera 0's frame).
  std::vector<Eigen::Vector3f> truth;
  for (const cv::Mat& pts : g.pts_W0) {
    for (auto it = pts.begin<cv::Vec3f>(); it != pts.end<cv::Vec3f>(); ++it) {
      if (std::isfinite((*it)[0])) truth.emplace_back((*it)[0], (*it)[1], (*it)[2]);
    }
  }
  auto accuracy = [&](const std::vector<Eigen::Vector3f>& points) {
    ReconstructionMetricsOptions o;
    o.normals = false;
    return reconstruction_metrics(points, truth, o).accuracy_mean;
  };
  const ColoredPoints surface = rec.surface().points();
  ASSERT_GT(surface.points.size(), 100u);
  EXPECT_LT(accuracy(surface.points), 0.05);
  // Kept by state() / restore(): the same surface, rebuilt from its frames;
  // a session without one starts it empty.
  const StateDict saved = rec.state();
  Reconstruction other(std::make_unique<FakeModel>(&g.pts_W0), config);
  other.restore(saved);
  EXPECT_EQ(other.surface().frames_kept(), g.bgr.size());
  EXPECT_EQ(other.surface().points().points.size(), surface.points.size());
  EXPECT_LT(accuracy(other.surface().points().points), 0.05);
  StateDict without = saved;
  for (auto it = without.begin(); it != without.end();) {
    it = it->first.rfind("surface.", 0) == 0 ? without.erase(it) : std::next(it);
  }
  other.restore(without);
  EXPECT_EQ(other.surface().frames_kept(), 0u);
  // Twice the scale: the surface is rebuilt twice as large (and as accurate
  // against the doubled truth).
  rec.set_scale(2.0);
  for (Eigen::Vector3f& p : truth) p *= 2.0f;
  const ColoredPoints doubled = rec.surface().points();
  ASSERT_GT(doubled.points.size(), surface.points.size());
  EXPECT_LT(accuracy(doubled.points), 0.05);
  rec.reset();
  EXPECT_TRUE(rec.surface().points().points.empty());
  EXPECT_EQ(rec.surface().frames_kept(), 0u);
}

// maps_in_background (the default) runs the surface's and the occupancy's
// updates on a thread of their own; every reader waits for them, so the maps,
// the sessions and a rescale read the same as with the updates in line.
TEST(Reconstruction, MapsInBackgroundReadTheSameAsInLine) {
  const GtSequence g = make_sequence(8);
  ReconstructionConfig config = test::gt_reconstruction_config();
  config.surface.enabled = TsdfVolume::available();
  config.surface.tsdf.voxel_size_m = 0.05;
  config.surface.tsdf.truncation_m = 0.2;
  auto run = [&](bool background) {
    ReconstructionConfig c = config;
    c.maps_in_background = background;
    auto rec = std::make_unique<Reconstruction>(std::make_unique<FakeModel>(&g.pts_W0), c);
    rec->set_calibration(g.seq.config.intrinsics);
    for (size_t k = 0; k < g.bgr.size(); ++k) rec->push(g.bgr[k], "bgr8", 0.1 * k);
    EXPECT_TRUE(rec->flush().has_value());
    return rec;
  };
  const std::unique_ptr<Reconstruction> inline_rec = run(false), background = run(true);
  ASSERT_GT(inline_rec->occupancy().voxels(), 0u);
  EXPECT_EQ(background->occupancy().write(), inline_rec->occupancy().write());
  EXPECT_EQ(background->surface().frames_kept(), inline_rec->surface().frames_kept());
  EXPECT_EQ(background->surface().points().points.size(),
            inline_rec->surface().points().points.size());
  const StateDict a = inline_rec->state(), b = background->state();
  EXPECT_EQ(StateReader(b, "b").bytes("occupancy.ot"), StateReader(a, "a").bytes("occupancy.ot"));
  inline_rec->set_scale(2.0);
  background->set_scale(2.0);
  EXPECT_EQ(background->occupancy().write(), inline_rec->occupancy().write());
}

// The occupancy of the mapped views (on by default) in W: what the views saw
// is occupied, rescaled with the stream, and kept by state() / restore().
TEST(Reconstruction, KeepsTheOccupancyOfTheMappedViews) {
  const GtSequence g = make_sequence(6);
  Reconstruction rec(std::make_unique<FakeModel>(&g.pts_W0), test::gt_reconstruction_config());
  rec.set_calibration(g.seq.config.intrinsics);
  for (size_t k = 0; k < g.bgr.size(); ++k) rec.push(g.bgr[k], "bgr8", 0.1 * k);
  ASSERT_TRUE(rec.flush().has_value());
  ASSERT_GT(rec.occupancy().voxels(), 0u);
  // A pixel of frame 2 whose ray it cast (pixel_step 4: pixels 2, 6, ...),
  // occupied; the camera: free.
  const cv::Vec3f c = g.pts_W0[2].at<cv::Vec3f>(34, 34);
  ASSERT_TRUE(std::isfinite(c[0]));
  const Eigen::Vector3d hit(c[0], c[1], c[2]);
  EXPECT_EQ(rec.occupancy().occupied(hit), std::optional<bool>(true));
  EXPECT_EQ(rec.occupancy().occupied(g.T_0_k[2].translation()), std::optional<bool>(false));
  const StateDict saved = rec.state();
  rec.set_scale(2.0);
  EXPECT_EQ(rec.occupancy().occupied(2.0 * hit), std::optional<bool>(true));
  // Restored: the occupancy as it was saved.
  Reconstruction other(std::make_unique<FakeModel>(&g.pts_W0), test::gt_reconstruction_config());
  other.restore(saved);
  EXPECT_EQ(other.occupancy().write(), StateReader(saved, "saved").bytes("occupancy.ot"));
  EXPECT_EQ(other.occupancy().occupied(hit), std::optional<bool>(true));
  // A session without one (saved with it off, or before it existed) starts empty.
  StateDict without = saved;
  without.erase("occupancy.ot");
  other.restore(without);
  EXPECT_EQ(other.occupancy().voxels(), 0u);
  // A damaged one is refused by name, and nothing changes: a byte changed
  // (its check sum no longer matches, so OctoMap never parses it) ...
  StateDict flipped = saved;
  flipped["occupancy.ot"] = saved.at("occupancy.ot").clone();
  flipped["occupancy.ot"].data_ptr<std::uint8_t>()[20] ^= 0x10;
  try {
    other.restore(flipped);
    ADD_FAILURE() << "a damaged occupancy was restored";
  } catch (const StateError& e) {
    EXPECT_NE(std::string(e.what()).find("check sum"), std::string::npos) << e.what();
  }
  // ... or whole bytes that are no OctoMap file.
  StateDict damaged = saved;
  damaged["occupancy.ot"] = bytes_tensor("not an octree");
  EXPECT_THROW(other.restore(damaged), StateError);
  try {
    other.restore(damaged);
  } catch (const StateError& e) {
    EXPECT_NE(std::string(e.what()).find("occupancy.ot"), std::string::npos) << e.what();
  }
}

// rescale() brings one result to a scale as set_scale() brings the stream.
TEST(Reconstruction, RescaleBringsOneResultToAScale) {
  const GtSequence g = make_sequence(3);
  Reconstruction rec(std::make_unique<FakeModel>(&g.pts_W0), test::gt_reconstruction_config());
  rec.set_calibration(g.seq.config.intrinsics);
  rec.push(g.bgr[0], "bgr8", 0.0);
  rec.push(g.bgr[1], "bgr8", 0.1);  // frame 0: identity pose, no covariance needed
  const std::optional<FrameResult> r = rec.push(g.bgr[2], "bgr8", 0.2);
  ASSERT_TRUE(r && r->pose.ok() && r->pose.covariance);
  ASSERT_EQ(r->frame_index, 1);
  FrameResult s = *r;
  Reconstruction::rescale(s, 2.0);
  EXPECT_DOUBLE_EQ(s.scale, 2.0);
  EXPECT_LT(cv::norm(s.points_W, 2.0 * r->points_W, cv::NORM_INF), 1e-5);
  EXPECT_LT(cv::norm(s.points_C, 2.0 * r->points_C, cv::NORM_INF), 1e-5);
  EXPECT_TRUE(s.pose.T_W_C.translation().isApprox(2.0 * r->pose.T_W_C.translation()));
  EXPECT_TRUE(s.pose.T_W_C.linear().isApprox(r->pose.T_W_C.linear()));
  EXPECT_TRUE(s.model_T_W_C.translation().isApprox(2.0 * r->model_T_W_C.translation()));
  const Eigen::Matrix<double, 6, 6>& a = *r->pose.covariance;
  const Eigen::Matrix<double, 6, 6>& b = *s.pose.covariance;
  // Translation block x factor^2, the cross blocks x factor, rotation as it was.
  const Eigen::Matrix3d tt = b.topLeftCorner(3, 3), tr = b.topRightCorner(3, 3);
  const Eigen::Matrix3d rt = b.bottomLeftCorner(3, 3), rr = b.bottomRightCorner(3, 3);
  EXPECT_TRUE(tt.isApprox(4.0 * a.topLeftCorner(3, 3)));
  EXPECT_TRUE(tr.isApprox(2.0 * a.topRightCorner(3, 3)));
  EXPECT_TRUE(rt.isApprox(2.0 * a.bottomLeftCorner(3, 3)));
  EXPECT_TRUE(rr == a.bottomRightCorner(3, 3));
  Reconstruction::rescale(s, 1.0);  // and back
  EXPECT_LT(cv::norm(s.points_W, r->points_W, cv::NORM_INF), 1e-5);
  EXPECT_DOUBLE_EQ(s.scale, 1.0);
}

// A pose given to push() places the frame's own geometry (pose from odometry).
TEST(Reconstruction, GivenPosePlacesTheFrame) {
  const GtSequence g = make_sequence(6);
  Reconstruction rec(std::make_unique<FakeModel>(&g.pts_W0), test::gt_reconstruction_config());
  rec.set_calibration(g.seq.config.intrinsics);
  Eigen::Isometry3d shift = Eigen::Isometry3d::Identity();
  shift.translation() = Eigen::Vector3d(0.5, 0.0, 0.0);
  std::vector<FrameResult> results;
  for (int k = 0; k < 4; ++k) {
    const Eigen::Isometry3d given = k == 0 ? Eigen::Isometry3d::Identity() : shift * g.T_0_k[k];
    if (auto r = rec.push(g.bgr[k], "bgr8", 0.1 * k, given)) results.push_back(std::move(*r));
  }
  results.push_back(*rec.flush());
  ASSERT_EQ(results.size(), 4u);
  for (int k = 1; k < 4; ++k) {
    const FrameResult& r = results[k];
    ASSERT_TRUE(r.pose.ok());
    EXPECT_TRUE(r.pose.T_W_C.isApprox(shift * g.T_0_k[k], 1e-9));
    EXPECT_TRUE(r.model_T_W_C.isApprox(g.T_0_k[k], 1e-3));  // the model's own pose
    // The frame's points moved with it: world = given pose * camera points.
    const cv::Vec3f c = r.points_C.at<cv::Vec3f>(kSize / 2, kSize / 2);
    const cv::Vec3f w = r.points_W.at<cv::Vec3f>(kSize / 2, kSize / 2);
    if (std::isfinite(c[2])) {
      const Eigen::Vector3d expected = shift * g.T_0_k[k] * Eigen::Vector3d(c[0], c[1], c[2]);
      EXPECT_LT((expected - Eigen::Vector3d(w[0], w[1], w[2])).norm(), 1e-4);
    }
  }
  EXPECT_TRUE(rec.trajectory()[2].second.isApprox(shift * g.T_0_k[2], 1e-9));
  rec.set_mapping(false);  // posed, but not fused
  const std::size_t n = rec.map().size();
  EXPECT_FALSE(rec.push(g.bgr[4], "bgr8", 0.4, shift * g.T_0_k[4]).has_value());
  auto r = rec.push(g.bgr[5], "bgr8", 0.5, shift * g.T_0_k[5]);
  ASSERT_TRUE(r.has_value());
  EXPECT_EQ(r->frame_index, 4);
  EXPECT_TRUE(r->pose.ok());
  EXPECT_FALSE(r->added_to_map);
  EXPECT_EQ(rec.map().size(), n);
}

// A frame placed by a given pose stays in the path when its PnP fails (the
// odometry places it), but is not mapped: its camera-frame points need PnP.
TEST(Reconstruction, GivenPosePlacesAFrameWhosePnpFails) {
  const GtSequence g = make_sequence(4);
  ReconstructionConfig cfg = test::gt_reconstruction_config();
  // Every PnP after frame 0 fails: more inliers needed than a frame has pixels.
  cfg.pnp.min_inliers = cfg.pnp.max_correspondences = 1000000;
  Reconstruction rec(std::make_unique<FakeModel>(&g.pts_W0), cfg);
  rec.set_calibration(g.seq.config.intrinsics);
  Eigen::Isometry3d shift = Eigen::Isometry3d::Identity();
  shift.translation() = Eigen::Vector3d(0.5, 0.0, 0.0);
  EXPECT_FALSE(rec.push(g.bgr[0], "bgr8", 0.0, Eigen::Isometry3d::Identity()).has_value());
  const std::optional<FrameResult> first = rec.push(g.bgr[1], "bgr8", 0.1, shift * g.T_0_k[1]);
  ASSERT_TRUE(first.has_value());
  EXPECT_TRUE(first->pose.ok());  // frame 0 defines the world
  const std::size_t mapped = rec.map().size();
  EXPECT_GT(mapped, 0u);
  const std::optional<FrameResult> r = rec.push(g.bgr[2], "bgr8", 0.2, shift * g.T_0_k[2]);
  ASSERT_TRUE(r.has_value());
  EXPECT_FALSE(r->pose.ok());
  EXPECT_TRUE(r->pose_given);
  EXPECT_TRUE(r->posed());
  EXPECT_TRUE(r->pose.T_W_C.isApprox(shift * g.T_0_k[1], 1e-12));
  EXPECT_TRUE(r->points_C.empty());
  EXPECT_FALSE(r->added_to_map);
  EXPECT_EQ(rec.map().size(), mapped);
  ASSERT_EQ(rec.trajectory().size(), 2u);
  EXPECT_TRUE(rec.trajectory()[1].second.isApprox(shift * g.T_0_k[1], 1e-12));
  // Without a given pose the same failure leaves the path alone.
  Reconstruction plain(std::make_unique<FakeModel>(&g.pts_W0), cfg);
  plain.set_calibration(g.seq.config.intrinsics);
  plain.push(g.bgr[0], "bgr8", 0.0);
  plain.push(g.bgr[1], "bgr8", 0.1);
  const std::optional<FrameResult> p = plain.push(g.bgr[2], "bgr8", 0.2);
  ASSERT_TRUE(p.has_value());
  EXPECT_FALSE(p->posed());
  EXPECT_EQ(plain.trajectory().size(), 1u);
}

// A metric scale found later rescales what the model measured, never the
// poses given in metres (odometry), in the stream and in the result.
TEST(Reconstruction, ScaleLeavesGivenPosesAlone) {
  const GtSequence g = make_sequence(5);
  Reconstruction rec(std::make_unique<FakeModel>(&g.pts_W0), test::gt_reconstruction_config());
  rec.set_calibration(g.seq.config.intrinsics);
  std::vector<FrameResult> results;
  for (int k = 0; k < 4; ++k) {  // frames 0 and 2 placed by the given pose, 1 and 3 by PnP
    std::optional<Eigen::Isometry3d> given;
    if (k % 2 == 0) given = g.T_0_k[k];
    if (auto r = rec.push(g.bgr[k], "bgr8", 0.1 * k, given)) results.push_back(std::move(*r));
  }
  ASSERT_EQ(rec.trajectory().size(), 3u);
  const auto before = rec.trajectory();
  FrameResult r = results[2];  // frame 2, given
  ASSERT_TRUE(r.pose_given && r.pose.ok());
  Reconstruction::rescale(r, 2.0);
  EXPECT_TRUE(r.pose.T_W_C.isApprox(results[2].pose.T_W_C, 1e-12));
  EXPECT_TRUE(r.model_T_W_C.translation().isApprox(2.0 * results[2].model_T_W_C.translation()));
  const cv::Vec3f c = r.points_C.at<cv::Vec3f>(kSize / 2, kSize / 2);
  const cv::Vec3f w = r.points_W.at<cv::Vec3f>(kSize / 2, kSize / 2);
  ASSERT_TRUE(std::isfinite(c[2]));
  const Eigen::Vector3d expected = r.pose.T_W_C * Eigen::Vector3d(c[0], c[1], c[2]);
  EXPECT_LT((expected - Eigen::Vector3d(w[0], w[1], w[2])).norm(), 1e-5);
  FrameResult m = results[1];  // frame 1, the model's pose
  Reconstruction::rescale(m, 2.0);
  EXPECT_TRUE(m.pose.T_W_C.translation().isApprox(2.0 * results[1].pose.T_W_C.translation()));

  // Kept through a session: the restored stream rescales the same way.
  Reconstruction copy(std::make_unique<FakeModel>(&g.pts_W0), test::gt_reconstruction_config());
  rec.flush();
  copy.restore(rec.state());
  for (Reconstruction* each : {&rec, &copy}) {
    each->set_scale(2.0);
    const auto after = each->trajectory();
    ASSERT_EQ(after.size(), 4u);
    EXPECT_TRUE(after[0].second.isApprox(before[0].second, 1e-12));  // given
    EXPECT_TRUE(after[1].second.translation().isApprox(2.0 * before[1].second.translation()));
    EXPECT_TRUE(after[2].second.isApprox(before[2].second, 1e-12));  // given
  }
}

TEST(Reconstruction, EstimatesIntrinsicsWithoutCalibration) {
  const GtSequence g = make_sequence(3);
  Reconstruction rec(std::make_unique<FakeModel>(&g.pts_W0), test::gt_reconstruction_config());
  rec.push(g.bgr[0], "bgr8", 0.0);
  auto r = rec.push(g.bgr[1], "bgr8", 0.1);
  ASSERT_TRUE(r.has_value());
  EXPECT_EQ(r->intrinsics_source, IntrinsicsSource::kEstimatedWeiszfeld);
  EXPECT_NEAR(r->intrinsics.fx, g.seq.config.intrinsics.fx, 0.02 * g.seq.config.intrinsics.fx);
}

TEST(Reconstruction, ResetRestartsAndSizeChangeThrows) {
  const GtSequence g = make_sequence(3);
  Reconstruction rec(std::make_unique<FakeModel>(&g.pts_W0), test::gt_reconstruction_config());
  rec.set_calibration(g.seq.config.intrinsics);
  rec.push(g.bgr[0], "bgr8", 0.0);
  rec.push(g.bgr[1], "bgr8", 0.1);
  EXPECT_FALSE(rec.map().empty());
  cv::Mat bigger;
  cv::resize(g.bgr[2], bigger, cv::Size(2 * kSize, 2 * kSize));
  EXPECT_THROW(rec.push(bigger, "bgr8", 0.2), std::invalid_argument);
  EXPECT_THROW(rec.push(g.bgr[2], "yuv422", 0.2), std::invalid_argument);
  EXPECT_EQ(rec.frames_pushed(), 2);
  rec.reset();
  EXPECT_TRUE(rec.map().empty());
  EXPECT_TRUE(rec.trajectory().empty());
  EXPECT_EQ(rec.frames_pushed(), 0);
  EXPECT_FALSE(rec.push(g.bgr[0], "bgr8", 1.0).has_value());
  auto r = rec.push(g.bgr[1], "bgr8", 1.1);
  ASSERT_TRUE(r.has_value());
  EXPECT_EQ(r->frame_index, 0);
  EXPECT_DOUBLE_EQ(r->stamp, 1.0);
}

// A tiny Spann3R (random weights).
ModelConfig tiny_spann3r() {
  return parse_model_config(std::string(
      R"({"model": "Spann3R", "dust3r": {"enc_embed_dim": 32, "enc_depth": 2, "enc_num_heads": 2,
      "dec_embed_dim": 16, "dec_depth": 2, "dec_num_heads": 2, "depth_mode": ["exp", "-inf", "inf"],
      "dpt_head": {"feature_dim": 12, "last_dim": 8, "layer_dims": [8, 12, 16, 16]}},
      "spann3r": {"value_encoder": {"depth": 1, "embed_dim": 32, "num_heads": 2, "out_dim": 32}},
      "spatial_memory": {"long_mem_size": 200, "top_k": 200, "work_mem_size": 3}})"));
}

TEST(Reconstruction, RandomSpann3rRunsEndToEnd) {
  const GtSequence g = make_sequence(4);
  ReconstructionConfig cfg = test::gt_reconstruction_config();
  cfg.conf_threshold = 1.0f;  // random confidences: let every pixel through
  Reconstruction rec(std::make_unique<Spann3rModel>(tiny_spann3r()), cfg);
  int64_t expected = 0;
  for (size_t k = 0; k < g.bgr.size(); ++k) {
    if (auto r = rec.push(g.bgr[k], "bgr8", k)) {
      EXPECT_EQ(r->frame_index, expected++);
      EXPECT_EQ(r->points_W.size(), cv::Size(kSize, kSize));
      EXPECT_GT(r->model.mem_short_tokens, 0);
      EXPECT_TRUE(r->pose.T_W_C.matrix().allFinite());
    }
  }
  auto last = rec.flush();
  ASSERT_TRUE(last.has_value());
  EXPECT_EQ(last->frame_index, expected);
  EXPECT_TRUE(last->pose.T_W_C.matrix().allFinite());
}

// A model runs at the size its checkpoint was trained at unless the
// configuration names one; a file that records none runs at 224 x 224.
TEST(Reconstruction, InputSizeFollowsTheCheckpoint) {
  const GtSequence g = make_sequence(3);
  ReconstructionConfig follows = test::gt_reconstruction_config();
  follows.conf_threshold = 1.0f;
  follows.preprocess.width = follows.preprocess.height = 0;
  const auto first_size = [&](ReconstructionConfig cfg, ModelConfig model) {
    Reconstruction rec(std::make_unique<Spann3rModel>(model), cfg);
    std::optional<FrameResult> r;
    for (size_t k = 0; k < g.bgr.size() && !r; ++k) r = rec.push(g.bgr[k], "bgr8", k);
    if (!r) r = rec.flush();
    EXPECT_TRUE(r.has_value());
    const PreprocessConfig& used = rec.config().preprocess;
    EXPECT_EQ(r->points_W.size(), cv::Size(used.width, used.height));
    return r->points_W.size();
  };
  ModelConfig recorded = tiny_spann3r();
  recorded.input_width = 48;
  recorded.input_height = 32;
  EXPECT_EQ(first_size(follows, recorded), cv::Size(48, 32));
  EXPECT_EQ(first_size(follows, tiny_spann3r()),
            cv::Size(kDefaultModelInputSide, kDefaultModelInputSide));
  ReconstructionConfig named = follows;
  named.preprocess.width = 64;
  named.preprocess.height = 48;
  EXPECT_EQ(first_size(named, recorded), cv::Size(64, 48));
}

TEST(Reconstruction, LoadStreamingModelErrors) {
  EXPECT_THROW(make_streaming_model("/nonexistent/model.safetensors"), CheckpointError);
}

}  // namespace
}  // namespace long3r
