// long3r_reconstruct: offline streaming reconstruction of an image folder, a
// video file or a TUM RGB-D folder (rgb.txt) with a LONG3R or Spann3R checkpoint.
//
// The frames go through the core's LiveSession, as the ROS node's do: the
// same stream continuity, calibration checks, rectification of distorted
// cameras and metric scale (--scale-source: a TUM folder's depth images or
// odometry, --odometry: by default its groundtruth.txt standing in for it).
//
// Sessions: --save-session writes the whole stream (memory, map, path, scale)
// at the end, --load-session continues one, e.g. on a later part of the same
// input (--first-frame): the map and trajectory then hold both parts, in the
// saved session's world frame.
//
// Outputs in --out: map.ply (fused voxel map, world = camera 0), with
// --surface-enabled true surface.ply and mesh.ply (the TSDF's), with --poses
// and the occupancy on grid.pgm and grid.yaml (map_server's files, in the
// poses' z-up frame, of the default band above the fitted floor), trajectory.txt
// (TUM "t tx ty tz qx qy qz qw", frames with a good pose), frames.csv (per
// frame timings, memory tokens, PnP status, scale, RSS); a summary on stdout.
// Lengths in metres once a metric scale is known, else in model units.
// Calibration: --calib fx fy cx cy (source pixels) wins; else a TUM folder's
// calibration.txt (lens distortion included: the images are rectified);
// else the focal length is estimated from frame 0.
//
// --poses places the frames by a known trajectory (a TUM folder's
// groundtruth.txt, or a TUM trajectory file) as the node's pose_source
// odometry places them by odometry: W is the first frame's camera, lengths in
// metres, so the map waits for a metric --scale-source. --fusion-split then
// measures what fusing the views could remove from the map's error
// (eval/fusion_bound.hpp): averaged.ply, averaged_rescaled.ply and
// fusion_split.json in --out.
#include <unistd.h>

#include <algorithm>
#include <any>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>
#include <string>
#include <vector>

#include "long3r/config/cli_options.hpp"
#include "long3r/dataset/tum_dataset.hpp"
#include "long3r/eval/eval_json.hpp"
#include "long3r/eval/fusion_bound.hpp"
#include "long3r/geometry/cv/point_cloud_io.hpp"
#include "long3r/io/atomic_file.hpp"
#include "long3r/mapping/occupancy_map.hpp"
#include "long3r/model/loading/safetensors.hpp"
#include "long3r/model/runtime/inference.hpp"
#include "long3r/model/runtime/inference_config.hpp"
#include "long3r/model/runtime/threads.hpp"
#include "long3r/pipeline/live_session.hpp"

namespace fs = std::filesystem;
using namespace long3r;

namespace {

long rss_kb() {
  std::ifstream f("/proc/self/status");
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::atol(line.c_str() + 6);
  }
  return -1;
}

// Frames from a folder, TUM folder or video, one at a time.
struct Source {
  std::vector<std::string> paths;
  std::vector<double> stamps;
  cv::VideoCapture video;
  bool is_video = false;
  double fps = 30.0;
  std::optional<TumDataset> tum;
  std::optional<CameraModel> camera;  // calibration.txt or --calib
  // --poses: each frame's T_ref_C by its index (nullopt: none near its stamp).
  std::vector<std::optional<Eigen::Isometry3d>> poses;
  // --odometry: each frame's camera pose in the odometry frame, metres.
  std::vector<std::optional<Eigen::Isometry3d>> odometry;
};

