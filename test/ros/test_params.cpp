// Parameter reading of the nodelet: defaults, valid values, and every kind of
// bad value must be rejected with a message naming the parameter.
#include <gtest/gtest.h>
#include <ros/ros.h>

#include "long3r/config/config_json.hpp"
#include "long3r_ros/params.hpp"

using long3r_ros::ParamError;
using long3r_ros::readParams;

namespace {

// Each test gets a fresh private namespace so parameters don't leak.
class ParamsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    static int counter = 0;
    pnh_ = ros::NodeHandle("~case" + std::to_string(counter++));
  }
  void expectError(const std::string& name) {
    try {
      readParams(pnh_);
      FAIL() << "no error for bad " << name;
    } catch (const ParamError& e) {
      EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
    }
  }
  ros::NodeHandle pnh_;
};

}  // namespace

TEST_F(ParamsTest, DefaultsWhenUnset) {
  auto c = readParams(pnh_).node;
  EXPECT_EQ(readParams(pnh_).frames.map_frame, "map_model_units");  // scale_source none
  EXPECT_EQ(c.queue_size, 1);
  EXPECT_TRUE(c.publish_tf);
  EXPECT_EQ(readParams(pnh_).threads.torch_threads, 0);
  EXPECT_EQ(readParams(pnh_).threads.openblas_threads, long3r::ThreadConfig::kOpenblasThreadsAuto);
}

TEST_F(ParamsTest, SessionAndGridParameters) {
  EXPECT_EQ(readParams(pnh_).node.session_path, "");
  EXPECT_FALSE(readParams(pnh_).frames.session_odometry_continues);
  EXPECT_EQ(readParams(pnh_).reconstruction.occupancy.resolution_m, 0.05);
  // Without base_frame there is no ~grid, and no occupancy is kept for it.
  EXPECT_FALSE(readParams(pnh_).reconstruction.occupancy.enabled);
  pnh_.setParam("base_frame", "base_link");
  EXPECT_TRUE(readParams(pnh_).reconstruction.occupancy.enabled);
  EXPECT_EQ(readParams(pnh_).grid.floor, long3r::GridFloor::kFit);
  pnh_.setParam("session_path", "/maps/site.l3s");
  pnh_.setParam("session_odometry_continues", true);
  pnh_.setParam("grid_resolution_m", 0.1);
  pnh_.setParam("grid_min_height_m", 0.2);
  pnh_.setParam("grid_max_height_m", 2);  // an int where a double is expected is fine
  pnh_.setParam("grid_max_range_m", 3.0);
  pnh_.setParam("grid_prob_hit", 0.8);
  pnh_.setParam("grid_pixel_step", 2);
  pnh_.setParam("grid_floor", "base");
  EXPECT_EQ(readParams(pnh_).node.session_path, "/maps/site.l3s");
  EXPECT_TRUE(readParams(pnh_).frames.session_odometry_continues);
  const long3r_ros::NodeParams p = readParams(pnh_);
  EXPECT_EQ(p.reconstruction.occupancy.resolution_m, 0.1);
  EXPECT_EQ(p.reconstruction.occupancy.max_range_m, 3.0);
  EXPECT_EQ(p.reconstruction.occupancy.prob_hit, 0.8);
  EXPECT_EQ(p.reconstruction.occupancy.pixel_step, 2);
  EXPECT_EQ(p.grid.min_height_m, 0.2);
  EXPECT_EQ(p.grid.max_height_m, 2.0);
  EXPECT_EQ(p.grid.floor, long3r::GridFloor::kBase);
  pnh_.setParam("grid_enabled", false);
  EXPECT_FALSE(readParams(pnh_).reconstruction.occupancy.enabled);
  pnh_.setParam("grid_max_height_m", 0.1);  // below the band's bottom
  expectError("grid_max_height_m");
  pnh_.setParam("grid_max_height_m", 2.0);
  pnh_.setParam("grid_prob_miss", 0.6);
  expectError("grid_prob_miss");
  pnh_.setParam("grid_prob_miss", 0.4);
  pnh_.setParam("grid_floor", "ceiling");
  expectError("grid_floor");
  pnh_.setParam("grid_floor", "fit");
  pnh_.setParam("grid_resolution_m", -1.0);
  expectError("grid_resolution_m");
  pnh_.setParam("grid_resolution_m", "fine");
  expectError("grid_resolution_m");
}

