// Training data (train/train_data.cpp): source frames with ground truth,
// recorded sequences and datasets as sources, ground-truth pointmaps, the
// preparation of a sequence for the model (crop, resize, augmentation),
// batches, and the sampler that draws them from generated scenes, TUM folders
// and datasets.
//
// Frames: ground-truth pointmaps are in the optical frame of camera 0 of each
// sampled sequence (x right, y down, z forward), metres, like the model's.
#pragma once

#include <ATen/core/Tensor.h>

#include <Eigen/Geometry>

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "long3r/geometry/pinhole_intrinsics.hpp"
#include "long3r/synth/generate.hpp"
#include "long3r/train/train_config.hpp"

namespace long3r {

class FrameCache;

// One source frame with ground truth (CPU tensors).
struct RawFrame {
  at::Tensor bgr;    // [H, W, 3] uint8, BGR order
  at::Tensor depth;  // [H, W] float32 z-depth, metres; 0 / non-finite = invalid
  PinholeIntrinsics intrinsics;
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();
};

// A recorded sequence used as training data: frames with depth, pose and
// calibration (TUM folders: open_tum_training_source in cv/train_cv.hpp).
class RecordedSource {
 public:
  virtual ~RecordedSource() = default;
  virtual int64_t size() const = 0;
  virtual RawFrame frame(int64_t index) const = 0;
  virtual std::string name() const = 0;  // in the samples' source strings
};
// Opens the folder of a data.tum_dirs entry, or throws naming the problem.
using RecordedSourceOpener = std::function<std::unique_ptr<RecordedSource>(const std::string&)>;

// A recorded frame that cannot be read: a missing, truncated or inconsistent
// file, named in the message. The sampler skips such a sample, counts it and
// draws another.
class RecordedFrameError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The sequences of one dataset of data.datasets (train/cv/datasets/dataset_io.hpp).
struct OpenedDataset {
  std::vector<std::unique_ptr<RecordedSource>> sequences;
  std::vector<std::string> skipped;  // "<path>: <why>" of each sequence left out
};
using DatasetOpener = std::function<OpenedDataset(const DatasetSource&)>;

// Intrinsics after cropping the rectangle (x0, y0, w, h) out of an image and
// resizing it to out_w x out_h with pixel-centre alignment (as cv::resize and
// torch's interpolation without align_corners):
// f' = f * out / crop, c' = (c - x0 + 0.5) * out / crop - 0.5.
PinholeIntrinsics crop_resize_intrinsics(const PinholeIntrinsics& k, int x0, int y0, int w, int h,
                                         int out_w, int out_h);

// Ground-truth pointmap of one frame: depth unprojected with `k` and mapped by
// T_C0_C into camera 0's frame. Returns [H, W, 3] float32 (zeros where
// invalid) and sets *valid ([H, W] bool: depth > 0 and finite).
// depth: [H, W] float32.
at::Tensor depth_to_pointmap(const at::Tensor& depth, const PinholeIntrinsics& k,
                             const Eigen::Isometry3d& T_C0_C, at::Tensor* valid);

// [3, H, W] float32 model input, (rgb - 0.5) / 0.5, from a BGR image
// ([H, W, 3] uint8).
at::Tensor bgr_to_model_input(const at::Tensor& bgr);

// A sequence ready for the model.
struct SequenceSample {
  std::vector<at::Tensor> images;             // N x [3, H, W]
  at::Tensor pts;                             // [N, H, W, 3], camera-0 frame
  at::Tensor valid;                           // [N, H, W] bool
  std::vector<Eigen::Isometry3d> T_C0_C;      // GT poses relative to camera 0
  std::vector<PinholeIntrinsics> intrinsics;  // at model resolution
  std::string source;                         // e.g. "synth:1234@17+3"
};

// Crop + resize every frame to size x size (one crop for the whole sequence:
// a random square of side (1 - u * max_crop) times the largest centred
// square, at a random position, u uniform), optional colour jitter per frame,
// and ground truth in camera 0's frame. rng == nullptr: centred full crop and
// no jitter (validation). Images shrink by area averaging and grow
// bilinearly; depth is resized by nearest neighbour (no depth mixed across
// object boundaries); a crop of the output size is copied as it is.
SequenceSample prepare_sequence(const std::vector<RawFrame>& frames, int size,
                                const AugmentConfig& augment, std::mt19937_64* rng,
                                const std::string& source = "");

// The generated scene of one seed of a synth data configuration, rendered at
// render_size x render_size: its field of view and path type drawn from the
// seed alone, so that a seed names the same scene in every run (the sampler's
// scenes and the frame cache's alike).
synth::SequenceConfig synth_scene_config(const SynthDataConfig& config, uint64_t seed,
                                         int render_size);

// A batch: frames[i] = [B, 3, H, W]; pts [B, N, H, W, 3]; valid [B, N, H, W].
struct Batch {
  std::vector<at::Tensor> frames;
  at::Tensor pts, valid;
  std::vector<std::string> sources;
  Batch to(const at::Device& device) const;
};
Batch collate(const std::vector<SequenceSample>& samples);

// Draws training sequences (random source, scene, start and stride) and
// builds the fixed validation sequences. Deterministic given its RNG state,
// which checkpoints save and restore.
// Thread-compatible: one thread uses a sampler at a time (the trainer's data
// thread while it prefetches).
class SequenceSampler {
 public:
  // open_recorded opens data.tum_dirs; without it a config naming any is
  // refused (std::runtime_error).
  // open_dataset likewise opens data.datasets (a dataset without any
  // sequence is refused; the sequences left out are reported on stderr).
  SequenceSampler(const DataConfig& config, int image_size, uint64_t seed, int render_threads = 2,
                  const RecordedSourceOpener& open_recorded = {},
                  const DatasetOpener& open_dataset = {});