// The pose of each frame of `src` from `spec` (the value of `option`):
// "groundtruth" (the TUM folder's, associated by its reader) or a TUM
// trajectory file, the pose nearest each frame's stamp within max_diff_s.
std::vector<std::optional<Eigen::Isometry3d>> read_poses(const std::string& option,
                                                         const std::string& spec, const Source& src,
                                                         double max_diff_s) {
  std::vector<std::optional<Eigen::Isometry3d>> poses;
  if (spec == "groundtruth") {
    if (!src.tum) throw std::runtime_error(option + " groundtruth needs a TUM folder");
    for (const TumFrame& f : src.tum->frames()) poses.push_back(f.pose);
    return poses;
  }
  const PoseTrajectory traj = read_tum_trajectory(spec);
  if (traj.size() == 0) throw std::runtime_error(option + " " + spec + ": no poses");
  for (double t : src.stamps) {
    const auto it = std::lower_bound(traj.stamps.begin(), traj.stamps.end(), t);
    std::optional<Eigen::Isometry3d> best;
    double best_diff = max_diff_s;
    for (auto c = it == traj.stamps.begin() ? it : it - 1; c != traj.stamps.end() && c <= it; ++c) {
      const double diff = std::abs(*c - t);
      if (diff <= best_diff) {
        best_diff = diff;
        best = traj.poses[static_cast<std::size_t>(c - traj.stamps.begin())];
      }
    }
    poses.push_back(best);
  }
  return poses;
}

// The dataset's answers to the session, and the session's outputs: results
// to `record`, messages to stderr (each kind of warning at most
// kWarningsPerKind times, then counted).
class Client : public LiveSessionClient {
 public:
  static constexpr int kWarningsPerKind = 3;
  Client(const Source& src, std::function<void(const FrameResult&)> record)
      : src_(src), record_(std::move(record)) {}

  // --poses: the frame's pose relative to the stream's first placed frame
  // (W is its camera, as the session's is).
  std::optional<Eigen::Isometry3d> place(const LiveFrame& frame) override {
    if (src_.poses.empty()) return std::nullopt;
    const std::size_t i = std::any_cast<std::size_t>(frame.tag);
    if (!src_.poses[i]) {
      throw Unavailable("pose missing",
                        "frame " + std::to_string(i) + " has no --poses pose near its stamp");
    }
    if (!T_ref_W_) T_ref_W_ = *src_.poses[i];
    return given_pose(i);
  }
  void on_new_stream(const std::string& why) override {
    (void)why;
    T_ref_W_.reset();
  }
  // The --poses' world frame's pose of W (the current stream's first placed
  // camera); nullopt until one is placed.
  std::optional<Eigen::Isometry3d> T_poses_W() const { return T_ref_W_; }
  // T_W_C of frame i by --poses (set once its stream is placed).
  std::optional<Eigen::Isometry3d> given_pose(std::size_t i) const {
    if (!T_ref_W_ || i >= src_.poses.size() || !src_.poses[i]) return std::nullopt;
    return T_ref_W_->inverse() * *src_.poses[i];
  }

  // --odometry's camera pose (by default the sequence's groundtruth.txt).
  Eigen::Isometry3d odometry_camera_m(const std::any& tag) override {
    const std::size_t i = std::any_cast<std::size_t>(tag);
    if (i >= src_.odometry.size() || !src_.odometry[i]) {
      throw Unavailable("odometry missing", "frame " + std::to_string(i) +
                                                " has no --odometry pose near its stamp "
                                                "(scale_source odometry or "
                                                "tracker_motion_prior odometry)");
    }
    return *src_.odometry[i];
  }
  cv::Mat depth(const std::any& tag) override {
    const std::size_t i = std::any_cast<std::size_t>(tag);
    if (!src_.tum || src_.tum->frame(i).depth_path.empty()) {
      throw Unavailable("depth missing",
                        "frame " + std::to_string(i) + " has no depth image (scale_source depth)");
    }
    try {
      return src_.tum->load_depth(i);
    } catch (const std::exception& e) {
      throw Unavailable("depth unreadable", e.what());
    }
  }
  void on_result(LiveResult& r) override {
    record_(r.frame);
    if (keep_) keep_(r);
  }
  // Also called with each result (--fusion-split).
  void keep_results(std::function<void(const LiveResult&)> keep) { keep_ = std::move(keep); }
  void on_event(const LiveEvent& e) override {
    if (e.level == LiveEvent::Level::kInfo) {
      std::fprintf(stderr, "\nlong3r_reconstruct: %s\n", e.message.c_str());
    } else if (!e.throttle || ++warnings_[e.kind] <= kWarningsPerKind) {
      std::fprintf(stderr, "\nlong3r_reconstruct: warning: %s\n", e.message.c_str());
    }
  }
  // "kind: N more" for the warnings not shown.
  std::string suppressed() const {
    std::string s;
    for (const auto& [kind, n] : warnings_) {
      if (n > kWarningsPerKind) {
        s += (s.empty() ? "" : ", ") + kind + ": " + std::to_string(n - kWarningsPerKind) + " more";
      }
    }
    return s;
  }