TEST_F(ParamsTest, ReadsValidValues) {
  pnh_.setParam("map_frame", "world");
  pnh_.setParam("queue_size", 5);
  pnh_.setParam("flush_after_s", 2);  // an int where a double is expected is fine
  pnh_.setParam("publish_tf", false);
  pnh_.setParam("torch_threads", 2);
  auto c = readParams(pnh_).node;
  EXPECT_EQ(readParams(pnh_).frames.map_frame, "world");
  EXPECT_EQ(c.queue_size, 5);
  EXPECT_DOUBLE_EQ(c.flush_after_s, 2.0);
  EXPECT_FALSE(c.publish_tf);
  EXPECT_EQ(readParams(pnh_).threads.torch_threads, 2);
}

TEST_F(ParamsTest, InputAndContinuityDefaultsAndValues) {
  const auto c = readParams(pnh_).node;
  EXPECT_EQ(c.max_image_pixels, 4096 * 4096);
  const auto s = readParams(pnh_).session;
  EXPECT_FALSE(s.image_is_rectified);
  EXPECT_EQ(s.lost_reset_frames, 0);
  const auto m = readParams(pnh_).session.stream;
  EXPECT_DOUBLE_EQ(m.max_backward_jump_s, 1.0);
  EXPECT_DOUBLE_EQ(m.max_stamp_jump_s, 5.0);
  EXPECT_EQ(m.size_change_frames, 3);
  pnh_.setParam("image_is_rectified", true);
  pnh_.setParam("lost_reset_frames", 30);
  pnh_.setParam("max_backward_jump_s", 0.2);
  pnh_.setParam("size_change_frames", 1);
  EXPECT_TRUE(readParams(pnh_).session.image_is_rectified);
  EXPECT_EQ(readParams(pnh_).session.lost_reset_frames, 30);
  EXPECT_EQ(readParams(pnh_).session.stream.size_change_frames, 1);
  EXPECT_DOUBLE_EQ(readParams(pnh_).session.stream.max_backward_jump_s, 0.2);
  EXPECT_EQ(readParams(pnh_).session.stream.size_change_frames, 1);
  EXPECT_NE(long3r_ros::describe(readParams(pnh_)).find("size_change_frames: 1"),
            std::string::npos);
}

TEST_F(ParamsTest, RejectsBadContinuitySettings) {
  pnh_.setParam("size_change_frames", 0);
  expectError("size_change_frames");
  pnh_.setParam("size_change_frames", 3);
  pnh_.setParam("max_stamp_jump_s", 0.0);
  expectError("max_stamp_jump_s");
  pnh_.setParam("max_stamp_jump_s", 5.0);
  pnh_.setParam("lost_reset_frames", -1);
  expectError("lost_reset_frames");
  pnh_.setParam("lost_reset_frames", 0);
  pnh_.setParam("max_image_pixels", 10);
  expectError("max_image_pixels");
}

TEST_F(ParamsTest, OpenblasThreadsAutoEnvironmentOrCount) {
  for (int n : {-1, 0, 3}) {
    pnh_.setParam("openblas_threads", n);
    EXPECT_EQ(readParams(pnh_).threads.openblas_threads, n);
  }
  pnh_.setParam("openblas_threads", -2);
  expectError("openblas_threads");
}

TEST_F(ParamsTest, RejectsZeroQueue) {
  pnh_.setParam("queue_size", 0);
  expectError("queue_size");
}

TEST_F(ParamsTest, RejectsQueueOfWrongType) {
  pnh_.setParam("queue_size", "three");
  expectError("queue_size");
}

TEST_F(ParamsTest, RejectsNegativePeriod) {
  pnh_.setParam("map_publish_period_s", -1.0);
  expectError("map_publish_period_s");
}

TEST_F(ParamsTest, RejectsNonNumericFlush) {
  pnh_.setParam("flush_after_s", "soon");
  expectError("flush_after_s");
}

TEST_F(ParamsTest, MapFrameDefaultSaysItsUnits) {
  pnh_.setParam("map_frame", "");  // as default.yaml has it
  EXPECT_EQ(readParams(pnh_).frames.map_frame, "map_model_units");
  for (const char* source : {"depth", "fixed"}) {
    pnh_.setParam("scale_source", source);
    EXPECT_EQ(readParams(pnh_).frames.map_frame, "map") << source;
  }
  pnh_.setParam("scale_source", "none");
  pnh_.setParam("map_frame", "map");  // named by the user: kept whatever the units
  EXPECT_EQ(readParams(pnh_).frames.map_frame, "map");
}

