// The streaming reconstruction pipeline: source images in, per-frame results
// (pointmap, pose, intrinsics) out, a fused voxel map kept.
//
// Per frame: preprocess (resize + crop to the model size) -> model step ->
// intrinsics (calibration scaled to model resolution, else estimated from
// frame 0's pointmap and kept for the stream) -> pose by PnP-RANSAC on the
// pointmap (PoseTracker, the paper's way), and with pose_method keyframes
// then by image correspondences with keyframes (tracking/keyframe_tracker.hpp,
// on the full-resolution image, its points the pointmap seen from the PnP
// pose) -> map fusion when the pose is good. With keyframes, a frame after
// one whose pose failed, or after a session's restore, is posed only when
// the images relocalise it against a kept keyframe (otherwise its pose
// status is kNotRelocalised and it is not mapped).
//
// Frames: the world frame W is the camera optical frame of frame 0 of the
// current stream (x right, y down, z forward); frame 0's pose is the identity.
// Results come with one frame of latency (the models need the next frame);
// flush() returns the pending one early (a pause in the input) and the stream
// goes on.
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include <array>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "long3r/mapping/occupancy_map.hpp"
#include "long3r/mapping/surface_map.hpp"
#include "long3r/mapping/voxel_map.hpp"
#include "long3r/model/loading/state_dict.hpp"
#include "long3r/model/network/streaming.hpp"
#include "long3r/pipeline/frame_result.hpp"
#include "long3r/pipeline/intrinsics.hpp"
#include "long3r/pipeline/pose.hpp"
#include "long3r/pipeline/preprocess.hpp"
#include "long3r/pipeline/serial_worker.hpp"
#include "long3r/tracking/baseline_scale.hpp"
#include "long3r/tracking/keyframe_tracker.hpp"

namespace long3r {

// Where a frame's pose comes from (besides a pose given to push()).
enum class PoseMethod {
  kModel,      // PnP of the pixels against the model's own pointmap (the paper)
  kKeyframes,  // KeyframeTracker; the model's pose where it cannot track
};
inline const std::array<std::pair<PoseMethod, const char*>, 2>& enum_names(PoseMethod) {
  static const std::array<std::pair<PoseMethod, const char*>, 2> names{
      {{PoseMethod::kModel, "model"}, {PoseMethod::kKeyframes, "keyframes"}}};
  return names;
}

struct ReconstructionConfig {
  // Chosen by the node's pose_source and long3r_reconstruct's --pose-source,
  // not a parameter of its own. Keyframes by default: it measures better than
  // the model's own PnP on every set measured, generated and real
  // (docs/model_card.md, "Poses from keyframes").
  PoseMethod pose_method = PoseMethod::kKeyframes;
  KeyframeTrackerConfig tracker;
  PreprocessConfig preprocess;  // model input size (0 x 0: the checkpoint's)
  PnpConfig pnp;
  VoxelMapConfig map;
  // The fused surface beside the voxel map (off by default: docs/performance.md,
  // "Fused surface").
  SurfaceMapConfig surface;
  // 3-D occupancy of the mapped views (the node's ~grid), in W.
  OccupancyMapConfig occupancy;
  FocalEstimationOptions focal;  // its own conf_threshold (default 0: all pixels, as DUSt3R)
  // When >= 0, replaces pnp.conf_threshold and map.conf_threshold; set it
  // negative to use theirs as given. The default 1 keeps every pixel: the
  // shipped model's confidence stays within about [1, 1.1] (docs/model_card.md)
  // and says little; 3 suits the official DUSt3R / Spann3R checkpoints.
  float conf_threshold = 1.0f;
  // Frames placed by given poses in metres (odometry) measure the metric
  // scale of the model's depth from their images over the baseline
  // (tracking/baseline_scale.hpp; FrameResult::baseline_scale). Set by
  // LiveSession for scale_source odometry, not a parameter of its own.
  bool scale_from_given_poses = false;
  // A control for measurements (long3r_reconstruct --tracker-constant-depth):
  // the keyframe tracker gets the model's rays at each frame's median depth,
  // so that what the model's depth adds to the poses shows; the map keeps
  // the model's depth. Not a parameter of the node.
  bool tracker_constant_depth = false;
  // The fused surface's and the occupancy's updates run on a thread of their
  // own, so that the model's thread goes on to the next frame (at most two
  // frames wait for them; a slower map slows the stream, it loses no view).
  // Every reader of the two waits for the frames handed over so far, so the
  // results are the same either way (docs/performance.md, "Occupancy").
  bool maps_in_background = true;

  // Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

// focal keeps its defaults (DUSt3R's estimate over all pixels).
template <class S, class V>
config::FieldsOf<S, ReconstructionConfig> visit_fields(S& s, V& v) {
  v("conf_threshold", s.conf_threshold);
  v("maps_in_background", s.maps_in_background);
  v.nested("preprocess", s.preprocess, "model_");
  v.nested("map", s.map, "");
  v.nested("pnp", s.pnp, "pnp_");
  v.nested("tracker", s.tracker, "tracker_");
  v.nested("surface", s.surface, "surface_");
  v.nested("occupancy", s.occupancy, "grid_");
}

// Metadata key long3r_make_random_model writes ("true"): the weights are
// random placeholders, the outputs meaningless.
constexpr const char* kRandomWeightsMetadataKey = "random_weights";
bool has_random_weights(const std::map<std::string, std::string>& metadata);

class Reconstruction {
 public:
  // Throws std::invalid_argument for a null model or a bad map config.
  Reconstruction(std::unique_ptr<StreamingModel> model, const ReconstructionConfig& config);
  ~Reconstruction();

  // Source-resolution calibration (e.g. from camera_info / --calib); nullopt =
  // estimate from frame 0. A calibration given mid-stream applies from the
  // next result on; clearing it mid-stream keeps the current intrinsics until
  // reset() (an estimate is only possible on frame 0).
  void set_calibration(const std::optional<PinholeIntrinsics>& calib);

  // One source image (cv::Mat + ROS-style encoding: rgb8, bgr8, rgba8, bgra8,
  // mono8, mono16). Returns the result of the previous frame, or nullopt for
  // the first frame of a stream. Throws std::invalid_argument for bad input
  // (unsupported encoding, type mismatch, size change within a stream: call
  // reset() first); nothing changes then. A frame already returned by flush()
  // is not returned again: its refined result only updates the model's memory.
  // Timings: total_ms = the frame's preprocess time + the wall time of the
  // call that returned it, from its model step to the result (compute time,
  // without the wait for the next frame).
  //
  // T_W_C, when given, places the frame (pose from odometry, as voxblox and
  // nvblox place depth): its pointmap, brought into its own camera frame by
  // its PnP pose, is moved to T_W_C for the map and the result; the result's
  // pose is T_W_C (W is camera 0's frame in the stream's scale: the caller
  // keeps frame 0 at the identity).
  std::optional<FrameResult> push(const cv::Mat& image, const std::string& encoding, double stamp_s,
                                  const std::optional<Eigen::Isometry3d>& T_W_C = std::nullopt);
  // The pending frame's result now, from the coarse head (the camera paused,
  // or the stream ended); nullopt if no frame awaits its result or the model
  // has no pair yet. The stream is not ended: memory, map, trajectory and
  // world frame stay, and the next push continues them. Only reset() starts over.
  std::optional<FrameResult> flush();
  // Model memory, map, trajectory, pose tracker, intrinsics estimate, frame
  // indices. The scale returns to 1 (model units); mapping stays as set.
  void reset();

  // Metres per model unit (metric_scale.hpp): every result from now on is in
  // this scale (pointmaps, poses, covariance), and the map and trajectory
  // built so far are rescaled to it at once, so the stream stays one
  // consistent reconstruction (poses given to push() stay as given).
  // Throws std::invalid_argument unless > 0.
  void set_scale(double scale);
  double scale() const { return scale_; }
  // Brings one result to `scale` as set_scale() brings the stream: its
  // points, model pose and covariance (a given pose is the caller's and
  // stays); r.scale becomes scale.
  // For the result that made the scale known, returned before set_scale().
  static void rescale(FrameResult& r, double scale);

