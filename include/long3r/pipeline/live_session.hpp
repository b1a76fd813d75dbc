// LiveSession: a camera stream, live or recorded, turned into one
// reconstruction, with the policy a robot needs around the model. The ROS
// node and long3r_reconstruct both run their frames through it.
//
// It owns the Reconstruction and decides, frame by frame:
//   - continuity (StreamMonitor): a pause of any length continues the stream;
//     single odd frames (no stamp, duplicates, stray sizes, one stamp far
//     ahead) are dropped; only time jumping far back, a lasting size change,
//     `lost_reset_frames` unposed frames or reset() start a new stream;
//   - calibration (CameraRectifier): each frame's calibration is validated
//     against its image, a valid new one applies from that frame on, an
//     invalid one is named and the last valid one kept; distorted raw images
//     are rectified before the model;
//   - metric scale (metric_scale.hpp): samples from the odometry's camera
//     displacements or from registered depth images, asked of the client when
//     a frame's result is known; once the estimate converges the stream is
//     rescaled, and every result leaves here in the stream's final scale
//     (with the keyframe tracker lifting its features by the depth images,
//     tracker_depth_images, the first depth sample is applied at once);
//   - the maps of ended streams: a new stream never wipes the map the user
//     built; the ending stream's map is kept in the client's map frame
//     (LiveSessionClient::T_map_W) beside the new one, saved with sessions,
//     and cleared only by reset().
// Each frame carries the caller's tag (a ROS header) back with its result.
//
// Frames: W is the camera optical frame of the stream's frame 0 (as in
// Reconstruction); lengths in metres once the scale is metric, else in
// model units. Not thread-safe: one thread (the node's worker) calls it,
// and a caller that serves other threads (services) holds its own lock.
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include <any>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>

#include "long3r/config/config_fields.hpp"
#include "long3r/pipeline/camera_rectifier.hpp"
#include "long3r/pipeline/metric_scale.hpp"
#include "long3r/pipeline/reconstruction.hpp"
#include "long3r/pipeline/session.hpp"
#include "long3r/pipeline/stream_monitor.hpp"

namespace long3r {

struct LiveSessionConfig {
  StreamMonitorConfig stream;
  MetricScaleConfig scale;
  // While tracking is lost the stream keeps its memory and map, and each new
  // frame is tried against them: relocalised when its pose passes the checks
  // tracking uses. A new stream starts after lost_reset_frames frames or
  // relocalise_for_s seconds of stamps without a pose, whichever comes first
  // (0: no bound of that kind).
  int lost_reset_frames = 0;
  double relocalise_for_s = 30.0;
  // The images arrive rectified: a calibration's distortion is not applied again.
  bool image_is_rectified = false;
  // With pose_method keyframes and scale_source depth (an RGB-D camera), the
  // keyframe tracker lifts its features by the depth images rather than the
  // model's depth, so that the path keeps the camera's metric scale instead
  // of chaining the model's from keyframe to keyframe; the first depth
  // image's scale is applied at once and kept, and each frame's points reach
  // the map at its own depth image's scale (docs/model_card.md, "A depth
  // camera for the tracker"). Off: the model's depth, as for a monocular camera.
  bool tracker_depth_images = true;
  // With tracker_depth_images, each frame's points take its depth image's
  // depth where it has one (the model's rays at the measured depth), as
  // RGB-D mappers map their sensor's depth; the model's depth, at the depth
  // image's scale, fills where the depth image has none or an implausible
  // one (beyond a factor of 2 of the model's there). Frame 0, mapped before
  // its depth image makes the stream metric, is at that scale. Off: the
  // model's depth everywhere, at the depth image's scale (its shape is the
  // model's: docs/model_card.md, "An RGB-D robot's map").
  bool map_depth_images = true;
  // What the calibrations are called in messages ("camera_info", "calibration.txt").
  std::string calibration_source = "calibration";

  // Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

// calibration_source is the client's to set, not a setting.
template <class S, class V>
config::FieldsOf<S, LiveSessionConfig> visit_fields(S& s, V& v) {
  v("image_is_rectified", s.image_is_rectified);
  v("tracker_depth_images", s.tracker_depth_images);
  v("map_depth_images", s.map_depth_images);
  v("lost_reset_frames", s.lost_reset_frames, "(no bound)");
  v("relocalise_for_s", s.relocalise_for_s, "(no bound)");
  v.nested("stream", s.stream, "");
  v.nested("scale", s.scale, "scale_");
}

// One input frame.
struct LiveFrame {
  cv::Mat image;         // the source image, in `encoding` (Reconstruction::push)
  std::string encoding;  // rgb8, bgr8, rgba8, bgra8, mono8, mono16
  double stamp_s = 0.0;  // its time stamp
  double clock_s = 0.0;  // the clock when it arrived (ROS time: simulated in a replay)
  // The camera's calibration for this frame, when one is known.
  std::optional<CameraModel> camera;
  std::any tag;  // the caller's, returned with the frame's result
};

struct LiveResult {
  FrameResult frame;    // in the stream's scale after this frame
  std::any tag;         // the frame's LiveFrame::tag
  cv::Size image_size;  // the image as the model took it (after rectification)
  // The metric scale was (re)applied with this result: the stream, this
  // result included, is now in another scale than the results before.
  bool scale_changed = false;
};

// What happened, for the log. Warnings are grouped by kind for throttling
// (one kind's flood does not hide another's); some must never be throttled.
struct LiveEvent {
  enum class Level { kInfo, kWarning };
  Level level = Level::kInfo;
  std::string kind;
  std::string message;
  bool throttle = true;        // warnings only
  bool frame_dropped = false;  // the frame named was not processed
};

// What the session asks of the world around it, on its caller's thread: the
// node answers from TF and its topics, long3r_reconstruct from the dataset.
class LiveSessionClient {
 public:
  // A question the world cannot answer now: kind (for throttling) and a
  // message naming the problem.
  class Unavailable : public std::runtime_error {
   public:
    Unavailable(std::string kind, const std::string& what)
        : std::runtime_error(what), kind_(std::move(kind)) {}
    const std::string& kind() const { return kind_; }

   private:
    std::string kind_;
  };

  virtual ~LiveSessionClient() = default;
  // Just before the model runs on a frame the stream admitted: the pose that
  // places it (pose from odometry, in W) or nullopt (the model's own pose).
  // Throwing Unavailable skips the frame (dropped, with that message).
  virtual std::optional<Eigen::Isometry3d> place(const LiveFrame& frame);
  // The camera's pose in a metric odometry frame (translation in metres) at
  // the stamp of the frame tagged `tag` (LiveFrame::tag), asked when the
  // model's result for it is known: scale_source odometry takes its
  // position, tracker_motion_prior odometry its motion. Throwing
  // Unavailable skips this frame's sample (and its odometry for the prior).
  virtual Eigen::Isometry3d odometry_camera_m(const std::any& tag);
  // scale_source depth: a depth image registered to the raw source image of
  // the frame tagged `tag` (LiveFrame::tag): CV_16UC1 millimetres (RGB-D
  // drivers) or CV_32FC1 metres, 0 or NaN where there is none. Asked once a
  // frame, when the model's result for it is known. Throwing Unavailable
  // skips this frame's sample (and its depth for the tracker).
  virtual cv::Mat depth(const std::any& tag);

  // Sessions: what the client keeps per stream that a saved session must
  // keep too (the node: where W sits in its map frame). Saved with the
  // session; after a load (and its on_new_stream()) it comes back. Entries
  // the client cannot use are ignored, never an error: the file may come
  // from another client (long3r_reconstruct's, loaded by the node).
  virtual StateDict session_state() { return {}; }
  virtual void restore_session_state(const StateDict& state) { (void)state; }
  // Where the ending stream's W sits in the client's map frame, asked when a
  // stream ends (before on_stream_ending()): its map is kept there
  // (LiveSession::ended_maps()). nullopt (the default): W is tied to no map
  // frame, and the ending stream's map is not kept.
  virtual std::optional<Eigen::Isometry3d> T_map_W() { return std::nullopt; }