TEST_F(ParamsTest, PoseSourceChoosesThePipelinesPoseMethod) {
  EXPECT_EQ(readParams(pnh_).reconstruction.pose_method, long3r::PoseMethod::kKeyframes);
  pnh_.setParam("pose_source", "model");
  EXPECT_EQ(readParams(pnh_).reconstruction.pose_method, long3r::PoseMethod::kModel);
  pnh_.setParam("pose_source", "keyframes");
  EXPECT_EQ(readParams(pnh_).reconstruction.pose_method, long3r::PoseMethod::kKeyframes);
  pnh_.setParam("tracker_solver", "essential");
  pnh_.setParam("tracker_fast_threshold", 0);
  expectError("tracker_fast_threshold");
  pnh_.setParam("tracker_fast_threshold", 12);
  EXPECT_EQ(readParams(pnh_).reconstruction.tracker.fast_threshold, 12);
  pnh_.setParam("tracker_pyramid_levels", 0);
  expectError("tracker_pyramid_levels");
  pnh_.setParam("tracker_pyramid_levels", 4);
  EXPECT_EQ(readParams(pnh_).reconstruction.tracker.pyramid_levels, 4);
  EXPECT_EQ(readParams(pnh_).reconstruction.tracker.solver, long3r::TrackingSolver::kEssential);
  EXPECT_EQ(readParams(pnh_).reconstruction.tracker.motion_prior,
            long3r::MotionPrior::kConstantVelocity);
  pnh_.setParam("tracker_motion_prior", "model");
  EXPECT_EQ(readParams(pnh_).reconstruction.tracker.motion_prior, long3r::MotionPrior::kModel);
  // tracker_when_lost's older name of "prior" still reads; it is not offered.
  pnh_.setParam("tracker_when_lost", "model_motion");
  EXPECT_EQ(readParams(pnh_).reconstruction.tracker.when_lost, long3r::WhenLost::kPrior);
  pnh_.setParam("tracker_when_lost", "stop");
  try {
    readParams(pnh_);
    FAIL() << "no error for tracker_when_lost stop";
  } catch (const ParamError& e) {
    EXPECT_NE(std::string(e.what()).find("\"relocalise\" or \"prior\","), std::string::npos)
        << e.what();
  }
}

TEST_F(ParamsTest, RejectsCameraFrameEqualToMap) {
  pnh_.setParam("camera_frame", "map_model_units");  // the default map_frame of scale_source none
  expectError("map_frame");
  pnh_.setParam("map_frame", "world");
  pnh_.setParam("camera_frame", "world");
  expectError("map_frame");
}

TEST_F(ParamsTest, WorldFrameIsTheOldNameOfMapFrame) {
  pnh_.setParam("world_frame", "world");
  EXPECT_EQ(readParams(pnh_).frames.map_frame, "world");
  pnh_.setParam("map_frame", "map");
  expectError("world_frame");  // both, disagreeing
}

TEST_F(ParamsTest, FramesAndScale) {
  pnh_.setParam("odom_frame", "odom");
  expectError("odom_frame");  // odometry without a base
  pnh_.setParam("base_frame", "base_link");
  const long3r_ros::FramesConfig f = readParams(pnh_).frames;
  EXPECT_EQ(f.odom_frame, "odom");
  EXPECT_EQ(f.base_frame, "base_link");
  EXPECT_EQ(readParams(pnh_).node.pose_source, long3r_ros::PoseSource::kKeyframes);
  pnh_.setParam("pose_source", "odometry");
  EXPECT_EQ(readParams(pnh_).node.pose_source, long3r_ros::PoseSource::kOdometry);
  EXPECT_EQ(readParams(pnh_).session.scale.source, long3r::ScaleSource::kNone);
  pnh_.setParam("scale_source", "depth");
  pnh_.setParam("scale_min_samples", 8);
  const long3r::MetricScaleConfig s = readParams(pnh_).session.scale;
  EXPECT_EQ(s.source, long3r::ScaleSource::kDepth);
  EXPECT_EQ(s.min_samples, 8);
  pnh_.setParam("scale_source", "lidar");
  expectError("scale_source");
  pnh_.setParam("scale_source", "fixed");
  pnh_.setParam("scale_m_per_unit", -2.0);
  expectError("/scale_m_per_unit must be > 0");
  pnh_.setParam("scale_m_per_unit", 2.0);
  EXPECT_EQ(readParams(pnh_).session.scale.fixed_scale, 2.0);
  pnh_.setParam("pose_source", "gps");
  expectError("pose_source");
}

