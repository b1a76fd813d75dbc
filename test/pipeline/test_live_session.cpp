// LiveSession without ROS: tags back with their results, stream continuity
// (a pause goes on, a jump back in time starts a new stream after the old
// one's last result), tracking loss, the metric scale from odometry and from
// depth images, calibrations validated, frames the client cannot place, and
// what ended streams leave (occupancy, surface) kept in the map and sessions.
// A model that returns the generator's ground truth makes every figure exact.
#include <gtest/gtest.h>

#include <any>
#include <cmath>
#include <functional>
#include <set>
#include <string>
#include <vector>

#include "long3r/pipeline/live_session.hpp"
#include "support/cv_test_support.hpp"
#include "support/live_session_support.hpp"
#include "support/test_support.hpp"

namespace long3r {
namespace {

using test::FakeModel;
using test::GtSequence;
using test::kGtSize;
using test::make_sequence;
using test::Recorder;
using test::Session;

TEST(LiveSession, TagsComeBackWithTheirResultsAcrossAPauseAndOddFrames) {
  Session s(7);
  for (int k = 0; k < 3; ++k) s.push(k, 10.0 + 0.1 * k);
  s.push(2, 10.2);  // a duplicate: dropped, named
  const LiveEvent* dup = s.client.event("duplicate or out of order");
  ASSERT_NE(dup, nullptr);
  EXPECT_TRUE(dup->frame_dropped);
  EXPECT_EQ(dup->level, LiveEvent::Level::kWarning);
  s.push(3, 0.0);  // no stamp: dropped
  EXPECT_NE(s.client.event("has no time stamp"), nullptr);
  s.session->flush();  // a pause: frame 2 now
  EXPECT_EQ(s.tags(), (std::vector<int>{0, 1, 2}));
  for (int k = 3; k < 7; ++k) s.push(k, 3600.0 + 0.1 * k);  // an hour later: the same stream
  s.session->flush();
  ASSERT_EQ(s.tags(), (std::vector<int>{0, 1, 2, 3, 4, 5, 6}));
  for (std::size_t k = 0; k < s.client.results.size(); ++k) {
    const FrameResult& r = s.client.results[k].frame;
    EXPECT_EQ(r.frame_index, static_cast<std::int64_t>(k));
    ASSERT_TRUE(r.pose.ok()) << k;
    EXPECT_LT((r.pose.T_W_C.translation() - s.g.T_0_k[k].translation()).norm(), 1e-3) << k;
    EXPECT_EQ(s.client.results[k].image_size, cv::Size(kGtSize, kGtSize));
  }
  const LiveStatus st = s.session->status();
  EXPECT_EQ(st.streams, 1u);
  EXPECT_EQ(st.stream_frames, 7);
  EXPECT_EQ(st.tracking, "ok");
  EXPECT_EQ(st.mem_short_tokens, 7);
  EXPECT_NE(s.client.event("intrinsics in use from calibration: fx"), nullptr);
  EXPECT_EQ(s.session->reconstruction().trajectory().size(), 7u);
}

TEST(LiveSession, TimeJumpingBackStartsANewStreamAfterTheOldOnesLastResult) {
  Session s(6);
  for (int k = 0; k < 4; ++k) s.push(k, 10.0 + 0.1 * k);
  s.push(4, 2.0);  // a looped bag
  s.push(5, 2.1);
  s.session->flush();
  ASSERT_EQ(s.client.log.size(), 7u);
  EXPECT_EQ(s.client.log[3], "result 3");  // the old stream's last frame comes first
  EXPECT_EQ(s.client.log[4].rfind("new stream: frame at t=2.000: time jumped back", 0), 0u)
      << s.client.log[4];
  EXPECT_EQ(s.client.log[5], "result 4");
  EXPECT_EQ(s.client.results.back().frame.frame_index, 1);  // of the new stream
  const LiveEvent* w = s.client.event("starting a new stream (memory, map and path start over)");
  ASSERT_NE(w, nullptr);
  EXPECT_FALSE(w->throttle);
  EXPECT_EQ(s.session->status().streams, 2u);
  EXPECT_EQ(s.session->reconstruction().trajectory().size(), 2u);
}

TEST(LiveSession, LostTrackingStartsANewStreamAfterLostResetFrames) {
  LiveSessionConfig config;
  config.lost_reset_frames = 2;
  Session s(8, config);
  const cv::Mat nothing(kGtSize, kGtSize, CV_32FC3, cv::Scalar::all(NAN));
  s.g.pts_W0[3] = s.g.pts_W0[4] = nothing;  // the model sees nothing it can pose
  for (int k = 0; k < 5; ++k) s.push(k, 1.0 + 0.1 * k);
  // Frame 4 (the second unposed one) comes back with frame 5: the stream restarts.
  s.push(5, 1.5);
  const LiveEvent* lost = s.client.event("pose estimation failed");
  ASSERT_NE(lost, nullptr);
  EXPECT_NE(lost->message.find("tracking lost for 1 frame(s)"), std::string::npos);
  EXPECT_EQ(s.client.log.back(), "result 4");
  EXPECT_EQ(s.client.log[s.client.log.size() - 2],
            "new stream: tracking lost for 2 consecutive frames (lost_reset_frames)");
  const LiveStatus st = s.session->status();
  EXPECT_EQ(st.lost_frames, 0);
  EXPECT_EQ(st.streams, 2u);
  // Frame 5 went with the old stream, counted as dropped; the new one starts
  // with frame 6.
  const LiveEvent* dropped = s.client.event("dropped with the ended stream");
  ASSERT_NE(dropped, nullptr);
  EXPECT_TRUE(dropped->frame_dropped);
  s.push(6, 1.6);
  s.push(7, 1.7);
  s.session->flush();
  EXPECT_EQ(s.tags(), (std::vector<int>{0, 1, 2, 3, 4, 6, 7}));
  EXPECT_EQ(s.client.results[5].frame.frame_index, 0);
  EXPECT_TRUE(s.client.results[5].frame.pose.ok());
}

TEST(LiveSession, LostTrackingRelocalisesInTheSameStreamAndMap) {
  LiveSessionConfig config;
  config.relocalise_for_s = 10.0;
  Session s(8, config);
  const cv::Mat nothing(kGtSize, kGtSize, CV_32FC3, cv::Scalar::all(NAN));
  s.g.pts_W0[3] = s.g.pts_W0[4] = nothing;
  for (int k = 0; k < 8; ++k) s.push(k, 1.0 + 0.1 * k);
  s.session->flush();
  // Frames 5-7 are posed again in the first frame's world: one stream, one map.
  const LiveStatus st = s.session->status();
  EXPECT_EQ(st.streams, 1u);
  EXPECT_EQ(st.tracking, "ok");
  EXPECT_EQ(st.relocalisations, 1u);
  EXPECT_EQ(st.relocalisation_attempts, 2u);  // frames 4 and 5 came while lost
  const LiveEvent* back = s.client.event("relocalised at frame 5 after 2 unposed frame(s) (0.2 s)");
  ASSERT_NE(back, nullptr);
  EXPECT_EQ(back->level, LiveEvent::Level::kInfo);
  for (int k : {5, 6, 7}) {
    const FrameResult& f = s.client.results[static_cast<std::size_t>(k)].frame;
    EXPECT_EQ(f.frame_index, k);
    EXPECT_TRUE(f.pose.ok());
    EXPECT_TRUE(f.pose.T_W_C.isApprox(s.g.T_0_k[static_cast<std::size_t>(k)], 1e-3)) << k;
  }
  EXPECT_TRUE(s.client.ended_map_points.empty());
}

TEST(LiveSession, RelocalisationIsBoundedInTimeAndTheEndingStreamIsHandedOver) {
  LiveSessionConfig config;
  config.relocalise_for_s = 0.15;
  Session s(8, config);
  const cv::Mat nothing(kGtSize, kGtSize, CV_32FC3, cv::Scalar::all(NAN));
  s.g.pts_W0[3] = s.g.pts_W0[4] = s.g.pts_W0[5] = nothing;
  for (int k = 0; k < 7; ++k) s.push(k, 1.0 + 0.1 * k);
  // Frame 5 is 0.2 s after the loss began at frame 3: a new stream, and the
  // ending one (its map of frames 0-2) went to the client first.
  EXPECT_NE(s.client.event("tracking lost for 0.2 s without relocalising (relocalise_for_s 0.15)"),
            nullptr);
  EXPECT_EQ(s.session->status().streams, 2u);
  ASSERT_EQ(s.client.ended_map_points.size(), 1u);
  EXPECT_GT(s.client.ended_map_points[0], 0u);
  EXPECT_EQ(s.session->status().relocalisations, 0u);
  EXPECT_TRUE(s.session->ended_maps().empty());  // the client ties W to no map frame
  LiveSessionConfig bad;
  bad.relocalise_for_s = -1.0;
  EXPECT_THROW(bad.validate({"live session config", ""}), ConfigError);
}

TEST(LiveSession, OdometryScaleConvergesAndEveryResultLeavesInIt) {
  LiveSessionConfig config;
  config.scale.source = ScaleSource::kOdometry;
  config.scale.min_baseline_m = 0.01;
  config.scale.min_samples = 3;
  Session s(10, config);
  s.client.odometry_scale = 2.5;
  for (int k = 0; k < 10; ++k) s.push(k, 1.0 + 0.1 * k);
  s.session->flush();
  ASSERT_EQ(s.client.results.size(), 10u);
  // The estimate: ratios of odometry to PnP displacements on exact points.
  const double scale = s.session->status().scale;
  EXPECT_NEAR(scale, 2.5, 1e-6);
  int changed = 0;
  bool metric = false;
  for (std::size_t k = 0; k < 10; ++k) {
    const LiveResult& r = s.client.results[k];
    changed += r.scale_changed;
    metric = metric || r.scale_changed;
    const double expected = metric ? scale : 1.0;
    EXPECT_EQ(r.frame.scale, expected) << k;
    EXPECT_LT((r.frame.pose.T_W_C.translation() - expected * s.g.T_0_k[k].translation()).norm(),
              2e-3)
        << k;
  }
  EXPECT_EQ(changed, 1);
  // The frames before the scale was known are rescaled in the path.
  const auto trajectory = s.session->reconstruction().trajectory();
  ASSERT_EQ(trajectory.size(), 10u);
  for (std::size_t k = 0; k < 10; ++k) {
    EXPECT_LT((trajectory[k].second.translation() - 2.5 * s.g.T_0_k[k].translation()).norm(), 5e-3)
        << k;
  }
  const LiveStatus st = s.session->status();
  EXPECT_TRUE(st.scale_metric);
  EXPECT_NE(s.client.event("metric scale 2.5000"), nullptr);
  const LiveEvent* missing = s.client.event("odometry: none at frame 5");
  ASSERT_NE(missing, nullptr);
  EXPECT_EQ(missing->kind, "tf odometry");
  EXPECT_FALSE(missing->frame_dropped);  // the frame is there; only its sample is not
}

TEST(LiveSession, DepthScaleFromMillimetreAndMetreImages) {
  for (const int type : {CV_32FC1, CV_16UC1}) {
    SCOPED_TRACE(type);
    LiveSessionConfig config;
    config.scale.source = ScaleSource::kDepth;
    config.scale.min_samples = 3;
    Session s(6, config);
    s.client.depth_scale = 0.8;
    s.client.depth_type = type;
    for (int k = 0; k < 6; ++k) s.push(k, 1.0 + 0.1 * k);
    s.session->flush();
    const LiveStatus st = s.session->status();
    ASSERT_TRUE(st.scale_metric);
    EXPECT_NEAR(st.scale, 0.8, type == CV_16UC1 ? 1e-3 : 1e-5);
    EXPECT_EQ(s.client.results.size(), 6u);
  }
  LiveSessionConfig config;
  config.scale.source = ScaleSource::kDepth;
  Session s(3, config);
  s.client.depth_scale = 1.0;
  s.client.depth_type = CV_8UC1;
  for (int k = 0; k < 3; ++k) s.push(k, 1.0 + 0.1 * k);
  const LiveEvent* e = s.client.event("depth image not used: a depth image must be 16UC1");
  ASSERT_NE(e, nullptr);
  EXPECT_EQ(e->kind, "depth encoding");
  EXPECT_FALSE(s.session->status().scale_metric);
}

TEST(LiveSession, CalibrationsAreValidatedAndARefusedOneIsNamed) {
  LiveSessionConfig config;
  config.calibration_source = "calibration.txt";
  Session s(5, config, /*calibrated=*/false);
  CameraModel bad = camera_model(s.g.seq.config.intrinsics);
  bad.K[0] = NAN;
  s.push(0, 1.0, -1.0, bad);
  const LiveEvent* refused = s.client.event("calibration.txt not used: K[0] (fx) is nan");
  ASSERT_NE(refused, nullptr);
  EXPECT_NE(refused->message.find("the focal length is estimated from the images"),
            std::string::npos);
  EXPECT_TRUE(s.session->status().calibration_refused);
  s.push(1, 1.1);  // no calibration: frame 0 comes back with an estimated focal length
  ASSERT_EQ(s.client.results.size(), 1u);
  EXPECT_EQ(s.client.results[0].frame.intrinsics_source, IntrinsicsSource::kEstimatedWeiszfeld);
  s.push(2, 1.2, -1.0, camera_model(s.g.seq.config.intrinsics));
  EXPECT_NE(s.client.event("camera calibration from calibration.txt: fx"), nullptr);
  EXPECT_FALSE(s.session->status().calibration_refused);
  EXPECT_EQ(s.session->status().calibration.rfind("fx ", 0), 0u);
  // A calibration of another image size is refused, the valid one kept.
  CameraModel other = camera_model(s.g.seq.config.intrinsics);
  other.width *= 2;
  s.push(3, 1.3, -1.0, other);
  EXPECT_NE(s.client.event("keeping the last valid calibration"), nullptr);
  s.push(4, 1.4);
  s.session->flush();
  ASSERT_EQ(s.client.results.size(), 5u);
  for (std::size_t k = 2; k < 5; ++k) {
    const FrameResult& r = s.client.results[k].frame;
    EXPECT_EQ(r.intrinsics_source, IntrinsicsSource::kCalibration) << k;
    EXPECT_NEAR(r.intrinsics.fx, s.g.seq.config.intrinsics.fx, 1e-9) << k;
  }
}

TEST(LiveSession, AFrameTheClientCannotPlaceIsSkippedAndTheStreamGoesOn) {
  Session s(5);
  s.client.placer = [&](int k) -> std::optional<Eigen::Isometry3d> {
    if (k == 2) throw LiveSessionClient::Unavailable("tf odometry", "frame 2: no odometry yet");
    if (k == 4) return s.g.T_0_k[4];  // a given pose places the frame
    return std::nullopt;
  };
  for (int k = 0; k < 5; ++k) s.push(k, 1.0 + 0.1 * k);
  s.session->flush();
  const LiveEvent* skipped = s.client.event("frame 2: no odometry yet");
  ASSERT_NE(skipped, nullptr);
  EXPECT_TRUE(skipped->frame_dropped);
  EXPECT_EQ(skipped->kind, "tf odometry");
  EXPECT_EQ(s.tags(), (std::vector<int>{0, 1, 3, 4}));
  // A given pose is in metres: mapping waits for a metric scale from then on.
  EXPECT_TRUE(s.client.results[1].frame.added_to_map);
  EXPECT_FALSE(s.client.results[3].frame.added_to_map);
  EXPECT_TRUE(s.client.results[3].frame.pose.T_W_C.isApprox(s.g.T_0_k[4]));
  EXPECT_TRUE(s.session->status().mapping_held);
  const LiveEvent* held = s.client.event("not mapped: the map waits for a metric scale (none;");
  ASSERT_NE(held, nullptr);
  EXPECT_FALSE(held->frame_dropped);
}

TEST(LiveSession, ResetStartsOverAndAConfigIsChecked) {
  Session s(4);
  for (int k = 0; k < 3; ++k) s.push(k, 1.0 + 0.1 * k);
  s.session->reset("reset requested");
  EXPECT_EQ(s.client.log.back(), "new stream: reset requested");
  // Frame 2 awaited its result: dropped, and said so.
  std::size_t dropped = 0;
  for (const LiveEvent& e : s.client.events) dropped += e.frame_dropped ? 1 : 0;
  EXPECT_EQ(dropped, 1u);
  EXPECT_EQ(s.session->reconstruction().map().size(), 0u);
  s.push(3, 1.05);  // even an earlier stamp: the monitor starts over too
  s.push(0, 1.06);
  EXPECT_EQ(s.client.results.back().frame.frame_index, 0);
  EXPECT_EQ(std::any_cast<int>(s.client.results.back().tag), 3);

  LiveSessionConfig bad;
  bad.lost_reset_frames = -1;
  Recorder client;
  const GtSequence g = make_sequence(1);
  EXPECT_THROW(LiveSession(std::make_unique<FakeModel>(&g.pts_W0), test::gt_reconstruction_config(),
                           bad, client),
               ConfigError);
  bad = LiveSessionConfig();
  bad.scale.min_samples = 0;
  try {
    LiveSession(std::make_unique<FakeModel>(&g.pts_W0), test::gt_reconstruction_config(), bad,
                client);
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("scale.min_samples"), std::string::npos) << e.what();
  }
  bad = LiveSessionConfig();
  bad.stream.size_change_frames = 0;
  try {
    LiveSession(std::make_unique<FakeModel>(&g.pts_W0), test::gt_reconstruction_config(), bad,
                client);
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("stream.size_change_frames"), std::string::npos)
        << e.what();
  }
}

