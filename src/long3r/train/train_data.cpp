// Training data: sequence sampling from generated scenes and TUM folders,
// augmentation, and ground-truth pointmaps in camera 0's frame.
#include <ATen/ATen.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <stdexcept>

#include "long3r/synth/generate.hpp"
#include "long3r/synth/render.hpp"
#include "long3r/train/frame_cache.hpp"
#include "long3r/train/train_config.hpp"
#include "long3r/train/train_data.hpp"

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

// Luma of [H, W, 3] RGB (Rec. 601 weights, as OpenCV's RGB2GRAY): [H, W, 1].
at::Tensor luma(const at::Tensor& rgb) {
  return (rgb.select(-1, 0) * 0.299f + rgb.select(-1, 1) * 0.587f + rgb.select(-1, 2) * 0.114f)
      .unsqueeze(-1);
}

// Brightness, contrast and saturation factors in [1 - j, 1 + j] on linear
// [0, 1] RGB ([H, W, 3] float32).
at::Tensor colour_jitter(at::Tensor rgb, double j, std::mt19937_64& rng) {
  const double b = 1.0 + (2.0 * uniform01(rng) - 1.0) * j;
  const double c = 1.0 + (2.0 * uniform01(rng) - 1.0) * j;
  const double s = 1.0 + (2.0 * uniform01(rng) - 1.0) * j;
  rgb = rgb * b;
  const at::Tensor mean = luma(rgb).mean();
  rgb = (rgb - mean) * c + mean;
  const at::Tensor grey = luma(rgb);
  rgb = grey + (rgb - grey) * s;
  return rgb.clamp(0.0, 1.0);
}

// [H, W, 3] float RGB in [0, 1] -> [3, H, W] model input.
at::Tensor rgb_float_to_input(const at::Tensor& rgb) {
  return rgb.permute({2, 0, 1}).contiguous().sub_(0.5).div_(0.5);
}

// [H, W, 3] uint8 BGR -> [H, W, 3] float RGB in [0, 1]. Multiplied by the
// float 1/255 (as OpenCV's convertTo), not divided: the inputs stay
// bit-identical to those the shipped model was trained and scored on.
at::Tensor bgr_to_rgb_float(const at::Tensor& bgr) {
  return bgr.flip({-1}).to(at::kFloat).mul_(1.0 / 255.0);
}

// Square crop (x0, y0, side) of an [H, W, C] image, resized to size x size:
// area averaging to shrink, bilinear (pixel centres aligned) to grow,
// nearest for depth.
at::Tensor crop_resize(const at::Tensor& image, int x0, int y0, int side, int size, bool nearest) {
  at::Tensor crop = image.slice(0, y0, y0 + side).slice(1, x0, x0 + side);
  if (side == size) return crop.contiguous();
  at::Tensor x = crop.permute({2, 0, 1}).unsqueeze(0);  // [1, C, side, side]
  if (nearest) {
    x = at::upsample_nearest2d(x, {size, size});
  } else if (side > size) {
    x = at::adaptive_avg_pool2d(x, {size, size});
  } else {
    x = at::upsample_bilinear2d(x, {size, size}, /*align_corners=*/false);
  }
  return x[0].permute({1, 2, 0}).contiguous();
}

}  // namespace

PinholeIntrinsics crop_resize_intrinsics(const PinholeIntrinsics& k, int x0, int y0, int w, int h,
                                         int out_w, int out_h) {
  const double sx = static_cast<double>(out_w) / w, sy = static_cast<double>(out_h) / h;
  PinholeIntrinsics r;
  r.fx = k.fx * sx;
  r.fy = k.fy * sy;
  // Pixel centres aligned: dst = (src - x0 + 0.5) * s - 0.5.
  r.cx = (k.cx - x0 + 0.5) * sx - 0.5;
  r.cy = (k.cy - y0 + 0.5) * sy - 0.5;
  r.width = out_w;
  r.height = out_h;
  return r;
}