TEST_F(ParamsTest, ScaleIsTheOldNameOfScaleMPerUnit) {
  pnh_.setParam("scale", 2.5);
  EXPECT_EQ(readParams(pnh_).session.scale.fixed_scale, 2.5);
  pnh_.setParam("scale_m_per_unit", 2.5);  // both, agreeing
  EXPECT_EQ(readParams(pnh_).session.scale.fixed_scale, 2.5);
  pnh_.setParam("scale_m_per_unit", 3.0);
  expectError("scale is the old name of scale_m_per_unit");
  EXPECT_TRUE(long3r_ros::unknownParams(pnh_).empty());  // old names are known
}

TEST_F(ParamsTest, OdometrySourcesNeedTheRobotFrames) {
  pnh_.setParam("pose_source", "odometry");
  expectError("/pose_source odometry needs odom_frame and base_frame");
  pnh_.setParam("pose_source", "model");
  pnh_.setParam("scale_source", "odometry");
  pnh_.setParam("base_frame", "base_link");
  expectError("/scale_source odometry needs odom_frame and base_frame");
  pnh_.setParam("odom_frame", "odom");
  EXPECT_EQ(readParams(pnh_).session.scale.source, long3r::ScaleSource::kOdometry);
  pnh_.setParam("odom_frame", "");
  pnh_.setParam("scale_source", "none");
  pnh_.setParam("pose_source", "keyframes");
  pnh_.setParam("tracker_motion_prior", "odometry");
  expectError("/tracker_motion_prior odometry needs odom_frame and base_frame");
  pnh_.setParam("odom_frame", "odom");
  EXPECT_EQ(readParams(pnh_).reconstruction.tracker.motion_prior, long3r::MotionPrior::kOdometry);
}

// Every field of the components' lists is a parameter, under its prefix.
TEST_F(ParamsTest, EveryListedFieldIsAParameter) {
  pnh_.setParam("scale_max_samples", 40);
  pnh_.setParam("drop_zero_stamps", false);
  pnh_.setParam("pnp_ransac_confidence", 0.99);
  pnh_.setParam("pnp_refine", false);
  const long3r_ros::NodeParams p = readParams(pnh_);
  EXPECT_EQ(p.session.scale.max_samples, 40u);
  EXPECT_FALSE(p.session.stream.drop_zero_stamps);
  EXPECT_DOUBLE_EQ(p.reconstruction.pnp.ransac_confidence, 0.99);
  EXPECT_FALSE(p.reconstruction.pnp.refine);
  pnh_.setParam("scale_max_samples", 4);  // below scale_min_samples
  expectError("/scale_max_samples must be >= min_samples");
  pnh_.setParam("scale_max_samples", 40);
  pnh_.setParam("pnp_ransac_confidence", 1.0);
  expectError("/pnp_ransac_confidence must be in (0, 1)");
}

TEST_F(ParamsTest, UnknownParametersAreNamed) {
  pnh_.setParam("voxel_size", 0.05);  // voxel_size_m meant
  pnh_.setParam("queue_size", 2);
  pnh_.setParam("compressed/mode", "unchanged");  // a plugin's own, nested
  const std::vector<std::string> unknown = long3r_ros::unknownParams(pnh_);
  ASSERT_EQ(unknown.size(), 1u);
  EXPECT_EQ(unknown[0], pnh_.getNamespace() + "/voxel_size");
}

// config/default.yaml (loaded by params.test into ~defaults) names every
// parameter, nothing else, each at the struct's default.
TEST(DefaultsFile, MatchesTheStructs) {
  const ros::NodeHandle defaults("~defaults");
  const std::vector<std::string> names = long3r_ros::parameterNames();
  ASSERT_GT(names.size(), 50u);
  for (const std::string& name : names) {
    EXPECT_TRUE(defaults.hasParam(name)) << "config/default.yaml lacks " << name;
  }
  EXPECT_EQ(long3r_ros::unknownParams(defaults), std::vector<std::string>{});
  const long3r::config::Json read = long3r::config::to_json(readParams(defaults));
  long3r_ros::NodeParams structs;
  long3r_ros::resolveDefaults(structs);
  const long3r::config::Json expected = long3r::config::to_json(structs);
  EXPECT_EQ(read.dump(2), expected.dump(2));
}

TEST_F(ParamsTest, RejectsBoolAsString) {
  pnh_.setParam("publish_tf", "yes");
  expectError("publish_tf");
}

TEST_F(ParamsTest, RejectsNegativeThreads) {
  pnh_.setParam("torch_threads", -2);
  expectError("torch_threads");
}