// The occupancy of the mapped views, seen from a z-up map frame (the
// generated room's, where its floor is z = 0): the grid of the band above the
// fitted floor; a stream that ends leaves its occupancy where it ended.
TEST(LiveSession, OccupancyGridOfTheStreamsInTheMapFrame) {
  Session s(8);
  const Eigen::Isometry3d T_map_W = s.g.seq.poses[0];  // the room's frame
  s.client.map_frame = T_map_W;
  for (int k = 0; k < 6; ++k) s.push(k, 10.0 + 0.1 * k);
  s.session->flush();
  GridProjectionConfig config;
  const LiveSession::GridProjection p = s.session->occupancy_grid(T_map_W, config);
  EXPECT_TRUE(p.floor_fitted);
  EXPECT_NEAR(p.floor_z_m, 0.0, 0.05);
  ASSERT_GT(p.grid.occupied, 0u);
  for (int k = 0; k < 6; ++k) {
    const Eigen::Vector3d c = s.g.seq.poses[static_cast<std::size_t>(k)].translation();
    EXPECT_NE(p.grid.at(c.x(), c.y()), OccupancyGrid::kOccupied) << k;
  }
  // Every occupied cell holds a true point of the band.
  std::set<std::pair<long, long>> truth;
  for (const cv::Mat& pts : s.g.pts_W0) {
    for (auto it = pts.begin<cv::Vec3f>(); it != pts.end<cv::Vec3f>(); ++it) {
      if (!std::isfinite((*it)[0])) continue;
      const Eigen::Vector3d q = T_map_W * Eigen::Vector3d((*it)[0], (*it)[1], (*it)[2]);
      if (q.z() < p.floor_z_m + 0.0 || q.z() > p.floor_z_m + 1.9) continue;
      truth.insert({std::lround(std::floor(q.x() / 0.05)), std::lround(std::floor(q.y() / 0.05))});
    }
  }
  std::size_t off = 0;
  const OccupancyGrid& g = p.grid;
  for (int y = 0; y < g.height; ++y) {
    for (int x = 0; x < g.width; ++x) {
      if (g.cells[static_cast<std::size_t>(y) * g.width + x] != OccupancyGrid::kOccupied) continue;
      const long cx = std::lround(g.origin_x_m / 0.05) + x,
                 cy = std::lround(g.origin_y_m / 0.05) + y;
      bool near = false;
      for (long dy = -1; dy <= 1 && !near; ++dy) {
        for (long dx = -1; dx <= 1 && !near; ++dx) near = truth.count({cx + dx, cy + dy}) > 0;
      }
      off += near ? 0 : 1;
    }
  }
  EXPECT_EQ(off, 0u);
  // base: the band from z = 0 of the map frame.
  config.floor = GridFloor::kBase;
  EXPECT_FALSE(s.session->occupancy_grid(T_map_W, config).floor_fitted);
  config.floor = GridFloor::kFit;

  // A jump back in time ends the stream: its occupancy stays in the grid.
  const std::uint64_t revision = s.session->occupancy_revision();
  // (The floor at z = 0 for both, the new stream's fit being another's.)
  config.floor = GridFloor::kBase;
  const std::size_t before = s.session->occupancy_grid(T_map_W, config).grid.occupied;
  s.push(6, 2.0);
  s.push(7, 2.1);
  EXPECT_NE(s.session->occupancy_revision(), revision);
  EXPECT_EQ(s.session->status().streams, 2u);
  const LiveSession::GridProjection after =
      s.session->occupancy_grid(Eigen::Isometry3d::Identity(), config);
  EXPECT_GE(after.grid.occupied, before);
  // A reset clears it all.
  s.session->reset("test");
  EXPECT_EQ(s.session->occupancy_grid(T_map_W, config).grid.occupied, 0u);
}

