// Streaming reconstruction pipeline (see reconstruction.hpp).
#include "long3r/pipeline/reconstruction.hpp"

#include <ATen/ATen.h>
#include <c10/core/InferenceMode.h>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <tuple>
#include <utility>
#include <vector>

#include "long3r/geometry/statistics.hpp"
#include "long3r/mapping/state_geometry.hpp"
#include "long3r/pipeline/keyframe_state.hpp"
#include "long3r/pipeline/metric_scale.hpp"

namespace long3r {
namespace {

double now_ms() {
  return std::chrono::duration<double, std::milli>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

ReconstructionConfig effective(ReconstructionConfig c, const StreamingModel* model) {
  c.validate({"reconstruction config", ""});
  if (model) {  // a null model is refused by the constructor
    const std::array<int64_t, 2> recorded = model->recorded_input_size();
    c.preprocess =
        c.preprocess.resolved(static_cast<int>(recorded[0]), static_cast<int>(recorded[1]));
  }
  if (c.conf_threshold >= 0.0f) {
    c.pnp.conf_threshold = c.conf_threshold;
    c.map.conf_threshold = c.conf_threshold;
  }
  return c;
}

// A frame's outputs, pointmap [1, H, W, 3] (or [H, W, 3]) and confidence
// [1, H, W] (or [H, W]), on any device: packed there as one [H, W, 4] float32
// tensor, copied to the host in one transfer, and split into a CV_32FC3 and a
// CV_32FC1 cv::Mat (the values bit for bit).
std::pair<cv::Mat, cv::Mat> to_mats(const at::Tensor& pts3d, const at::Tensor& conf, int rows,
                                    int cols) {
  const at::Tensor p = pts3d.dim() == 4 ? pts3d[0] : pts3d;
  const at::Tensor c = conf.dim() == 3 ? conf[0] : conf;
  for (const auto& [t, what] : {std::pair{&p, "pts3d"}, std::pair{&c, "conf"}}) {
    if (t->size(0) != rows || t->size(1) != cols) {
      const bool transposed = t->size(0) == cols && t->size(1) == rows;
      throw std::runtime_error(
          std::string("model output ") + what + " is " + std::to_string(t->size(0)) + "x" +
          std::to_string(t->size(1)) + ", expected " + std::to_string(rows) + "x" +
          std::to_string(cols) +
          (transposed ? " (transposed: portrait input to a landscape-only model; use a landscape "
                        "model input size, width >= height)"
                      : ""));
    }
  }
  const at::Tensor packed =
      at::cat({p.to(at::kFloat), c.to(at::kFloat).unsqueeze(-1)}, -1).to(at::kCPU).contiguous();
  const float* src = packed.data_ptr<float>();
  cv::Mat points(rows, cols, CV_32FC3), confidence(rows, cols, CV_32FC1);
  float* pts_out = points.ptr<float>();
  float* conf_out = confidence.ptr<float>();
  for (int64_t i = 0, n = static_cast<int64_t>(rows) * cols; i < n; ++i) {
    pts_out[3 * i] = src[4 * i];
    pts_out[3 * i + 1] = src[4 * i + 1];
    pts_out[3 * i + 2] = src[4 * i + 2];
    conf_out[i] = src[4 * i + 3];
  }
  return {points, confidence};
}

// The pointmap's rays at its median depth (a constant-depth plane per frame).
cv::Mat at_median_depth(const cv::Mat& points_C) {
  std::vector<double> z;
  for (int i = 0; i < points_C.rows * points_C.cols; ++i) {
    const float d = points_C.at<cv::Vec3f>(i)[2];
    if (std::isfinite(d) && d > 0.0f) z.push_back(d);
  }
  cv::Mat out = points_C.clone();
  if (z.empty()) return out;
  const float depth = static_cast<float>(median(std::move(z)));
  for (int i = 0; i < out.rows * out.cols; ++i) {
    cv::Vec3f& p = out.at<cv::Vec3f>(i);
    if (std::isfinite(p[2]) && p[2] > 0.0f) p *= depth / p[2];
  }
  return out;
}

// The pointmap's rays at the given depths (CV_32FC1 at its pixels; NaN
// where a depth is missing or the ray does not point forward).
cv::Mat at_depth(const cv::Mat& points_C, const cv::Mat& depth) {
  cv::Mat out(points_C.size(), CV_32FC3);
  for (int i = 0; i < out.rows * out.cols; ++i) {
    const cv::Vec3f p = points_C.at<cv::Vec3f>(i);
    const float d = depth.at<float>(i);
    out.at<cv::Vec3f>(i) = std::isfinite(p[2]) && p[2] > 0.0f && std::isfinite(d) && d > 0.0f
                               ? p * (d / p[2])
                               : cv::Vec3f::all(std::numeric_limits<float>::quiet_NaN());
  }
  return out;
}

// A depth image's depth is taken for a pixel only within this factor of the
// model's depth there (at the frame's depth ratio): the model's depth errs
// by some 10 % about the frame's middle, while a sensor's invalid readings
// (multipath, garbage, a hostile message's huge values) can be anything.
constexpr float kMaxDepthImageFactor = 2.0f;

// The pointmap at the given depths where they are valid and plausible, and
// scaled by `scale` elsewhere.
cv::Mat at_depth_or_scaled(const cv::Mat& points_C, const cv::Mat& depth, double scale) {
  cv::Mat out(points_C.size(), CV_32FC3);
  const float s = static_cast<float>(scale);
  for (int i = 0; i < out.rows * out.cols; ++i) {
    const cv::Vec3f p = points_C.at<cv::Vec3f>(i);
    const float d = depth.at<float>(i), expected = p[2] * s;
    const bool take = std::isfinite(p[2]) && p[2] > 0.0f && std::isfinite(d) && d > 0.0f &&
                      d <= kMaxDepthImageFactor * expected && d * kMaxDepthImageFactor >= expected;
    out.at<cv::Vec3f>(i) = take ? p * (d / p[2]) : p * s;
  }
  return out;
}

}  // namespace

void ReconstructionConfig::validate(const config::FieldCheck& check) const {
  check.require(std::isfinite(conf_threshold) && (conf_threshold < 0.0f || conf_threshold >= 1.0f),
                "conf_threshold",
                "must be >= 1 (the model's confidence starts at 1), or negative to keep pnp's "
                "and map's own");
  config::validate_nested(*this, check);
}

bool has_random_weights(const std::map<std::string, std::string>& metadata) {
  const auto it = metadata.find(kRandomWeightsMetadataKey);
  return it != metadata.end() && it->second == "true";
}

Reconstruction::Reconstruction(std::unique_ptr<StreamingModel> model,
                               const ReconstructionConfig& config)
    : model_(std::move(model)),
      config_(effective(config, model_.get())),
      tracker_(config_.pnp),
      keyframes_(config_.tracker),
      baseline_scale_(config_.tracker),
      map_(config_.map),
      surface_(config_.surface),
      occupancy_(config_.occupancy) {
  if (!model_) throw std::invalid_argument("Reconstruction: null model");
  if (config_.maps_in_background && (config_.surface.enabled || config_.occupancy.enabled)) {
    map_worker_ = std::make_unique<SerialWorker>(2);
  }
  // A landscape-only Spann3R returns portrait maps transposed on a scrambled
  // token grid (as the official model does); refuse rather than mislead.
  if (config_.preprocess.height > config_.preprocess.width && !model_->accepts_portrait()) {
    throw std::invalid_argument("Reconstruction: portrait model input (" +
                                std::to_string(config_.preprocess.width) + "x" +
                                std::to_string(config_.preprocess.height) +
                                ") with a landscape-only Spann3R model; use width >= height");
  }
}

Reconstruction::~Reconstruction() = default;

void Reconstruction::settle_maps() const {
  if (map_worker_) map_worker_->wait_idle();
}

const SurfaceMap& Reconstruction::surface() const {
  settle_maps();
  return surface_;
}

const OccupancyMap& Reconstruction::occupancy() const {
  settle_maps();
  return occupancy_;
}

void Reconstruction::set_calibration(const std::optional<PinholeIntrinsics>& calib) {
  if (calib && !calib->valid()) {
    throw std::invalid_argument("set_calibration: fx and fy must be positive");
  }
  calibration_ = calib;
  if (calib) {
    intrinsics_.reset();  // re-scaled from the calibration at the next result
    intrinsics_failed_ = false;
  }
}

void Reconstruction::reset() {
  model_->reset();
  pending_.clear();
  intrinsics_.reset();
  intrinsics_failed_ = false;
  tracker_.reset();
  keyframes_.reset();
  baseline_scale_.reset();
  placed_.clear();
  map_.clear();
  settle_maps();
  surface_.clear();
  occupancy_.clear();
  trajectory_.clear();
  trajectory_given_.clear();
  frames_pushed_ = 0;
  source_width_ = source_height_ = 0;
  flushed_index_ = -1;
  scale_ = 1.0;
}

void Reconstruction::set_scale(double scale) {
  if (!(scale > 0.0) || !std::isfinite(scale)) {
    throw std::invalid_argument("Reconstruction::set_scale: the scale must be positive and finite");
  }
  const double factor = scale / scale_;
  if (factor == 1.0) return;
  map_.rescale(factor);
  settle_maps();
  surface_.rescale(factor);
  occupancy_.rescale(factor);
  // Given poses are the caller's (odometry: metres), not the model's.
  for (std::size_t i = 0; i < trajectory_.size(); ++i) {
    if (!trajectory_given_[i]) trajectory_[i].second.translation() *= factor;
  }
  tracker_.rescale(factor);
  keyframes_.rescale(factor);
  for (Placed& p : placed_) {
    p.T_W_C.translation() *= factor;
    p.model_T_W_C.translation() *= factor;
  }
  scale_ = scale;
}

void Reconstruction::rescale(FrameResult& r, double scale) {
  const double factor = scale / r.scale;
  if (factor == 1.0) return;
  // Into new buffers: a copied FrameResult shares its images with the original.
  for (cv::Mat* points : {&r.points_W, &r.points_C}) {
    cv::Mat scaled;
    if (!points->empty()) points->convertTo(scaled, CV_32FC3, factor);
    *points = scaled;
  }
  if (r.pose_given) {  // the caller's pose stays; the points it places are rescaled
    if (!r.points_C.empty()) r.points_W = transform_points(r.points_C, r.pose.T_W_C);
  } else {
    r.pose.T_W_C.translation() *= factor;
  }
  r.model_T_W_C.translation() *= factor;
  if (r.pose.covariance) {  // translation rows and columns of [t, r]
    Eigen::Matrix<double, 6, 6>& c = *r.pose.covariance;
    c.topLeftCorner<3, 3>() *= factor * factor;
    c.topRightCorner<3, 3>() *= factor;
    c.bottomLeftCorner<3, 3>() *= factor;
  }
  r.scale = scale;
}

std::unique_ptr<SurfaceMap> Reconstruction::take_surface() {
  auto taken = std::make_unique<SurfaceMap>(config_.surface);
  settle_maps();
  taken->swap(surface_);
  return taken;
}

StateDict Reconstruction::state() const {
  const bool lone_first = frames_pushed_ == 1 && pending_.size() == 1;
  if (!pending_.empty() && !lone_first) {
    throw std::logic_error("Reconstruction::state: a frame waits for its result; flush() first");
  }
  StateDict out;
  if (lone_first || frames_pushed_ == 0) {
    put_int(out, "frames_pushed", 0);
    put_int(out, "model.frames", 0);
    put_real(out, "scale", scale_);
    return out;
  }
  put_int(out, "frames_pushed", frames_pushed_);
  put_int(out, "source_width", source_width_);
  put_int(out, "source_height", source_height_);
  put_int(out, "flushed_index", flushed_index_);
  put_real(out, "scale", scale_);
  put_int(out, "intrinsics_failed", intrinsics_failed_ ? 1 : 0);
  if (calibration_) out["calibration"] = intrinsics_to_tensor(*calibration_);
  if (intrinsics_) {
    out["intrinsics"] = intrinsics_to_tensor(intrinsics_->intrinsics);
    put_int(out, "intrinsics.source", static_cast<int64_t>(intrinsics_->source));
  }
  const PoseTracker::State tracker = tracker_.state();
  out["tracker.last_good"] = pose_to_tensor(tracker.last_good);
  put_int(out, "tracker.has_good", tracker.has_good ? 1 : 0);
  put_int(out, "tracker.consecutive_failures", tracker.consecutive_failures);

  const int64_t n = static_cast<int64_t>(trajectory_.size());
  at::Tensor stamps = at::empty({n}, at::kDouble), poses = at::empty({n, 4, 4}, at::kDouble);
  for (int64_t i = 0; i < n; ++i) {
    const auto& [stamp, T_W_C] = trajectory_[static_cast<std::size_t>(i)];
    stamps.data_ptr<double>()[i] = stamp;
    Eigen::Map<Eigen::Matrix<double, 4, 4, Eigen::RowMajor>>(poses.data_ptr<double>() + 16 * i) =
        T_W_C.matrix();
  }
  out["trajectory.stamp"] = stamps;
  out["trajectory.T_W_C"] = poses;
  at::Tensor given = at::empty({n}, at::kLong);
  for (int64_t i = 0; i < n; ++i) {
    given.data_ptr<int64_t>()[i] = trajectory_given_[static_cast<std::size_t>(i)] ? 1 : 0;
  }
  out["trajectory.given"] = given;

  if (config_.pose_method == PoseMethod::kKeyframes) {
    put_keyframes(out, "keyframes.", keyframes_.kept());
  }
  put_state(out, "map.", map_.state());
  settle_maps();
  if (config_.occupancy.enabled) out["occupancy.ot"] = bytes_tensor(occupancy_.write());
  if (config_.surface.enabled) put_state(out, "surface.", surface_.state());
  put_state(out, "model.", model_->stream_state());
  return out;
}

void Reconstruction::restore(const StateDict& state) {
  const StateReader r(state, "saved reconstruction");
  constexpr int64_t kMax = int64_t{1} << 53;
  const int64_t frames = r.integer("frames_pushed", 0, kMax);
  const double scale = r.real("scale");
  if (!(scale > 0.0) || !std::isfinite(scale)) r.fail("scale", "must be positive and finite");
  const StateDict model_state = sub_state(state, "model.");
  if (frames == 0) {
    if (r.integer("model.frames", 0, kMax) != 0) {
      r.fail("model.frames", "a model stream without frames pushed");
    }
    reset();
    set_scale(scale);
    return;
  }
  const int width = static_cast<int>(r.integer("source_width", 1, 1 << 16));
  const int height = static_cast<int>(r.integer("source_height", 1, 1 << 16));
  const int64_t flushed = r.integer("flushed_index", -1, frames - 1);
  const bool intrinsics_failed = r.integer("intrinsics_failed", 0, 1) == 1;
  std::optional<PinholeIntrinsics> calibration;
  if (r.has("calibration")) calibration = read_intrinsics(r, "calibration");
  std::optional<ResolvedIntrinsics> intrinsics;
  if (r.has("intrinsics")) {
    intrinsics = ResolvedIntrinsics{
        read_intrinsics(r, "intrinsics"),
        static_cast<IntrinsicsSource>(r.integer(
            "intrinsics.source", 0, static_cast<int64_t>(IntrinsicsSource::kEstimatedWeiszfeld)))};
  }
  PoseTracker::State tracker;
  tracker.last_good = read_pose(r, "tracker.last_good");
  tracker.has_good = r.integer("tracker.has_good", 0, 1) == 1;
  tracker.consecutive_failures = r.integer("tracker.consecutive_failures", 0, kMax);

  const at::Tensor stamps = r.floating("trajectory.stamp", {-1}).to(at::kDouble).contiguous();
  const int64_t n = stamps.size(0);
  const at::Tensor poses = r.floating("trajectory.T_W_C", {n, 4, 4});
  std::vector<std::pair<double, Eigen::Isometry3d>> trajectory;
  trajectory.reserve(static_cast<std::size_t>(n));
  for (int64_t i = 0; i < n; ++i) {
    const std::optional<Eigen::Isometry3d> T = pose_from_tensor(poses[i]);
    if (!T) r.fail("trajectory.T_W_C[" + std::to_string(i) + "]", "not a rigid transform");
    trajectory.emplace_back(stamps.data_ptr<double>()[i], *T);
  }
  std::vector<bool> trajectory_given(static_cast<std::size_t>(n), false);
  if (r.has("trajectory.given")) {  // absent: every pose the model's
    const at::Tensor given = r.int64("trajectory.given", {n}).contiguous();
    for (int64_t i = 0; i < n; ++i) {
      const int64_t g = given.data_ptr<int64_t>()[i];
      if (g != 0 && g != 1) r.fail("trajectory.given", "not 0 or 1");
      trajectory_given[static_cast<std::size_t>(i)] = g == 1;
    }
  }

  const int64_t model_frames = r.integer("model.frames", 0, kMax);
  if (model_frames != frames) {
    r.fail("model.frames", "the model's stream has " + std::to_string(model_frames) +
                               " frames, the reconstruction " + std::to_string(frames));
  }
  // The model and the map validate their own parts; the model's is undone
  // if the map then refuses its part.
  // The occupancy, where the session has one (sessions saved before it, or
  // with it off, have none: it starts empty), is read before anything changes.
  OccupancyMap occupancy(config_.occupancy);
  if (config_.occupancy.enabled && r.has("occupancy.ot")) occupancy.restore(r, "occupancy.ot");
  // So is the surface (rebuilt from its kept frames); sessions without one
  // start it empty.
  SurfaceMap surface(config_.surface);
  if (config_.surface.enabled && r.has("surface.frames")) surface.restore(r.child("surface."));
  // The kept keyframes, where the session has them (sessions saved before
  // them, or with pose_method model, have none: the next frame starts a
  // keyframe where the model puts it).
  std::vector<KeptKeyframe> kept;
  if (r.has("keyframes.version")) kept = read_keyframes(r.child("keyframes."));
  const StateDict previous = model_->stream_state();
  model_->restore_stream_state(model_state);
  try {
    map_.restore(r.child("map."));
  } catch (const StateError&) {
    model_->restore_stream_state(previous);
    throw;
  }
  settle_maps();
  occupancy_.swap(occupancy);
  pending_.clear();
  frames_pushed_ = frames;
  source_width_ = width;
  source_height_ = height;
  flushed_index_ = flushed;
  scale_ = scale;
  calibration_ = calibration;
  intrinsics_ = intrinsics;
  intrinsics_failed_ = intrinsics_failed;
  tracker_.restore(tracker);
  trajectory_ = std::move(trajectory);
  trajectory_given_ = std::move(trajectory_given);
  surface_.swap(surface);
  keyframes_.restore(std::move(kept));
  placed_.clear();
}

std::optional<FrameResult> Reconstruction::push(const cv::Mat& image, const std::string& encoding,
                                                double stamp_s,
                                                const std::optional<Eigen::Isometry3d>& T_W_C) {
  const double t0 = now_ms();
  const ImageEncoding enc = parse_image_encoding(encoding);  // throws invalid_argument
  if (image.empty()) throw std::invalid_argument("Reconstruction::push: empty image");
  if (frames_pushed_ > 0 && (image.cols != source_width_ || image.rows != source_height_)) {
    throw std::invalid_argument(
        "Reconstruction::push: image size changed within a stream (" +
        std::to_string(source_width_) + "x" + std::to_string(source_height_) + " -> " +
        std::to_string(image.cols) + "x" + std::to_string(image.rows) + "); call reset() first");
  }
  Pending p;
  p.image = preprocess_image(image, enc, config_.preprocess);
  p.index = frames_pushed_;
  p.stamp = stamp_s;
  p.T_W_C = T_W_C;
  if (config_.pose_method == PoseMethod::kKeyframes || (config_.scale_from_given_poses && T_W_C)) {
    // Straight from the source encoding (the same weights as through RGB).
    switch (enc) {
      case ImageEncoding::kMono8:
        p.gray = image.clone();
        break;
      case ImageEncoding::kRgb8:
        cv::cvtColor(image, p.gray, cv::COLOR_RGB2GRAY);
        break;
      case ImageEncoding::kBgr8:
        cv::cvtColor(image, p.gray, cv::COLOR_BGR2GRAY);
        break;
      case ImageEncoding::kRgba8:
        cv::cvtColor(image, p.gray, cv::COLOR_RGBA2GRAY);
        break;
      case ImageEncoding::kBgra8:
        cv::cvtColor(image, p.gray, cv::COLOR_BGRA2GRAY);
        break;
      case ImageEncoding::kMono16:  // scaled to 8 bits as the model's input is
        p.gray = to_rgb8(image, enc, config_.preprocess.mono16);
        cv::cvtColor(p.gray, p.gray, cv::COLOR_RGB2GRAY);
        break;
    }
  }
  const int h = p.image.height, w = p.image.width;
  // The tensor takes over the chw buffer: no copy, and it lives as long as
  // the model keeps the input.
  auto* buffer = new std::vector<float>(std::move(p.image.chw));
  const at::Tensor input = at::from_blob(
      buffer->data(), {1, 3, h, w}, [buffer](void*) { delete buffer; },
      at::TensorOptions().dtype(at::kFloat));
  p.preprocess_ms = now_ms() - t0;

  const double t_model = now_ms();
  std::optional<StreamOutput> out;
  {
    c10::InferenceMode guard;
    out = model_->push(input);
  }
  const double model_ms = now_ms() - t_model;
  source_width_ = image.cols;
  source_height_ = image.rows;
  ++frames_pushed_;
  pending_.push_back(std::move(p));
  if (!out || out->frame_index == flushed_index_) return std::nullopt;
  return finish(*out, t_model, model_ms);
}

std::optional<FrameResult> Reconstruction::flush() {
  if (pending_.empty()) return std::nullopt;
  const double t_model = now_ms();
  std::optional<StreamOutput> out;
  {
    c10::InferenceMode guard;
    out = model_->peek_last();
  }
  const double model_ms = now_ms() - t_model;
  if (!out) return std::nullopt;  // e.g. a single frame: it comes with the next one
  FrameResult r = finish(*out, t_model, model_ms);
  r.from_coarse_head = true;
  flushed_index_ = r.frame_index;
  return r;
}

Eigen::Matrix3d Reconstruction::source_camera_matrix(const PixelMapping& model_to_source) const {
  // The calibration is the source image's own; an estimate is at model
  // resolution and maps through the resize and crop.
  Eigen::Matrix3d K = Eigen::Matrix3d::Identity();
  if (calibration_) {
    K << calibration_->fx, 0, calibration_->cx, 0, calibration_->fy, calibration_->cy, 0, 0, 1;
    return K;
  }
  const PinholeIntrinsics& m = intrinsics_->intrinsics;
  K << m.fx, 0, m.cx, 0, m.fy, m.cy, 0, 0, 1;
  return model_to_source.matrix() * K;
}

Eigen::Isometry3d Reconstruction::tracker_prior(int64_t frame_index,
                                                const Eigen::Isometry3d& model_T_W_C,
                                                const std::optional<OdometryPose>& odometry) const {
  if (placed_.empty()) return model_T_W_C;
  const Placed& last = placed_.back();
  if (config_.tracker.motion_prior == MotionPrior::kModel) {
    // The model's motion since the last frame, from where that frame went
    // (the model's own world would jump).
    return last.T_W_C * last.model_T_W_C.inverse() * model_T_W_C;
  }
  // The velocity is what the images measured: between the last two frames
  // they placed. Before there are two, the frames stay where the last one
  // went: continuing the model's own motion instead would carry its
  // registration error on (a stream whose first frames have too few
  // features travelled eight times too far).
  Eigen::Isometry3d motion = Eigen::Isometry3d::Identity();
  std::vector<const Placed*> by_images;
  for (const Placed& p : placed_) {
    if (p.by_images) by_images.push_back(&p);
  }
  if (by_images.size() >= 2) {
    const Placed& a = *by_images[by_images.size() - 2];
    const Placed& b = *by_images.back();
    // The last measured step's motion per frame, continued for the frames
    // since the last placed one.
    const Eigen::Isometry3d step = a.T_W_C.inverse() * b.T_W_C;
    const double f = static_cast<double>(frame_index - last.frame_index) /
                     static_cast<double>(b.frame_index - a.frame_index);
    const Eigen::AngleAxisd rotation(step.rotation());
    motion.linear() = Eigen::AngleAxisd(rotation.angle() * f, rotation.axis()).toRotationMatrix();
    motion.translation() = step.translation() * f;
  }
  if (config_.tracker.motion_prior == MotionPrior::kOdometry && odometry && last.T_O_C) {
    // The camera's motion as the odometry measured it; its length only in a
    // metric stream (the model's units have no known relation to metres).
    const Eigen::Isometry3d step = last.T_O_C->inverse() * odometry->T_O_C;
    motion.linear() = step.linear();
    if (odometry->metric) motion.translation() = step.translation();
  }
  return last.T_W_C * motion;
}

void Reconstruction::remember_placed(const Placed& placed) {
  placed_.push_back(placed);
  // Kept: the last placed frame and the last two the images placed.
  int by_images = placed.by_images ? 1 : 0;
  for (auto it = placed_.end() - 1; it != placed_.begin();) {
    --it;
    if (it->by_images && ++by_images <= 2) continue;
    it = placed_.erase(it);
  }
}

FrameResult Reconstruction::finish(const StreamOutput& out, double call_start_ms, double model_ms) {
  if (pending_.empty() || pending_.front().index != out.frame_index) {
    throw std::logic_error("Reconstruction: model returned frame " +
                           std::to_string(out.frame_index) + " out of order");
  }
  Pending p = std::move(pending_.front());
  pending_.pop_front();
  const int h = p.image.height, w = p.image.width;

  FrameResult r;
  r.frame_index = p.index;
  r.stamp = p.stamp;
  r.from_coarse_head = out.from_coarse_head;
  std::tie(r.points_W, r.conf) = to_mats(out.pts3d, out.conf, h, w);
  if (scale_ != 1.0) r.points_W.convertTo(r.points_W, CV_32FC3, scale_);
  r.scale = scale_;
  r.rgb = p.image.rgb;
  r.timings.preprocess_ms = p.preprocess_ms;
  r.timings.model_ms = model_ms;
  r.model = out.stats;

  // PinholeIntrinsics: calibration at any frame; an estimate only from frame 0,
  // whose pointmap is in its own camera frame.
  double t = now_ms();
  if (!intrinsics_ && !intrinsics_failed_ && (calibration_ || p.index == 0)) {
    intrinsics_ = resolve_intrinsics(calibration_, p.image, r.points_W, r.conf, config_.focal);
    intrinsics_failed_ = !intrinsics_.has_value();
  }
  r.timings.intrinsics_ms = now_ms() - t;

  t = now_ms();
  if (intrinsics_) {
    r.intrinsics = intrinsics_->intrinsics;
    r.intrinsics_source = intrinsics_->source;
  }
  if (p.index == 0) {
    r.pose.status = PnpStatus::kOk;  // defines the world frame
    r.pose.T_W_C = Eigen::Isometry3d::Identity();
    if (intrinsics_) {
      r.pose.covariance =
          pose_covariance(r.points_W, r.conf, r.intrinsics, r.pose.T_W_C, tracker_.config());
    }
  } else if (intrinsics_) {
    r.pose = tracker_.track(r.points_W, r.conf, r.intrinsics);
  } else {
    r.pose.status = PnpStatus::kSolverFailed;
    r.pose.message = "no intrinsics: no calibration and the focal estimate on frame 0 failed";
    r.pose.T_W_C = tracker_.last_good_pose();
  }
  r.model_T_W_C = r.pose.T_W_C;
  if (r.pose.ok()) r.points_C = points_in_camera(r.points_W, r.pose.T_W_C);
  // The keyframe tracker: the frame's shape as its PnP pose sees it, placed
  // by the images' correspondences with the keyframe (a given pose wins).
  // A frame whose model pose failed has no depth in its own camera frame to
  // track with; the next frames are tracked against the keyframe as before
  // (an isolated failure must not lose a stream the images still place), or,
  // where lost frames relocalise (a cut to another scene), relocalised.
  if (config_.pose_method == PoseMethod::kKeyframes && !p.T_W_C && !r.pose.ok() &&
      config_.tracker.when_lost == WhenLost::kRelocalise) {
    keyframes_.lose();
  }
  if (config_.pose_method == PoseMethod::kKeyframes && !p.T_W_C && r.pose.ok() && intrinsics_) {
    TrackerFrame frame;
    frame.gray = p.gray;
    frame.K = source_camera_matrix(p.image.model_to_source);
    // A depth camera's depth, where one is given for the frame and covers
    // enough of it, replaces the model's (and the constant-depth control).
    std::optional<double> depth_ratio;  // the depth image's over the model's, at this frame
    cv::Mat measured;                   // the depth image at the model's pixels
    if (tracker_depth_source_) {
      const cv::Mat metres = tracker_depth_source_(p.stamp);
      if (!metres.empty() && (metres.cols != source_width_ || metres.rows != source_height_)) {
        throw std::invalid_argument(
            "a depth image for the tracker of " + std::to_string(metres.cols) + "x" +
            std::to_string(metres.rows) + " is not registered to the " +
            std::to_string(source_width_) + "x" + std::to_string(source_height_) + " image");
      }
      if (!metres.empty()) {
        measured = depth_at_model_pixels(metres, p.image.model_to_source, r.points_C.cols,
                                         r.points_C.rows);
        std::vector<cv::Mat> xyz;
        cv::split(r.points_C, xyz);
        depth_ratio = depth_scale_sample(xyz[2], measured, r.conf, config_.map.conf_threshold);
        if (depth_ratio) {
          frame.points_C = at_depth(r.points_C, measured);
          frame.depth = metres;
        }
      }
    }
    if (!depth_ratio) {
      frame.points_C = config_.tracker_constant_depth ? at_median_depth(r.points_C) : r.points_C;
    }
    frame.model_to_image = p.image.model_to_source.matrix();
    std::optional<OdometryPose> odometry;
    if (config_.tracker.motion_prior == MotionPrior::kOdometry && odometry_source_) {
      odometry = odometry_source_(p.stamp);
      if (odometry) r.T_O_C = odometry->T_O_C;
    }
    const Eigen::Isometry3d prior = tracker_prior(r.frame_index, r.model_T_W_C, odometry);
    const double t_tracking = now_ms();
    r.tracking = keyframes_.track(frame, prior);
    r.timings.tracking_ms = now_ms() - t_tracking;
    if (r.tracking->status == TrackStatus::kRefused || r.tracking->status == TrackStatus::kLost) {
      // Relocalising (or lost, relocalising from the next frame), and the
      // images do not say where: not posed, not mapped, and the path does
      // not jump.
      r.pose.status = PnpStatus::kNotRelocalised;
      r.pose.message = (r.tracking->status == TrackStatus::kLost ? "tracking lost: "
                                                                 : "relocalisation refused: ") +
                       r.tracking->message;
      r.pose.T_W_C = placed_.empty() ? r.model_T_W_C : placed_.back().T_W_C;
      r.points_C = cv::Mat();
    } else {
      r.pose.T_W_C = r.tracking->posed() ? r.tracking->T_W_C : prior;
      // A keyframe made after lost frames sits at the prior, but the next
      // tracked frame's step from it is measured.
      remember_placed({r.frame_index, r.pose.T_W_C, r.model_T_W_C,
                       r.tracking->posed() || r.tracking->new_keyframe, r.T_O_C});
      // The frame's points in the stream's scale: by its depth image where
      // it has one (its depth itself, with kPoints), else by the tracker's Sim(3).
      if (depth_ratio && depth_image_use_ == DepthImageUse::kPoints) {
        r.points_C = at_depth_or_scaled(r.points_C, measured, *depth_ratio);
      } else {
        const double scale = depth_ratio ? *depth_ratio : r.tracking->scale;
        if (scale != 1.0) r.points_C *= scale;
      }
      r.points_W = transform_points(r.points_C, r.pose.T_W_C);
    }
  }
  if (p.T_W_C && config_.scale_from_given_poses && r.pose.ok() && intrinsics_) {
    // The scale of the model's depth over the given poses' baseline.
    TrackerFrame frame;
    frame.gray = p.gray;
    frame.K = source_camera_matrix(p.image.model_to_source);
    frame.points_C = r.points_C / scale_;  // model units
    frame.model_to_image = p.image.model_to_source.matrix();
    r.baseline_scale = baseline_scale_.add(frame, *p.T_W_C);
  }
  if (p.T_W_C) {  // placed by the given pose, whether PnP found the model's or not
    r.pose_given = true;
    r.pose.T_W_C = *p.T_W_C;
    if (r.pose.ok()) r.points_W = transform_points(r.points_C, r.pose.T_W_C);
  }
  r.timings.pose_ms = now_ms() - t;

  t = now_ms();
  if (r.pose.ok() && mapping_) {  // only with points_C, which PnP's pose gives
    map_.integrate(r.points_W, r.conf, r.rgb, r.frame_index);
    // A job on the map thread gets copies of what it reads (the caller owns
    // r), and only of what the enabled maps read.
    const bool surface = config_.surface.enabled, occupancy = config_.occupancy.enabled;
    auto held = [&](const cv::Mat& m, bool needed) {
      return !needed ? cv::Mat() : map_worker_ ? m.clone() : m;
    };
    auto update = [this, surface, occupancy, points_C = held(r.points_C, surface),
                   rgb = held(r.rgb, surface), points_W = held(r.points_W, occupancy),
                   conf = held(r.conf, true), intrinsics = r.intrinsics, T_W_C = r.pose.T_W_C] {
      const float threshold = config_.map.conf_threshold;
      if (surface) surface_.integrate(points_C, rgb, conf, threshold, intrinsics, T_W_C);
      if (occupancy) occupancy_.insert(points_W, conf, threshold, T_W_C.translation());
    };
    if (map_worker_) {
      map_worker_->post(std::move(update));
    } else {
      update();
    }
    r.added_to_map = true;
  }
  if (r.posed()) {
    trajectory_.emplace_back(r.stamp, r.pose.T_W_C);
    trajectory_given_.push_back(r.pose_given);
  }
  r.map_points = map_.size();
  r.timings.map_ms = now_ms() - t;
  r.timings.total_ms = p.preprocess_ms + (now_ms() - call_start_ms);
  return r;
}

}  // namespace long3r
