// Training data: sequence sampling from generated scenes and TUM folders,
// augmentation, and ground-truth pointmaps in camera 0's frame.
#include <ATen/ATen.h>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "long3r/train/train.hpp"

namespace long3r {

namespace {

// Portable draws (the standard's distributions are implementation-defined,
// which would make a resumed run depend on the standard library).
double uniform01(std::mt19937_64& rng) {
  return static_cast<double>(rng() >> 11) * (1.0 / 9007199254740992.0);
}
int64_t uniform_int(std::mt19937_64& rng, int64_t lo, int64_t hi) {
  if (hi <= lo) return lo;
  return lo + static_cast<int64_t>(rng() % static_cast<uint64_t>(hi - lo + 1));
}

// Brightness, contrast and saturation factors in [1 - j, 1 + j] on linear
// [0, 1] RGB (CV_32FC3), in place.
void colour_jitter(cv::Mat& rgb, double j, std::mt19937_64& rng) {
  const double b = 1.0 + (2.0 * uniform01(rng) - 1.0) * j;
  const double c = 1.0 + (2.0 * uniform01(rng) - 1.0) * j;
  const double s = 1.0 + (2.0 * uniform01(rng) - 1.0) * j;
  rgb *= b;
  cv::Mat grey;
  cv::cvtColor(rgb, grey, cv::COLOR_RGB2GRAY);
  const double mean = cv::mean(grey)[0];
  rgb = (rgb - cv::Scalar::all(mean)) * c + cv::Scalar::all(mean);
  cv::cvtColor(rgb, grey, cv::COLOR_RGB2GRAY);
  cv::Mat grey3;
  cv::cvtColor(grey, grey3, cv::COLOR_GRAY2RGB);
  rgb = grey3 + (rgb - grey3) * s;
  cv::min(cv::max(rgb, 0.0), 1.0, rgb);
}

at::Tensor rgb_float_to_input(const cv::Mat& rgb) {
  cv::Mat cont = rgb.isContinuous() ? rgb : rgb.clone();
  at::Tensor t = at::from_blob(cont.data, {cont.rows, cont.cols, 3}, at::kFloat).clone();
  return t.permute({2, 0, 1}).contiguous().sub_(0.5).div_(0.5);
}

}  // namespace

PinholeIntrinsics crop_resize_intrinsics(const PinholeIntrinsics& k, int x0, int y0, int w, int h,
                                         int out_w, int out_h) {
  const double sx = static_cast<double>(out_w) / w, sy = static_cast<double>(out_h) / h;
  PinholeIntrinsics r;
  r.fx = k.fx * sx;
  r.fy = k.fy * sy;
  // cv::resize aligns pixel centres: dst = (src - x0 + 0.5) * s - 0.5.
  r.cx = (k.cx - x0 + 0.5) * sx - 0.5;
  r.cy = (k.cy - y0 + 0.5) * sy - 0.5;
  r.width = out_w;
  r.height = out_h;
  return r;
}

at::Tensor depth_to_pointmap(const cv::Mat& depth, const PinholeIntrinsics& k,
                             const Eigen::Isometry3d& T_C0_C, at::Tensor* valid) {
  if (depth.type() != CV_32FC1) throw std::invalid_argument("depth_to_pointmap: need CV_32FC1");
  if (!k.valid()) throw std::invalid_argument("depth_to_pointmap: invalid intrinsics");
  const int H = depth.rows, W = depth.cols;
  at::Tensor pts = at::zeros({H, W, 3}, at::kFloat);
  at::Tensor mask = at::zeros({H, W}, at::kBool);
  float* p = pts.data_ptr<float>();
  bool* m = mask.data_ptr<bool>();
  const Eigen::Matrix3d R = T_C0_C.linear();
  const Eigen::Vector3d t = T_C0_C.translation();
  for (int v = 0; v < H; ++v) {
    const float* row = depth.ptr<float>(v);
    for (int u = 0; u < W; ++u) {
      const double z = row[u];
      if (!(z > 0.0) || !std::isfinite(z)) continue;
      const Eigen::Vector3d X = R * k.backproject(u, v, z) + t;
      const std::size_t i = static_cast<std::size_t>(v) * W + u;
      p[3 * i] = static_cast<float>(X.x());
      p[3 * i + 1] = static_cast<float>(X.y());
      p[3 * i + 2] = static_cast<float>(X.z());
      m[i] = true;
    }
  }
  if (valid != nullptr) *valid = mask;
  return pts;
}

at::Tensor bgr_to_model_input(const cv::Mat& bgr) {
  if (bgr.type() != CV_8UC3) throw std::invalid_argument("bgr_to_model_input: need CV_8UC3");
  cv::Mat rgb;
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  rgb.convertTo(rgb, CV_32FC3, 1.0 / 255.0);
  return rgb_float_to_input(rgb);
}

SequenceSample prepare_sequence(const std::vector<RawFrame>& frames, int size,
                                const AugmentConfig& augment, std::mt19937_64* rng,
                                const std::string& source) {
  if (frames.empty()) throw std::invalid_argument("prepare_sequence: no frames");
  const int w = frames[0].bgr.cols, h = frames[0].bgr.rows;
  // One crop for the whole sequence, so that every frame keeps one camera.
  const int base = std::min(w, h);
  const double shrink = rng != nullptr ? uniform01(*rng) * augment.max_crop : 0.0;
  const int side = std::max(1, static_cast<int>(std::lround(base * (1.0 - shrink))));
  int x0 = (w - side) / 2, y0 = (h - side) / 2;
  if (rng != nullptr) {
    x0 = static_cast<int>(uniform_int(*rng, 0, w - side));
    y0 = static_cast<int>(uniform_int(*rng, 0, h - side));
  }
  const cv::Rect roi(x0, y0, side, side);
  SequenceSample s;
  s.source = source;
  const int N = static_cast<int>(frames.size());
  s.pts = at::empty({N, size, size, 3}, at::kFloat);
  s.valid = at::empty({N, size, size}, at::kBool);
  const Eigen::Isometry3d T_C0_W = frames[0].T_W_C.inverse();
  for (int i = 0; i < N; ++i) {
    const RawFrame& f = frames[static_cast<std::size_t>(i)];
    if (f.bgr.cols != w || f.bgr.rows != h || f.depth.size() != f.bgr.size()) {
      throw std::invalid_argument("prepare_sequence: frames of one sequence need one size");
    }
    cv::Mat bgr, depth;
    cv::resize(f.bgr(roi), bgr, cv::Size(size, size), 0, 0,
               side > size ? cv::INTER_AREA : cv::INTER_LINEAR);
    // Nearest: no depth mixed across object boundaries.
    cv::resize(f.depth(roi), depth, cv::Size(size, size), 0, 0, cv::INTER_NEAREST);
    cv::Mat rgb;
    cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
    rgb.convertTo(rgb, CV_32FC3, 1.0 / 255.0);
    if (rng != nullptr && augment.color_jitter > 0.0)
      colour_jitter(rgb, augment.color_jitter, *rng);
    s.images.push_back(rgb_float_to_input(rgb));
    const PinholeIntrinsics k =
        crop_resize_intrinsics(f.intrinsics, x0, y0, side, side, size, size);
    const Eigen::Isometry3d T = T_C0_W * f.T_W_C;
    at::Tensor valid;
    s.pts[i].copy_(depth_to_pointmap(depth, k, T, &valid));
    s.valid[i].copy_(valid);
    s.T_C0_C.push_back(T);
    s.intrinsics.push_back(k);
  }
  return s;
}

Batch Batch::to(const at::Device& device) const {
  Batch b;
  for (const at::Tensor& f : frames) b.frames.push_back(f.to(device));
  b.pts = pts.to(device);
  b.valid = valid.to(device);
  b.sources = sources;
  return b;
}

Batch collate(const std::vector<SequenceSample>& samples) {
  if (samples.empty()) throw std::invalid_argument("collate: empty batch");
  const std::size_t N = samples[0].images.size();
  Batch b;
  std::vector<at::Tensor> pts, valid;
  for (const SequenceSample& s : samples) {
    if (s.images.size() != N) throw std::invalid_argument("collate: sequences of unequal length");
    pts.push_back(s.pts);
    valid.push_back(s.valid);
    b.sources.push_back(s.source);
  }
  for (std::size_t i = 0; i < N; ++i) {
    std::vector<at::Tensor> f;
    for (const SequenceSample& s : samples) f.push_back(s.images[i]);
    b.frames.push_back(at::stack(f));
  }
  b.pts = at::stack(pts);
  b.valid = at::stack(valid);
  return b;
}

SequenceSampler::SequenceSampler(const DataConfig& config, int image_size, uint64_t seed,
                                 int render_threads)
    : config_(config),
      image_size_(image_size),
      render_threads_(std::max(1, render_threads)),
      rng_(seed) {
  TumDatasetOptions opt;
  opt.require_depth = true;
  opt.require_pose = true;
  for (const std::string& dir : config_.tum_dirs) {
    TumDataset ds = TumDataset::open(dir, opt);
    if (!ds.calibration()) throw std::runtime_error(dir + ": training needs calibration.txt");
    if (ds.size() < 2) throw std::runtime_error(dir + ": fewer than 2 frames with depth and pose");
    tum_.push_back(std::move(ds));
  }
}

int64_t SequenceSampler::draw_int(int64_t lo, int64_t hi) { return uniform_int(rng_, lo, hi); }
double SequenceSampler::draw_uniform() { return uniform01(rng_); }

const synth::Sequence& SequenceSampler::scene(uint64_t seed) {
  auto it = scenes_.find(seed);
  if (it != scenes_.end()) return it->second;
  // Everything about a scene is a function of its seed (not of the sampler's
  // RNG), so a seed names the same sequence in every run.
  std::mt19937_64 r(seed * 0x9E3779B97F4A7C15ull + 17);
  const SynthDataConfig& sc = config_.synth;
  synth::SequenceConfig c;
  c.seed = seed;
  const int render = sc.render_size > 0 ? sc.render_size : image_size_;
  const double hfov = sc.hfov_min_deg + uniform01(r) * (sc.hfov_max_deg - sc.hfov_min_deg);
  c.intrinsics = PinholeIntrinsics::from_hfov(render, render, hfov);
  const synth::TrajectoryType types[3] = {synth::TrajectoryType::kWalk,
                                          synth::TrajectoryType::kOrbit,
                                          synth::TrajectoryType::kPanReturn};
  c.trajectory.type = types[uniform_int(r, 0, 2)];
  c.trajectory.frames = static_cast<int>(sc.trajectory_frames);
  c.trajectory.speed = sc.speed;
  // Keep a bounded cache: scenes are cheap to regenerate, not to keep forever.
  if (scenes_.size() >= 4096) scenes_.clear();
  return scenes_.emplace(seed, synth::generate_sequence(c)).first->second;
}

std::vector<RawFrame> SequenceSampler::synth_frames(uint64_t scene_seed, int64_t start,
                                                    int64_t stride, int64_t frames) {
  const synth::Sequence& seq = scene(scene_seed);
  synth::RenderOptions ro;
  ro.threads = render_threads_;
  std::vector<RawFrame> out;
  for (int64_t i = 0; i < frames; ++i) {
    const std::size_t idx = static_cast<std::size_t>(start + i * stride);
    if (idx >= seq.poses.size()) throw std::out_of_range("synth_frames: past the trajectory");
    synth::RenderedFrame r =
        synth::render_frame(seq.scene, seq.poses[idx], seq.config.intrinsics, ro);
    RawFrame f;
    f.bgr = r.bgr;
    f.depth = r.depth;
    f.intrinsics = seq.config.intrinsics;
    f.T_W_C = seq.poses[idx];
    out.push_back(std::move(f));
  }
  return out;
}

SequenceSample SequenceSampler::sample(int64_t frames) {
  bool use_tum = !tum_.empty();
  if (use_tum && config_.synth.enabled) use_tum = draw_uniform() < config_.tum_fraction;
  std::ostringstream source;
  std::vector<RawFrame> raw;
  auto pick = [&](int64_t length, int64_t* start, int64_t* stride) {
    // The longest stride that still fits, so short sources work too.
    const int64_t fit = std::max<int64_t>(1, (length - 1) / std::max<int64_t>(1, frames - 1));
    *stride = std::min(draw_int(config_.min_stride, config_.max_stride), fit);
    const int64_t span = (frames - 1) * *stride + 1;
    if (span > length) throw std::runtime_error("sequence source too short for the frame count");
    *start = draw_int(0, length - span);
  };
  if (use_tum) {
    const TumDataset& ds =
        tum_[static_cast<std::size_t>(draw_int(0, static_cast<int64_t>(tum_.size()) - 1))];
    int64_t start = 0, stride = 1;
    pick(static_cast<int64_t>(ds.size()), &start, &stride);
    for (int64_t i = 0; i < frames; ++i) {
      const std::size_t idx = static_cast<std::size_t>(start + i * stride);
      RawFrame f;
      f.bgr = ds.load_rgb(idx);
      f.depth = ds.load_depth(idx);
      f.intrinsics = *ds.calibration();
      f.T_W_C = *ds.frame(idx).pose;
      raw.push_back(std::move(f));
    }
    source << "tum:" << ds.root() << "@" << start << "+" << stride;
  } else {
    const uint64_t seed = config_.synth.train_seed_begin +
                          static_cast<uint64_t>(draw_int(0, config_.synth.train_scenes - 1));
    int64_t start = 0, stride = 1;
    pick(config_.synth.trajectory_frames, &start, &stride);
    raw = synth_frames(seed, start, stride, frames);
    source << "synth:" << seed << "@" << start << "+" << stride;
  }
  return prepare_sequence(raw, image_size_, config_.augment, &rng_, source.str());
}

Batch SequenceSampler::sample_batch(int64_t batch_size, int64_t frames) {
  std::vector<SequenceSample> samples;
  for (int64_t b = 0; b < batch_size; ++b) samples.push_back(sample(frames));
  return collate(samples);
}

SequenceSample SequenceSampler::validation_sequence(int64_t index, int64_t frames, int64_t stride) {
  const uint64_t seed = config_.synth.val_seed_begin + static_cast<uint64_t>(index);
  std::ostringstream source;
  source << "val:" << seed << "@0+" << stride;
  return prepare_sequence(synth_frames(seed, 0, stride, frames), image_size_, config_.augment,
                          nullptr, source.str());
}

std::string SequenceSampler::rng_state() const {
  std::ostringstream ss;
  ss << rng_;
  return ss.str();
}

void SequenceSampler::set_rng_state(const std::string& state) {
  std::istringstream ss(state);
  ss >> rng_;
  if (ss.fail()) throw std::runtime_error("SequenceSampler: bad RNG state");
}

}  // namespace long3r