  // Results, in frame order.
  virtual void on_result(LiveResult& result) = 0;
  // The stream is about to end (its last result delivered): its map and path
  // are still there to keep (the node keeps the map in ~map).
  virtual void on_stream_ending(const Reconstruction& ending) { (void)ending; }
  // A new stream starts (after the old one's last result): the caller's
  // per-stream state goes with the memory, map and path.
  virtual void on_new_stream(const std::string& why) { (void)why; }
  virtual void on_event(const LiveEvent& event) { (void)event; }
};

// A snapshot for diagnostics.
struct LiveStatus {
  std::int64_t stream_frames = 0;        // frames pushed in the current stream
  std::uint64_t streams = 0;             // streams started, the first included
  std::string tracking = "not started";  // "ok", "lost"
  int lost_frames = 0;                   // consecutive frames without a pose
  double lost_for_s = 0.0;               // stamps spanned by them
  // Frames tried while tracking was lost or, with pose_method keyframes,
  // while relocalising (after a lost pose or a loaded session); of them, the
  // ones that found the pose again, and those the images refused (no kept
  // keyframe confirms the pose: the frame is not posed).
  std::uint64_t relocalisation_attempts = 0;
  std::uint64_t relocalisations = 0;
  std::uint64_t relocalisations_refused = 0;
  // pose_method keyframes: frames the keyframe tracker posed, and those it
  // could not (placed by the motion prior, tracker_motion_prior); and the
  // frames that lost it (tracker_when_lost relocalise: a cut to another
  // scene or a fast move, not posed, relocalising from the next frame).
  std::uint64_t keyframe_tracked = 0, keyframe_untracked = 0, keyframe_lost = 0;
  // Of the tracked frames, those the optical-flow bridge posed
  // (tracker_flow_bridge: too few features or matches for the keyframes).
  std::uint64_t keyframe_flow = 0;
  std::string calibration = "none";  // the one in use, or why the latest was refused
  bool calibration_refused = false;  // the latest calibration was not used
  ScaleEstimate scale_estimate;
  double scale = 1.0;  // metres per model unit in use
  bool scale_metric = false;
  // Frames are placed by given poses (metres) but not mapped until the scale
  // is metric.
  bool mapping_held = false;
  std::int64_t mem_short_tokens = 0, mem_long_tokens = 0, relevant_tokens = -1;
};

class LiveSession {
 public:
  // Throws ConfigError for a bad config, std::invalid_argument for a null
  // model (Reconstruction).
  LiveSession(std::unique_ptr<StreamingModel> model, const ReconstructionConfig& reconstruction,
              const LiveSessionConfig& config, LiveSessionClient& client);

  // One input frame, in arrival order. Results and events go to the client.
  // Throws what Reconstruction::push throws for input it refuses (nothing of
  // the session changes then but the stream's record of the frame).
  void push(LiveFrame frame);
  // The pending frame's result now (a pause in the input); the stream goes on.
  void flush();
  // Starts a new stream with the next frame (memory, map, path, scale) and
  // clears the maps of ended streams; `why` names the reason in the warning.
  void reset(const std::string& why);

  // Sessions (session.hpp). save() delivers the pending frame's result (as
  // flush()) and writes the whole stream to `path` atomically; the stream
  // goes on. load() replaces the stream by a saved one: memory, map, path,
  // world frame, scale and frame indices. The next frame continues it,
  // whatever its stamp (a recording replayed again, another day), and
  // on_new_stream() tells the client that its per-stream state is stale.
  // Both throw SessionError naming the file and the problem (another model
  // or configuration, a damaged or foreign file, a failed write); the
  // running stream is then unchanged.
  void save(const std::string& path);
  void load(const std::string& path);
  SessionIdentity identity() const;