// An ended stream's surface stays where it ended, beside the current one's;
// sessions keep the ended streams' surfaces and occupancy, and a load puts
// the file's in place of the running ones'.
TEST(LiveSession, EndedStreamsKeepTheirSurfaceAndOccupancyInSessions) {
  if (!TsdfVolume::available()) GTEST_SKIP() << "built without Open3D";
  ReconstructionConfig recon = test::gt_reconstruction_config();
  recon.surface.enabled = true;
  recon.surface.tsdf.voxel_size_m = 0.05;
  recon.surface.tsdf.truncation_m = 0.2;
  recon.surface.tsdf.min_weight = 1.0f;
  Session s(8, {}, true, recon);
  const Eigen::Isometry3d T_map_W = s.g.seq.poses[0];
  s.client.map_frame = T_map_W;
  for (int k = 0; k < 4; ++k) s.push(k, 10.0 + 0.1 * k);
  s.session->flush();
  const std::size_t first = s.session->surface_points(T_map_W).points.size();
  const std::size_t first_triangles = s.session->surface_mesh(T_map_W).triangles.size();
  ASSERT_GT(first, 0u);
  ASSERT_GT(first_triangles, 0u);
  const std::uint64_t revision = s.session->surface_revision();
  // A jump back in time ends the stream: its surface stays, the new one's beside it.
  s.push(4, 2.0);
  s.push(5, 2.1);
  s.session->flush();
  ASSERT_EQ(s.session->status().streams, 2u);
  EXPECT_NE(s.session->surface_revision(), revision);
  EXPECT_EQ(s.session->reconstruction().surface().frames_kept(), 2u);
  const ColoredPoints both = s.session->surface_points(T_map_W);
  EXPECT_GT(both.points.size(), first);
  EXPECT_GT(s.session->surface_mesh(T_map_W).triangles.size(), first_triangles);
  GridProjectionConfig grid;
  grid.floor = GridFloor::kBase;
  const std::size_t occupied = s.session->occupancy_grid(T_map_W, grid).grid.occupied;
  ASSERT_GT(occupied, 0u);

  // Saved, reset, loaded: the ended stream's parts come back with the file.
  const std::string path = test::scratch_dir("live_session/ended") + "/ended.l3s";
  s.session->save(path);
  s.session->reset("test");
  EXPECT_EQ(s.session->surface_points(T_map_W).points.size(), 0u);
  s.session->load(path);
  EXPECT_EQ(s.session->surface_points(T_map_W).points.size(), both.points.size());
  EXPECT_EQ(s.session->occupancy_grid(T_map_W, grid).grid.occupied, occupied);
  // A file without ended streams replaces them: nothing of the running
  // session's ended streams is left beside the file's map.
  Session fresh(8, {}, true, recon);
  fresh.client.map_frame = T_map_W;
  for (int k = 0; k < 3; ++k) fresh.push(k, 10.0 + 0.1 * k);
  const std::string single = test::scratch_dir("live_session/ended") + "/single.l3s";
  fresh.session->save(single);
  const std::size_t single_points = fresh.session->surface_points(T_map_W).points.size();
  s.session->load(single);
  EXPECT_EQ(s.session->surface_points(T_map_W).points.size(), single_points);
}

}  // namespace
}  // namespace long3r