  // Every sample draws from a generator of its own, seeded in turn from the
  // sampler's: a sample is then the same whichever process makes it, and the
  // sampler's state after a batch does not depend on who made which part.
  SequenceSample sample(int64_t frames);
  // The samples [first, first + count) of a batch of batch_size (count < 0:
  // to its end), in their places: the shard one data-parallel rank makes of
  // the batch that all ranks draw together. The sampler moves past the whole
  // batch.
  Batch sample_batch(int64_t batch_size, int64_t frames, int64_t first = 0, int64_t count = -1);

  // Held-out scenes val_seed_begin + i, frames from 0 with a fixed stride, no
  // augmentation.
  SequenceSample validation_sequence(int64_t index, int64_t frames, int64_t stride,
                                     int64_t start = 0);
  // The blind control's sequences of a validation configuration (scenes x
  // evenly spaced starts x strides), in that order.
  std::vector<SequenceSample> blind_sequences(const ValidationConfig& config);

  // Training frames of the scenes `cache` holds come from it instead of the
  // renderer (the same bytes); other scenes (validation's) are rendered.
  void set_frame_cache(std::shared_ptr<const FrameCache> cache) { cache_ = std::move(cache); }

  // Raw frames of a generated scene (start, stride) without preprocessing.
  std::vector<RawFrame> synth_frames(uint64_t scene_seed, int64_t start, int64_t stride,
                                     int64_t frames);

  std::string rng_state() const;
  void set_rng_state(const std::string& state);
  // Samples skipped so far for an unreadable frame (RecordedFrameError).
  int64_t skipped_samples() const { return skipped_samples_; }

 private:
  const synth::Sequence& scene(uint64_t seed);
  // One sample, all of its draws from rng.
  SequenceSample sample_from(int64_t frames, std::mt19937_64& rng);
  SequenceSample dataset_sample(int64_t frames, std::mt19937_64& rng);
  // The drawn frames played backwards for data.reverse_fraction, then
  // prepared (crop, resize, augmentation) with the sample's generator.
  SequenceSample finish_sample(std::vector<RawFrame> raw, std::string source,
                               std::mt19937_64& rng) const;

  DataConfig config_;
  int image_size_;
  int render_threads_;
  std::mt19937_64 rng_;
  std::map<uint64_t, synth::Sequence> scenes_;
  std::shared_ptr<const FrameCache> cache_;
  std::vector<std::unique_ptr<RecordedSource>> recorded_;
  struct Dataset {
    DatasetSource source;
    std::vector<std::unique_ptr<RecordedSource>> sequences;
  };
  std::vector<Dataset> datasets_;
  double dataset_weight_ = 0.0;  // sum of the datasets' weights
  int64_t skipped_samples_ = 0;
};

}  // namespace long3r