 private:
  const Source& src_;
  std::function<void(const FrameResult&)> record_;
  std::function<void(const LiveResult&)> keep_;
  std::map<std::string, int> warnings_;
  std::optional<Eigen::Isometry3d> T_ref_W_;
};

}  // namespace

int main(int argc, char** argv) {
  std::string model_path, out_dir, input, load_session, save_session, poses_spec;
  std::string odometry_spec = "groundtruth";
  bool fusion_split = false, tracker_true_depth = false;
  int stride = 1;
  long first_frame = 0;
  ThreadConfig threads;
  long max_frames = -1;
  ReconstructionConfig cfg;
  LiveSessionConfig session_cfg;
  session_cfg.calibration_source = "calibration";
  session_cfg.stream.drop_zero_stamps = false;  // recorded clocks may start at 0
  std::optional<PinholeIntrinsics> calib;
  CliOptions cli("long3r_reconstruct");
  cli.positional("INPUT", &input,
                 "a folder of images (name order), a video file, or a TUM folder (rgb.txt)")
      .required();
  cli.option("--model", "FILE", &model_path, "LONG3R or Spann3R safetensors checkpoint").required();
  cli.option("--out", "DIR", &out_dir,
             "map.ply, trajectory.txt, frames.csv (surface.ply, mesh.ply with "
             "--surface-enabled true)")
      .required();
  cli.option("--stride", "N", &stride, "use every N-th frame").min(1);
  cli.option("--max-frames", "N", &max_frames, "stop after N used frames").shown_default("all");
  cli.option("--first-frame", "N", &first_frame, "start at the input's N-th frame (0-based)")
      .min(0);
  cli.option("--load-session", "FILE", &load_session,
             "continue a session saved by --save-session or the node's ~save_session");
  cli.option("--save-session", "FILE", &save_session,
             "save the session (memory, map, path, scale) at the end, to continue it later");
  cli.option("--poses", "SOURCE", &poses_spec,
             "place the frames by known poses: groundtruth (a TUM folder's) or a TUM "
             "trajectory file (metres; the map waits for a metric --scale-source)");
  cli.option("--odometry", "SOURCE", &odometry_spec,
             "the robot's odometry (the camera in its frame, metres) for --scale-source "
             "odometry and --tracker-motion-prior odometry: groundtruth (a TUM folder's) or a "
             "TUM trajectory file")
      .shown_default("groundtruth");
  cli.flag("--fusion-split", &fusion_split,
           "with --poses groundtruth and depth: what fusing views could remove from the map's "
           "error (averaged.ply, averaged_rescaled.ply, fusion_split.json)");
  cli.custom(
         "--img-size", {"N"},
         [&](const std::vector<std::string>& v) {
           cfg.preprocess.width = cfg.preprocess.height = parse_cli_value<int>("--img-size", v[0]);
         },
         "model input size N x N (--model-width and --model-height)")
      .shown_default("the size the checkpoint was trained at where it records one, else 224");
  add_thread_options(cli, &threads);
  InferenceConfig inference;
  add_inference_options(cli, &inference);
  add_memory_options(cli, &inference);
  cli.custom(
         "--calib", {"fx", "fy", "cx", "cy"},
         [&](const std::vector<std::string>& v) {
           PinholeIntrinsics k;
           k.fx = parse_cli_value<double>("--calib", v[0]);
           k.fy = parse_cli_value<double>("--calib", v[1]);
           k.cx = parse_cli_value<double>("--calib", v[2]);
           k.cy = parse_cli_value<double>("--calib", v[3]);
           calib = k;
         },
         "source-pixel intrinsics")
      .shown_default("TUM calibration.txt, else estimated from frame 0");
  // The node's parameters of the pipeline and the session, by the same names
  // (README, Parameters). --scale-source: depth takes a TUM folder's depth
  // images, odometry --odometry's positions.
  cli.option("--pose-source", "NAME", &cfg.pose_method,
             "the node's parameter pose_source: model (PnP on the model's pointmap, the "
             "paper's) or keyframes (image correspondences with keyframes, lifted by the "
             "pointmaps)");
  cli.flag("--tracker-constant-depth", &cfg.tracker_constant_depth,
           "a control for measuring the tracker: it lifts its keyframes' features by a "
           "constant-depth plane (each frame's median depth) instead of the model's depth; the "
           "map keeps the model's");
  cli.flag("--tracker-true-depth", &tracker_true_depth,
           "a control for measuring the tracker: it lifts its keyframes' features by the TUM "
           "folder's depth images (the model's rays at the true depth) instead of the model's "
           "depth, from the first frame whatever --scale-source, so that what the model's depth "
           "costs the path shows; the map's points take each depth image's scale (measure the "
           "path, not the map)");
  cli.section("Pipeline and session (the node's parameters, README \"Parameters\")");
  add_config_options(cli, &cfg);
  add_config_options(cli, &session_cfg);
  if (const auto rc = cli.parse_or_exit(argc, argv)) return *rc;

  try {
    if (!fs::exists(model_path)) throw std::runtime_error("model file not found: " + model_path);
    if (!fs::exists(input)) throw std::runtime_error("input not found: " + input);
    // Named as the options are, without their dashes.
    const config::FieldCheck check{"long3r_reconstruct: option", "", true};
    cfg.validate(check);
    session_cfg.validate(check);
    Source src;
    if (fs::is_directory(input)) {
      if (fs::exists(fs::path(input) / "rgb.txt")) {
        TumDatasetOptions options;
        options.allow_distortion = true;  // rectified by the session
        src.tum = TumDataset::open(input, options);
        for (const TumFrame& f : src.tum->frames()) {
          src.paths.push_back(f.rgb_path);
          src.stamps.push_back(f.stamp);
        }
        if (const auto& c = src.tum->camera()) {
          src.camera = camera_model(c->intrinsics, c->distortion_model, c->distortion);
          session_cfg.calibration_source = "calibration.txt";
        }
      } else {
        const ImageFolder folder = ImageFolder::open(input);
        src.paths = folder.paths();
        for (size_t i = 0; i < src.paths.size(); ++i) src.stamps.push_back(i / 30.0);
      }
      if (src.paths.empty()) throw std::runtime_error("no images in " + input);
    } else {
      src.is_video = true;
      if (!src.video.open(input) || !src.video.isOpened()) {
        throw std::runtime_error("cannot open video " + input);
      }
      const double fps = src.video.get(cv::CAP_PROP_FPS);
      if (fps > 0) src.fps = fps;
    }
    if (calib) {
      src.camera = camera_model(*calib);
      session_cfg.calibration_source = "--calib";
    }
    if (!poses_spec.empty()) {
      if (src.is_video) throw std::runtime_error("--poses needs images with stamps, not a video");
      if (!load_session.empty()) {
        throw std::runtime_error(
            "--poses places frames in a new stream's world; it cannot "
            "continue --load-session's");
      }
      src.poses = read_poses("--poses", poses_spec, src, 0.02);
    }
    if (src.tum || odometry_spec != "groundtruth") {
      if (src.is_video)
        throw std::runtime_error("--odometry needs images with stamps, not a video");
      src.odometry = read_poses("--odometry", odometry_spec, src, 0.02);
    }
    // What --fusion-split and --tracker-true-depth read the depth images by.
    const bool own_pinhole =
        src.tum && src.tum->camera() && !src.tum->camera()->distorted() && !calib;
    if (fusion_split) {
      if (poses_spec != "groundtruth") {
        throw std::runtime_error("--fusion-split needs --poses groundtruth");
      }
      if (!own_pinhole) {
        throw std::runtime_error(
            "--fusion-split needs the TUM folder's own undistorted calibration.txt");
      }
    }
    if (tracker_true_depth) {
      if (!own_pinhole) {
        throw std::runtime_error(
            "--tracker-true-depth needs a TUM folder with depth images and its own undistorted "
            "calibration.txt");
      }
      if (cfg.pose_method != PoseMethod::kKeyframes) {
        throw std::runtime_error("--tracker-true-depth needs --pose-source keyframes");
      }
      if (cfg.tracker_constant_depth) {
        throw std::runtime_error(
            "--tracker-true-depth and --tracker-constant-depth both replace the model's depth "
            "for the tracker: give one of --tracker-true-depth and --tracker-constant-depth");
      }
      if (session_cfg.scale.source == ScaleSource::kDepth && session_cfg.tracker_depth_images) {
        throw std::runtime_error(
            "--tracker-true-depth with --scale-source depth: the tracker lifts its features by "
            "the depth images already (--tracker-depth-images); give one of them");
      }
    }
    const ScaleSource scale_source = session_cfg.scale.source;
    if ((scale_source == ScaleSource::kDepth || scale_source == ScaleSource::kOdometry) &&
        !src.tum) {
      throw std::runtime_error(std::string("--scale-source ") + config::enum_name(scale_source) +
                               " needs a TUM folder (depth.txt, groundtruth.txt)");
    }

    const auto metadata = read_safetensors_metadata(model_path);
    const bool random = has_random_weights(metadata);
    if (random) {
      std::fprintf(stderr,
                   "\n*** WARNING: %s HAS RANDOM WEIGHTS (a placeholder made by "
                   "long3r_make_random_model). Pointmaps, poses and the map are "
                   "meaningless. ***\n\n",
                   model_path.c_str());
    }
    const ThreadState thread_state = apply_thread_config(threads);
    fs::create_directories(out_dir);
    AtomicFile csv((fs::path(out_dir) / "frames.csv").string());  // appears at the end, whole
    csv.write(
        "frame,stamp,preprocess_ms,model_ms,encode_ms,decode_ms,memory_ms,intrinsics_ms,"
        "pose_ms,map_ms,total_ms,mem_short,mem_long,mem_relevant,pnp_status,pnp_inliers,"
        "added_to_map,map_points,scale,rss_kb,tracking,tracking_solver,tracking_matches,"
        "tracking_inliers,tracking_parallax_deg,tracking_scale,keyframe,tracking_ms,"
        "tracking_features_ms,baseline_scale_sample,baseline_triangulated\n");
    const bool tty = isatty(fileno(stdout));
    std::vector<double> frame_ms;
    long peak_rss = 0;
    auto record = [&](const FrameResult& r) {
      const StageTimings& t = r.timings;
      const StepStats& m = r.model;
      const long rss = rss_kb();
      peak_rss = std::max(peak_rss, rss);
      frame_ms.push_back(t.total_ms);
      // pose_source keyframes: what the tracker made of the frame (else empty).
      char tracking[192] = ",,,,,,,,";
      if (const auto& k = r.tracking) {
        std::snprintf(tracking, sizeof tracking, "%s,%s,%d,%d,%.3f,%.6g,%d,%.3f,%.3f",
                      to_string(k->status), k->flow ? "flow" : config::enum_name(k->solver),
                      k->matches, k->inliers, k->parallax_deg, k->scale, k->new_keyframe ? 1 : 0,
                      t.tracking_ms, k->features_ms);
      }
      // Placed by given poses with --scale-source odometry: the images' sample
      // of metres per model unit over the baseline (else empty).
      char baseline[64] = ",";
      if (const auto& b = r.baseline_scale) {
        std::snprintf(baseline, sizeof baseline, "%s,%d",
                      b->sample ? std::to_string(*b->sample).c_str() : "", b->triangulated);
      }
      char line[768];
      std::snprintf(
          line, sizeof line,
          "%lld,%.6f,%.3f,%.3f,%.3f,%.3f,%.3f,%.3f,%.3f,%.3f,%.3f,%lld,%lld,%lld,%s,%d,%d,"
          "%zu,%.9g,%ld,%s,%s\n",
          static_cast<long long>(r.frame_index), r.stamp, t.preprocess_ms, t.model_ms, m.encode_ms,
          m.decode_ms, m.memory_ms, t.intrinsics_ms, t.pose_ms, t.map_ms, t.total_ms,
          static_cast<long long>(m.mem_short_tokens), static_cast<long long>(m.mem_long_tokens),
          static_cast<long long>(m.relevant_tokens), to_string(r.pose.status), r.pose.inliers,
          r.added_to_map ? 1 : 0, r.map_points, r.scale, rss, tracking, baseline);
      csv.write(line);
      const double fps = t.total_ms > 0 ? 1000.0 / t.total_ms : 0.0;
      if (tty) {
        std::printf("\rframe %lld  %.1f FPS  pose %s  map %zu pts   ",
                    static_cast<long long>(r.frame_index), fps, to_string(r.pose.status),
                    r.map_points);
        std::fflush(stdout);
      } else {
        std::printf("frame %lld: %.1f ms, pose %s (%d inliers), map %zu points\n",
                    static_cast<long long>(r.frame_index), t.total_ms, to_string(r.pose.status),
                    r.pose.inliers, r.map_points);
      }
    };
    Client client(src, record);
    // --fusion-split: the mapped frames' camera-frame points, brought to the
    // final scale at the end.
    struct Kept {
      std::size_t index;
      cv::Mat points_C;
      double scale;
      PinholeIntrinsics K;
    };
    std::vector<Kept> kept;
    if (fusion_split) {
      client.keep_results([&](const LiveResult& r) {
        if (r.frame.added_to_map && !r.frame.points_C.empty()) {
          kept.push_back({std::any_cast<std::size_t>(r.tag), r.frame.points_C.clone(),
                          r.frame.scale, r.frame.intrinsics});
        }
      });
    }
    LiveSession session(make_streaming_model(model_path, inference), cfg, session_cfg, client);
    if (!load_session.empty()) session.load(load_session);
    if (tracker_true_depth) {
      // The frame of a stamp: the folder's stamps are its frames' (and unique).
      std::map<double, std::size_t> frame_at;
      for (std::size_t i = 0; i < src.stamps.size(); ++i) frame_at.emplace(src.stamps[i], i);
      session.reconstruction().set_tracker_depth_source(
          [&src, frame_at = std::move(frame_at)](double stamp_s) {
            const auto it = frame_at.find(stamp_s);
            if (it == frame_at.end() || src.tum->frame(it->second).depth_path.empty()) {
              throw std::runtime_error("--tracker-true-depth: no depth image for the frame at " +
                                       std::to_string(stamp_s));
            }
            return src.tum->load_depth(it->second);
          });
    }

    long used = 0, skipped = 0;
    for (size_t i = 0;; ++i) {
      if (max_frames >= 0 && used >= max_frames) break;
      if (!src.is_video && static_cast<long>(i) < first_frame) continue;
      cv::Mat bgr;
      double stamp = 0.0;
      if (src.is_video) {
        if (!src.video.read(bgr)) break;
        if (static_cast<long>(i) < first_frame) continue;
        stamp = static_cast<double>(i) / src.fps;
      } else {
        if (i >= src.paths.size()) break;
        if (i % stride != 0) continue;
        bgr = cv::imread(src.paths[i], cv::IMREAD_COLOR);
        stamp = src.stamps[i];
        if (bgr.empty()) {
          std::fprintf(stderr, "\nlong3r_reconstruct: warning: cannot read %s, skipped\n",
                       src.paths[i].c_str());
          ++skipped;
          continue;
        }
      }
      if (src.is_video && i % stride != 0) continue;
      ++used;
      LiveFrame f;
      f.image = bgr;
      f.encoding = "bgr8";
      f.stamp_s = stamp;
      f.clock_s = stamp;  // recorded data: the stamps are the clock
      if (src.camera) {
        f.camera = src.camera;
        // A calibration without its image size is of these images.
        if (f.camera->width == 0 && f.camera->height == 0) {
          f.camera->width = bgr.cols;
          f.camera->height = bgr.rows;
        }
      }
      f.tag = i;
      session.push(std::move(f));
    }
    session.flush();
    // The maps' updates still running in the background count towards the
    // stream's time (total_ms is the model's thread's).
    const auto settle_start = std::chrono::steady_clock::now();
    session.reconstruction().settle_maps();
    const double settle_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - settle_start)
            .count();
    if (tty) std::printf("\n");
    if (used == 0) throw std::runtime_error("no readable frames in " + input);
    csv.commit();
    if (!save_session.empty()) session.save(save_session);

    const Reconstruction& rec = session.reconstruction();
    const LiveStatus status = session.status();
    rec.map().save((fs::path(out_dir) / "map.ply").string());
    PoseTrajectory traj;
    for (const auto& [t, T] : rec.trajectory()) {
      traj.stamps.push_back(t);
      traj.poses.push_back(T);
    }
    write_tum_trajectory((fs::path(out_dir) / "trajectory.txt").string(), traj,
                         std::string("long3r_reconstruct: T_W_C, world = camera 0, ") +
                             (status.scale_metric ? "metres" : "model units"));

    if (fusion_split) {
      if (!status.scale_metric) {
        throw std::runtime_error("--fusion-split: the scale never became metric (--scale-source)");
      }
      FusionBound bound(cfg.map.voxel_size_m);
      for (const Kept& k : kept) {
        const auto T_W_C = client.given_pose(k.index);
        if (!T_W_C) continue;
        const cv::Mat truth = true_points_at_pixels(
            src.tum->load_depth(k.index), src.tum->camera()->intrinsics, k.K, k.points_C.size());
        bound.add(k.points_C * (status.scale / k.scale), truth, *T_W_C);
      }
      save_point_cloud((fs::path(out_dir) / "averaged.ply").string(), bound.averaged_points());
      save_point_cloud((fs::path(out_dir) / "averaged_rescaled.ply").string(),
                       bound.averaged_points(true));
      const FusionBoundSummary b = bound.summary();
      const nlohmann::json j{{"frames", b.frames},
                             {"pairs", b.pairs},
                             {"voxel_size_m", cfg.map.voxel_size_m},
                             {"voxels", b.voxels},
                             {"mean_views", b.mean_views},
                             {"single_view_error_m", b.single_view_m},
                             {"averaged_error_m", b.averaged_m},
                             {"averaged_rescaled_error_m", b.averaged_rescaled_m},
                             {"depth_ratio_median", b.depth_ratio_median},
                             {"depth_ratio_mad", b.depth_ratio_mad},
                             {"depth_ratio", b.depth_ratio}};
      AtomicFile json((fs::path(out_dir) / "fusion_split.json").string());
      json.write(j.dump(2) + "\n");
      json.commit();
      std::printf(
          "fusion split: %zu frames, %zu voxels seen by %.1f frames on average; per voxel, the "
          "error of one view %.4f m mean (median %.4f), of the views averaged %.4f m (median "
          "%.4f), averaged with each frame's depth ratio divided out %.4f m (median %.4f); depth "
          "ratio over frames median %.4f, MAD %.4f\n",
          b.frames, b.voxels, b.mean_views, b.single_view_m.mean, b.single_view_m.median,
          b.averaged_m.mean, b.averaged_m.median, b.averaged_rescaled_m.mean,
          b.averaged_rescaled_m.median, b.depth_ratio_median, b.depth_ratio_mad);
    }

    if (cfg.surface.enabled) {
      const auto t0 = std::chrono::steady_clock::now();
      const ColoredPoints surface = rec.surface().points();
      const auto t1 = std::chrono::steady_clock::now();
      const ColoredMesh mesh = rec.surface().mesh();
      const auto t2 = std::chrono::steady_clock::now();
      using ms = std::chrono::duration<double, std::milli>;
      save_point_cloud((fs::path(out_dir) / "surface.ply").string(), surface.points,
                       &surface.colors);
      save_mesh_ply((fs::path(out_dir) / "mesh.ply").string(), mesh.vertices, &mesh.colors,
                    mesh.triangles);
      std::printf(
          "surface: %zu points (extracted in %.1f ms), mesh of %zu triangles (%.1f ms), "
          "from %zu frames (%zu no longer kept for rebuilds)\n",
          surface.points.size(), ms(t1 - t0).count(), mesh.triangles.size(), ms(t2 - t1).count(),
          rec.surface().frames_kept(), rec.surface().frames_dropped());
    }

    // The grid needs a z-up frame: the --poses' world (a generated
    // sequence's room, a motion-capture frame), where it is known.
    if (cfg.occupancy.enabled) {
      std::printf("occupancy: %zu voxels known", rec.occupancy().voxels());
      if (const std::optional<Eigen::Isometry3d> T_P_W = client.T_poses_W()) {
        GridBand band;
        const std::optional<double> floor = rec.occupancy().floor_z(*T_P_W);
        band.floor_z_m = floor.value_or(0.0);
        const OccupancyGrid grid = rec.occupancy().project(band, *T_P_W);
        if (grid.width > 0) save_grid_map((fs::path(out_dir) / "grid").string(), grid);
        std::printf("; grid (the --poses' frame, %s %.3f m): %d x %d cells, %zu occupied, %zu free",
                    floor ? "floor fitted at" : "no floor found, z =", band.floor_z_m, grid.width,
                    grid.height, grid.occupied, grid.free);
      }
      std::printf("\n");
    }

    std::vector<double> sorted = frame_ms;
    std::sort(sorted.begin(), sorted.end());
    double sum = 0;
    for (double m : frame_ms) sum += m;
    sum += settle_ms;
    const double mean_fps = frame_ms.empty() || sum <= 0 ? 0 : 1000.0 * frame_ms.size() / sum;
    const double median_ms = sorted.empty() ? 0 : sorted[sorted.size() / 2];
    std::printf(
        "summary: %ld frames used (%ld unreadable skipped), %zu results, %zu with a good pose, "
        "map %zu points\n"
        "         model input %dx%d, mean %.2f FPS, median %.2f FPS, peak RSS %.1f MiB, %s, %s "
        "%s\n"
        "         scale %.6g m per model unit (%s), %llu stream(s)\n"
        "         cpu %s\n"
        "         outputs in %s\n",
        used, skipped, frame_ms.size(), traj.size(), rec.map().size(),
        rec.config().preprocess.width, rec.config().preprocess.height, mean_fps,
        median_ms > 0 ? 1000.0 / median_ms : 0.0, peak_rss / 1024.0, describe(thread_state).c_str(),
        inference.device.c_str(), config::enum_name(inference.precision), status.scale,
        status.scale_metric ? "metric" : "model units",
        static_cast<unsigned long long>(status.streams), describe_cpu().c_str(), out_dir.c_str());
    if (!client.suppressed().empty()) {
      std::printf("warnings not repeated: %s\n", client.suppressed().c_str());
    }
    if (random)
      std::printf("WARNING: the model has RANDOM weights; the results are meaningless.\n");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "long3r_reconstruct: error: %s\n", e.what());
    return 1;
  }
  return 0;
}