  // Whether posed frames are fused into the map (default on); frames are
  // still posed and returned when off.
  void set_mapping(bool on) { mapping_ = on; }

  const VoxelMap& map() const { return map_; }
  VoxelMap& map() { return map_; }
  // The fused surface of the mapped frames (empty unless surface.enabled);
  // rescaled with the stream, kept in sessions (rebuilt from its kept frames).
  // With maps_in_background, waits for the frames handed to it so far.
  const SurfaceMap& surface() const;
  // The surface handed over whole (an ending stream's, kept apart); an empty
  // one takes its place.
  std::unique_ptr<SurfaceMap> take_surface();
  // The 3-D occupancy of the mapped views in W (empty unless
  // occupancy.enabled); rescaled with the stream, kept in sessions.
  // With maps_in_background, waits for the frames handed to it so far.
  const OccupancyMap& occupancy() const;
  // Returns when the surface and the occupancy hold every frame mapped so
  // far (at once unless maps_in_background).
  void settle_maps() const;
  // (stamp, T_W_C) of the frames with a good pose or a given one, in order.
  std::vector<std::pair<double, Eigen::Isometry3d>> trajectory() const { return trajectory_; }
  // Frames pushed in the current stream.
  int64_t frames_pushed() const { return frames_pushed_; }

  // The whole stream as a state dict, for sessions (session.hpp): the
  // model's stream ("model."), the map ("map.", exact), the path, the pose
  // tracker, the intrinsics and calibration, the scale and frame counters.
  // Call flush() first: a frame still waiting for its result is a
  // std::logic_error, except the lone first frame of a stream, which has no
  // result yet and is left out (the state is then an empty stream).
  StateDict state() const;
  // Replaces the stream by a saved one, of a model with the same identity()
  // and a map of the same voxel size (the caller checks both). Everything is
  // validated first: StateError naming the entry, and nothing changes then.
  // The next push continues the saved stream (its world frame, memory, map,
  // path, scale and frame indices), as after flush().
  void restore(const StateDict& state);

  // A depth camera for the keyframe tracker: the depth this returns for the
  // frame of stamp_s (CV_32FC1 registered to the source image as pushed, in
  // the stream's lengths, 0 or NaN where there is none; empty: none for this
  // frame) lifts the tracker's features instead of the model's depth (the
  // model's rays at the given depth), and the frame's points reach the map
  // at the depth image's scale (the median ratio of the two depths, as
  // depth_scale_sample measures it) rather than the tracker's Sim(3). A
  // frame whose depth covers fewer than 100 confident pixels is tracked by
  // the model's depth. LiveSession sets it for pose_method keyframes with
  // scale_source depth (its depth images, from the first frame after the
  // stream became metric); long3r_reconstruct's
  // --tracker-true-depth sets it as a control (the sequence's true depth, in
  // metres whatever the stream's scale: the path is what to measure). A
  // depth image of another size than the image is a std::invalid_argument.
  // It takes the place of tracker_constant_depth where both are set
  // (long3r_reconstruct refuses the two together). Empty: off.
  // With DepthImageUse::kPoints the frame's points take the depth image's
  // depth too, where it has one (the model's rays at the measured depth, as
  // an RGB-D mapper maps its sensor's depth), and the model's depth at the
  // depth image's scale where it has none or reads more than twice or less
  // than half that (an invalid reading, not the model's error).
  using TrackerDepthSource = std::function<cv::Mat(double stamp_s)>;
  enum class DepthImageUse { kScale, kPoints };
  void set_tracker_depth_source(TrackerDepthSource source,
                                DepthImageUse use = DepthImageUse::kScale) {
    tracker_depth_source_ = std::move(source);
    depth_image_use_ = use;
  }
  // A robot's odometry for the keyframe tracker's motion prior
  // (tracker.motion_prior odometry): the camera's pose in the odometry frame
  // O at the frame of stamp_s (metres), and whether the stream's lengths are
  // metres by then (its translation applies; else only its rotation);
  // nullopt: none for this frame. LiveSession sets it from its client's
  // odometry. Unset or nullopt: the constant velocity.
  struct OdometryPose {
    Eigen::Isometry3d T_O_C = Eigen::Isometry3d::Identity();
    bool metric = false;
  };
  using OdometrySource = std::function<std::optional<OdometryPose>(double stamp_s)>;
  void set_odometry_source(OdometrySource source) { odometry_source_ = std::move(source); }