TEST_F(ParamsTest, ReconstructionDefaultsAndValues) {
  auto d = readParams(pnh_).reconstruction;
  EXPECT_TRUE(d.preprocess.follows_checkpoint());  // 0 x 0: the checkpoint's size
  EXPECT_EQ(d.preprocess.width, 0);
  EXPECT_EQ(d.preprocess.height, 0);
  EXPECT_FLOAT_EQ(d.conf_threshold, 1.0f);
  pnh_.setParam("model_width", 320);
  pnh_.setParam("model_height", 240);
  pnh_.setParam("conf_threshold", 2);  // int for a double
  pnh_.setParam("voxel_size_m", 0.05);
  pnh_.setParam("max_map_points", 1000);
  auto c = readParams(pnh_).reconstruction;
  EXPECT_EQ(c.preprocess.width, 320);
  EXPECT_EQ(c.preprocess.height, 240);
  EXPECT_FLOAT_EQ(c.conf_threshold, 2.0f);
  EXPECT_DOUBLE_EQ(c.map.voxel_size_m, 0.05);
  EXPECT_EQ(c.map.max_points, 1000u);
}

TEST_F(ParamsTest, RejectsModelSizeNotMultipleOf16) {
  pnh_.setParam("model_width", 224);
  pnh_.setParam("model_height", 200);
  expectError("model_height");
}

// One size alone would leave the other to the checkpoint: an aspect ratio
// nobody chose.
TEST_F(ParamsTest, RejectsOneModelSizeWithoutTheOther) {
  pnh_.setParam("model_width", 320);
  expectError("model_height");
}

TEST_F(ParamsTest, RejectsConfidenceBelowOne) {
  pnh_.setParam("conf_threshold", 0.5);
  expectError("conf_threshold");
}

TEST_F(ParamsTest, RejectsZeroVoxelSize) {
  pnh_.setParam("voxel_size_m", 0.0);
  expectError("voxel_size_m");
}

TEST_F(ParamsTest, RejectsVoxelSizeAsString) {
  pnh_.setParam("voxel_size_m", "small");
  expectError("voxel_size_m");
}

TEST_F(ParamsTest, RejectsTooFewPnpInliers) {
  pnh_.setParam("pnp_min_inliers", 3);
  expectError("pnp_min_inliers");
}

TEST_F(ParamsTest, RejectsFewerCorrespondencesThanInliers) {
  pnh_.setParam("pnp_min_inliers", 100);
  pnh_.setParam("pnp_max_correspondences", 50);
  expectError("pnp_max_correspondences");
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_params");
  ros::NodeHandle nh;
  return RUN_ALL_TESTS();
}

TEST_F(ParamsTest, InferenceDefaultsAndValues) {
  const long3r::InferenceConfig d = readParams(pnh_).inference;
  EXPECT_EQ(d.device, "cpu");
  EXPECT_EQ(d.precision, long3r::Precision::kFloat32);
  EXPECT_FALSE(d.allow_emulated_precision);
  pnh_.setParam("device", "cuda:1");
  pnh_.setParam("precision", "bfloat16");
  pnh_.setParam("allow_emulated_precision", true);
  const long3r::InferenceConfig c = readParams(pnh_).inference;
  EXPECT_EQ(c.device, "cuda:1");
  EXPECT_EQ(c.precision, long3r::Precision::kBFloat16);
  EXPECT_TRUE(c.allow_emulated_precision);
  EXPECT_NE(long3r_ros::describe(readParams(pnh_)).find("precision: bfloat16"), std::string::npos);
  // The model's memory: the checkpoint's unless set.
  EXPECT_EQ(d.short_term_frames, -1);
  EXPECT_EQ(d.long_term_capacity, -1);
  pnh_.setParam("short_term_frames", 5);
  pnh_.setParam("long_term_capacity", 0);
  EXPECT_EQ(readParams(pnh_).inference.short_term_frames, 5);
  EXPECT_EQ(readParams(pnh_).inference.long_term_capacity, 0);
  pnh_.setParam("short_term_frames", -2);
  expectError("short_term_frames");
}

TEST_F(ParamsTest, RejectsUnknownDevice) {
  pnh_.setParam("device", "gpu0");
  expectError("device");
}

TEST_F(ParamsTest, RejectsUnknownPrecision) {
  pnh_.setParam("precision", "fp8");
  expectError("precision");
}

TEST_F(ParamsTest, RejectsPrecisionOfWrongType) {
  pnh_.setParam("precision", 16);
  expectError("precision");
}