  LiveStatus status() const { return status_; }
  // The maps of the streams that ended since the last reset() (tracking
  // lost, time jumps, size changes), in the client's map frame. Like the
  // current stream's map it locks itself: another thread may read it.
  const VoxelMap& ended_maps() const { return ended_maps_; }
  // The whole map in the client's map frame: the current stream's, placed by
  // T_map_W, and the ended streams'. Callable from any thread (both maps
  // lock themselves), as is map_revision(), which changes whenever either
  // map does.
  MapSnapshot map_snapshot(const Eigen::Isometry3d& T_map_W) const;
  std::uint64_t map_revision() const;
  // The fused surface (surface_enabled) and its mesh in the client's map
  // frame: the current stream's placed by T_map_W and the ended streams'
  // where they ended. Callable from any thread, as is surface_revision().
  ColoredPoints surface_points(const Eigen::Isometry3d& T_map_W) const;
  ColoredMesh surface_mesh(const Eigen::Isometry3d& T_map_W) const;
  std::uint64_t surface_revision() const;
  // The 3-D occupancy (occupancy.enabled) seen from the client's z-up map
  // frame: the current stream's placed by T_map_W and the ended streams'
  // where they ended (as their maps are kept), one grid of config's band
  // above the floor, its height fitted (GridFloor::kFit, where a floor is
  // found) or z = 0 of the map frame (the base's). Callable from any thread,
  // as is occupancy_revision().
  struct GridProjection {
    OccupancyGrid grid;
    double floor_z_m = 0.0;
    bool floor_fitted = false;
  };
  GridProjection occupancy_grid(const Eigen::Isometry3d& T_map_W,
                                const GridProjectionConfig& config) const;
  std::uint64_t occupancy_revision() const;
  const Reconstruction& reconstruction() const { return recon_; }
  Reconstruction& reconstruction() { return recon_; }
  const LiveSessionConfig& config() const { return config_; }

 private:
  struct Pending {  // a frame the model took, awaiting its result
    std::any tag;
    cv::Size image_size;
    double stamp_s = 0.0;
  };
  // The frame being finished (the oldest pending one with this stamp), or null.
  const Pending* pending_at(double stamp_s) const;
  void process(LiveFrame frame);
  cv::Mat calibrate(const LiveFrame& frame);
  void deliver(FrameResult frame);
  void track_loss(const FrameResult& r);
  void update_scale(LiveResult& result);
  std::optional<double> depth_sample(const LiveResult& result);
  cv::Mat registered_depth(const std::any& tag, double stamp_s, const cv::Size& image_size);
  void new_stream(const std::string& why, bool keep_map);
  void keep_ended_map();
  void start_stream_scale();
  void info(const std::string& kind, const std::string& message);
  void warn(const std::string& kind, const std::string& message, bool dropped = false);

  LiveSessionConfig config_;
  LiveSessionClient& client_;
  Reconstruction recon_;
  VoxelMap ended_maps_;
  // What an ended stream leaves besides its points (ended_maps_): its
  // occupancy and its surface (each null where off or empty), at the T_map_W
  // where it ended. Guarded: the grid and the surface are read from other
  // threads. Saved with the session.
  struct EndedStream {
    std::shared_ptr<const OccupancyMap> occupancy;
    std::shared_ptr<const SurfaceMap> surface;
    Eigen::Isometry3d T_map_W = Eigen::Isometry3d::Identity();
  };
  template <class Part>
  Part surfaces_in_map(Part (SurfaceMap::*part)() const, const Eigen::Isometry3d& T_map_W) const;
  StateDict ended_state() const;
  std::vector<EndedStream> read_ended(const StateDict& file) const;
  void set_ended(std::vector<EndedStream> ended);
  mutable std::mutex ended_mutex_;
  std::vector<EndedStream> ended_;
  std::uint64_t ended_revision_ = 0;
  StreamMonitor monitor_;
  std::optional<LiveFrame> held_;  // see StreamMonitor::kHold
  std::deque<Pending> pending_;
  // The last frame's depth image as registered_depth() gave it (empty: none).
  struct DepthImage {
    double stamp_s = 0.0;
    cv::Mat metres;
  };
  std::optional<DepthImage> depth_;
  CameraRectifier rectifier_;
  ScalePolicy scale_policy_;
  OdometryScaleSampler scale_sampler_;
  double lost_since_stamp_ = 0.0;
  std::string intrinsics_logged_;  // the intrinsics line last reported
  LiveStatus status_;
};

}  // namespace long3r