  const StreamingModel& model() const { return *model_; }
  // As given, with the model input size resolved (PreprocessConfig::resolved
  // by the checkpoint's recorded size).
  const ReconstructionConfig& config() const { return config_; }
  // Intrinsics of the current stream at model resolution, once known.
  const std::optional<ResolvedIntrinsics>& intrinsics() const { return intrinsics_; }

 private:
  struct Pending {
    int64_t index = 0;
    double stamp = 0.0;
    PreprocessedImage image;  // chw moved into the model input
    double preprocess_ms = 0.0;
    std::optional<Eigen::Isometry3d> T_W_C;  // given to push()
    cv::Mat gray;                            // source resolution, for the keyframe tracker
  };
  FrameResult finish(const StreamOutput& out, double call_start_ms, double model_ms);
  // The camera matrix of the source image (the keyframe tracker's pixels).
  Eigen::Matrix3d source_camera_matrix(const PixelMapping& model_to_source) const;

  std::unique_ptr<StreamingModel> model_;
  ReconstructionConfig config_;
  std::optional<PinholeIntrinsics> calibration_;
  std::optional<ResolvedIntrinsics> intrinsics_;
  bool intrinsics_failed_ = false;
  PoseTracker tracker_;
  KeyframeTracker keyframes_;
  BaselineScale baseline_scale_;
  // Where the keyframe tracker's frame goes should it not be tracked
  // (tracker.motion_prior), from the frames it placed before.
  // odometry: the frame's (motion_prior odometry).
  Eigen::Isometry3d tracker_prior(int64_t frame_index, const Eigen::Isometry3d& model_T_W_C,
                                  const std::optional<OdometryPose>& odometry) const;
  // A frame the keyframe tracker posed or the prior placed.
  struct Placed {
    int64_t frame_index = 0;
    Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();
    Eigen::Isometry3d model_T_W_C = Eigen::Isometry3d::Identity();  // the model's own pose
    bool by_images = false;  // posed by the tracker or made a keyframe (not only the prior)
    std::optional<Eigen::Isometry3d> T_O_C;  // the odometry's camera pose (motion_prior odometry)
  };
  // The last placed frame and, before it, the last two placed by the images;
  // oldest first.
  std::deque<Placed> placed_;
  void remember_placed(const Placed& placed);
  VoxelMap map_;
  SurfaceMap surface_;
  OccupancyMap occupancy_;
  // Runs the surface's and the occupancy's updates (maps_in_background);
  // after them, so that it finishes its jobs before they go.
  std::unique_ptr<SerialWorker> map_worker_;
  std::deque<Pending> pending_;
  std::vector<std::pair<double, Eigen::Isometry3d>> trajectory_;
  std::vector<bool> trajectory_given_;  // per entry: the pose was given to push()
  int64_t frames_pushed_ = 0;
  int source_width_ = 0, source_height_ = 0;
  int64_t flushed_index_ = -1;  // frame returned early by flush(), whose refined result is dropped
  double scale_ = 1.0;
  bool mapping_ = true;
  TrackerDepthSource tracker_depth_source_;
  DepthImageUse depth_image_use_ = DepthImageUse::kScale;
  OdometrySource odometry_source_;
};

}  // namespace long3r