at::Tensor depth_to_pointmap(const at::Tensor& depth_map, const PinholeIntrinsics& k,
                             const Eigen::Isometry3d& T_C0_C, at::Tensor* valid) {
  if (depth_map.dim() != 2 || depth_map.scalar_type() != at::kFloat) {
    throw std::invalid_argument("depth_to_pointmap: need an [H, W] float32 depth map");
  }
  if (!k.valid()) throw std::invalid_argument("depth_to_pointmap: invalid intrinsics");
  const at::Tensor depth = depth_map.to(at::kCPU).contiguous();
  const int H = static_cast<int>(depth.size(0)), W = static_cast<int>(depth.size(1));
  const float* d = depth.data_ptr<float>();
  at::Tensor pts = at::zeros({H, W, 3}, at::kFloat);
  at::Tensor mask = at::zeros({H, W}, at::kBool);
  float* p = pts.data_ptr<float>();
  bool* m = mask.data_ptr<bool>();
  const Eigen::Matrix3d R = T_C0_C.linear();
  const Eigen::Vector3d t = T_C0_C.translation();
  for (int v = 0; v < H; ++v) {
    const float* row = d + static_cast<std::size_t>(v) * W;
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

at::Tensor bgr_to_model_input(const at::Tensor& bgr) {
  if (bgr.dim() != 3 || bgr.size(2) != 3 || bgr.scalar_type() != at::kByte) {
    throw std::invalid_argument("bgr_to_model_input: need an [H, W, 3] uint8 image");
  }
  return rgb_float_to_input(bgr_to_rgb_float(bgr.to(at::kCPU)));
}

SequenceSample prepare_sequence(const std::vector<RawFrame>& frames, int size,
                                const AugmentConfig& augment, std::mt19937_64* rng,
                                const std::string& source) {
  if (frames.empty()) throw std::invalid_argument("prepare_sequence: no frames");
  const auto check = [](const RawFrame& f) {
    if (f.bgr.dim() != 3 || f.bgr.size(2) != 3 || f.bgr.scalar_type() != at::kByte ||
        f.depth.dim() != 2 || f.depth.scalar_type() != at::kFloat ||
        f.depth.size(0) != f.bgr.size(0) || f.depth.size(1) != f.bgr.size(1)) {
      throw std::invalid_argument(
          "prepare_sequence: a frame needs an [H, W, 3] uint8 image and an [H, W] float32 depth");
    }
  };
  check(frames[0]);
  const int w = static_cast<int>(frames[0].bgr.size(1)),
            h = static_cast<int>(frames[0].bgr.size(0));
  // One crop for the whole sequence, so that every frame keeps one camera.
  const int base = std::min(w, h);
  const double shrink = rng != nullptr ? uniform01(*rng) * augment.max_crop : 0.0;
  const int side = std::max(1, static_cast<int>(std::lround(base * (1.0 - shrink))));
  int x0 = (w - side) / 2, y0 = (h - side) / 2;
  if (augment.crop_at_principal_point) {
    // The crop's centre ((x0 + side / 2) - 0.5 in pixel coordinates) as close
    // to (cx, cy) as the image allows.
    const PinholeIntrinsics& k = frames[0].intrinsics;
    x0 = std::clamp(static_cast<int>(std::lround(k.cx + 0.5 - side / 2.0)), 0, w - side);
    y0 = std::clamp(static_cast<int>(std::lround(k.cy + 0.5 - side / 2.0)), 0, h - side);
  } else if (rng != nullptr) {
    x0 = static_cast<int>(uniform_int(*rng, 0, w - side));
    y0 = static_cast<int>(uniform_int(*rng, 0, h - side));
  }
  SequenceSample s;
  s.source = source;
  const int N = static_cast<int>(frames.size());
  s.pts = at::empty({N, size, size, 3}, at::kFloat);
  s.valid = at::empty({N, size, size}, at::kBool);
  const Eigen::Isometry3d T_C0_W = frames[0].T_W_C.inverse();
  for (int i = 0; i < N; ++i) {
    const RawFrame& f = frames[static_cast<std::size_t>(i)];
    check(f);
    if (f.bgr.size(1) != w || f.bgr.size(0) != h) {
      throw std::invalid_argument("prepare_sequence: frames of one sequence need one size");
    }
    at::Tensor rgb = crop_resize(bgr_to_rgb_float(f.bgr.to(at::kCPU)), x0, y0, side, size, false);
    const at::Tensor depth =
        crop_resize(f.depth.to(at::kCPU).unsqueeze(-1), x0, y0, side, size, true).squeeze(-1);
    if (rng != nullptr && augment.color_jitter > 0.0) {
      rgb = colour_jitter(rgb, augment.color_jitter, *rng);
    }
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
                                 int render_threads, const RecordedSourceOpener& open_recorded,
                                 const DatasetOpener& open_dataset)
    : config_(config),
      image_size_(image_size),
      render_threads_(std::max(1, render_threads)),
      rng_(seed) {
  if (!config_.tum_dirs.empty() && !open_recorded) {
    throw std::runtime_error(
        "data.tum_dirs: this build reads no TUM folders (built without OpenCV); train on "
        "generated scenes only, or build with OpenCV");
  }
  for (const std::string& dir : config_.tum_dirs) recorded_.push_back(open_recorded(dir));
  if (!config_.datasets.empty() && !open_dataset) {
    throw std::runtime_error(
        "data.datasets: this build reads no datasets (built without OpenCV); train on generated "
        "scenes only, or build with OpenCV");
  }
  for (const DatasetSource& source : config_.datasets) {
    const std::string& name = source.label();
    OpenedDataset opened = open_dataset(source);
    for (const std::string& why : opened.skipped) {
      std::fprintf(stderr, "long3r_train: %s: left out %s\n", name.c_str(), why.c_str());
    }
    if (opened.sequences.empty()) {
      throw std::runtime_error("data.datasets: " + name + " (" + source.root + ", split " +
                               source.split + ") has no usable sequence");
    }
    std::fprintf(stderr, "long3r_train: %s: %zu sequences (%zu left out), weight %g\n",
                 name.c_str(), opened.sequences.size(), opened.skipped.size(), source.weight);
    datasets_.push_back({source, std::move(opened.sequences)});
    dataset_weight_ += source.weight;
  }
}

synth::SequenceConfig synth_scene_config(const SynthDataConfig& sc, uint64_t seed,
                                         int render_size) {
  // Everything about a scene is a function of its seed (not of the sampler's
  // RNG), so a seed names the same sequence in every run.
  std::mt19937_64 r(seed * 0x9E3779B97F4A7C15ull + 17);
  synth::SequenceConfig c;
  c.seed = seed;
  const double hfov = sc.hfov_min_deg + uniform01(r) * (sc.hfov_max_deg - sc.hfov_min_deg);
  c.intrinsics = PinholeIntrinsics::from_hfov(render_size, render_size, hfov);
  const synth::TrajectoryType types[3] = {synth::TrajectoryType::kWalk,
                                          synth::TrajectoryType::kOrbit,
                                          synth::TrajectoryType::kPanReturn};
  c.trajectory.type = types[uniform_int(r, 0, 2)];
  c.trajectory.frames = static_cast<int>(sc.trajectory_frames);
  c.trajectory.speed = sc.speed;
  return c;
}

const synth::Sequence& SequenceSampler::scene(uint64_t seed) {
  auto it = scenes_.find(seed);
  if (it != scenes_.end()) return it->second;
  const SynthDataConfig& sc = config_.synth;
  const synth::SequenceConfig c = synth_scene_config(sc, seed, sc.render_side(image_size_));
  // Keep a bounded cache: scenes are cheap to regenerate, not to keep forever.
  if (scenes_.size() >= 4096) scenes_.clear();
  return scenes_.emplace(seed, synth::generate_sequence(c)).first->second;
}

std::vector<RawFrame> SequenceSampler::synth_frames(uint64_t scene_seed, int64_t start,
                                                    int64_t stride, int64_t frames) {
  std::vector<RawFrame> out;
  if (cache_ && cache_->covers(scene_seed)) {
    for (int64_t i = 0; i < frames; ++i)
      out.push_back(cache_->frame(scene_seed, start + i * stride));
    return out;
  }
  const synth::Sequence& seq = scene(scene_seed);
  synth::RenderOptions ro;
  ro.threads = render_threads_;
  for (int64_t i = 0; i < frames; ++i) {
    const std::size_t idx = static_cast<std::size_t>(start + i * stride);
    if (idx >= seq.poses.size()) throw std::out_of_range("synth_frames: past the trajectory");
    synth::RenderedFrame r =
        synth::render_frame(seq.scene, seq.poses[idx], seq.config.intrinsics, ro);
    RawFrame f;
    f.bgr = std::move(r.bgr);
    f.depth = std::move(r.depth);
    f.intrinsics = seq.config.intrinsics;
    f.T_W_C = seq.poses[idx];
    out.push_back(std::move(f));
  }
  return out;
}

SequenceSample SequenceSampler::sample(int64_t frames) {
  std::mt19937_64 rng(rng_());
  return sample_from(frames, rng);
}

SequenceSample SequenceSampler::sample_from(int64_t frames, std::mt19937_64& rng) {
  auto draw_int = [&rng](int64_t lo, int64_t hi) { return uniform_int(rng, lo, hi); };
  auto draw_uniform = [&rng] { return uniform01(rng); };
  if (!datasets_.empty()) return dataset_sample(frames, rng);
  bool use_tum = !recorded_.empty();
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
    const RecordedSource& ds = *recorded_[static_cast<std::size_t>(
        draw_int(0, static_cast<int64_t>(recorded_.size()) - 1))];
    int64_t start = 0, stride = 1;
    pick(ds.size(), &start, &stride);
    for (int64_t i = 0; i < frames; ++i) raw.push_back(ds.frame(start + i * stride));
    source << "tum:" << ds.name() << "@" << start << "+" << stride;
  } else {
    const uint64_t seed = config_.synth.train_seed_begin +
                          static_cast<uint64_t>(draw_int(0, config_.synth.train_scenes - 1));
    int64_t start = 0, stride = 1;
    pick(config_.synth.trajectory_frames, &start, &stride);
    raw = synth_frames(seed, start, stride, frames);
    source << "synth:" << seed << "@" << start << "+" << stride;
  }
  return finish_sample(std::move(raw), source.str(), rng);
}

SequenceSample SequenceSampler::finish_sample(std::vector<RawFrame> raw, std::string source,
                                              std::mt19937_64& rng) const {
  // Drawn only when asked for, so that runs without it draw what they drew.
  if (config_.reverse_fraction > 0.0 && uniform01(rng) < config_.reverse_fraction) {
    std::reverse(raw.begin(), raw.end());
    source += "r";
  }
  return prepare_sequence(raw, image_size_, config_.augment, &rng, source);
}

SequenceSample SequenceSampler::dataset_sample(int64_t frames, std::mt19937_64& rng) {
  // A sample whose frame cannot be read is skipped, counted and drawn again
  // (from the same generator, so a run stays reproducible); only a dataset
  // that fails sample after sample ends the run.
  constexpr int kMaxAttempts = 100;
  std::string last_error;
  for (int attempt = 0; attempt < kMaxAttempts; ++attempt) {
    // The dataset by weight, a sequence uniformly, then the frames: a random
    // start and gaps drawn in [min_stride, max_stride] (smaller when the
    // sequence is short), as Spann3R picks frames up to a gap threshold.
    double pick = uniform01(rng) * dataset_weight_;
    std::size_t d = 0;
    while (d + 1 < datasets_.size() && pick >= datasets_[d].source.weight) {
      pick -= datasets_[d].source.weight;
      ++d;
    }
    const Dataset& ds = datasets_[d];
    const RecordedSource& seq = *ds.sequences[static_cast<std::size_t>(
        uniform_int(rng, 0, static_cast<int64_t>(ds.sequences.size()) - 1))];
    const int64_t length = seq.size();
    std::vector<int64_t> gaps;
    int64_t span = 0;
    for (int64_t i = 0; i + 1 < frames; ++i) {
      gaps.push_back(uniform_int(rng, ds.source.min_stride, ds.source.max_stride));
      span += gaps.back();
    }
    if (span > length - 1) {  // too short for these gaps: the widest even ones that fit
      const int64_t g = std::max<int64_t>(1, (length - 1) / std::max<int64_t>(1, frames - 1));
      std::fill(gaps.begin(), gaps.end(), g);
      span = g * (frames - 1);
    }
    if (span > length - 1) {
      last_error = seq.name() + ": " + std::to_string(length) + " frames, " +
                   std::to_string(frames) + " needed";
    } else {
      const int64_t start = uniform_int(rng, 0, length - 1 - span);
      std::ostringstream source;
      source << ds.source.label() << ":" << seq.name() << "@" << start;
      try {
        std::vector<RawFrame> raw;
        int64_t index = start;
        for (int64_t i = 0; i < frames; ++i) {
          raw.push_back(seq.frame(index));
          if (i + 1 < frames) {
            index += gaps[static_cast<std::size_t>(i)];
            source << "+" << gaps[static_cast<std::size_t>(i)];
          }
        }
        return finish_sample(std::move(raw), source.str(), rng);
      } catch (const RecordedFrameError& e) {
        last_error = e.what();
      }
    }
    ++skipped_samples_;
    // Named every time for the first few, then every 100th.
    if (skipped_samples_ <= 20 || skipped_samples_ % 100 == 0) {
      std::fprintf(stderr, "long3r_train: skipped a sample (%lld so far): %s\n",
                   static_cast<long long>(skipped_samples_), last_error.c_str());
    }
  }
  throw std::runtime_error("data.datasets: " + std::to_string(kMaxAttempts) +
                           " samples in a row could not be read; the last: " + last_error);
}

Batch SequenceSampler::sample_batch(int64_t batch_size, int64_t frames, int64_t first,
                                    int64_t count) {
  if (count < 0) count = batch_size - first;
  if (first < 0 || count < 1 || first + count > batch_size) {
    throw std::invalid_argument("sample_batch: samples [" + std::to_string(first) + ", " +
                                std::to_string(first + count) + ") are not in a batch of " +
                                std::to_string(batch_size));
  }
  std::vector<uint64_t> seeds;
  for (int64_t b = 0; b < batch_size; ++b) seeds.push_back(rng_());
  std::vector<SequenceSample> samples;
  for (int64_t b = first; b < first + count; ++b) {
    std::mt19937_64 rng(seeds[static_cast<std::size_t>(b)]);
    samples.push_back(sample_from(frames, rng));
  }
  return collate(samples);
}

SequenceSample SequenceSampler::validation_sequence(int64_t index, int64_t frames, int64_t stride,
                                                    int64_t start) {
  const uint64_t seed = config_.synth.val_seed_begin + static_cast<uint64_t>(index);
  std::ostringstream source;
  source << "val:" << seed << "@" << start << "+" << stride;
  return prepare_sequence(synth_frames(seed, start, stride, frames), image_size_, config_.augment,
                          nullptr, source.str());
}

std::vector<SequenceSample> SequenceSampler::blind_sequences(const ValidationConfig& config) {
  std::vector<SequenceSample> out;
  for (int64_t scene = 0; scene < config.blind_scenes; ++scene) {
    for (int64_t i = 0; i < config.blind_starts; ++i) {
      for (const int64_t s : config.blind_strides) {
        const int64_t span = (config.blind_frames - 1) * s + 1;
        const int64_t room = std::max<int64_t>(0, config_.synth.trajectory_frames - span);
        const int64_t start = config.blind_starts > 1 ? room * i / (config.blind_starts - 1) : 0;
        out.push_back(validation_sequence(scene, config.blind_frames, s, start));
      }
    }
  }
  return out;
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
