// The pre-rendered frame cache (train/frame_cache.cpp): every frame of the
// generated training scenes of a data configuration, rendered once by the
// generator and kept in one file that the trainer maps into memory, so that a
// training step reads its frames instead of rendering them (docs/training.md,
// "The frame cache"). Only the training scenes are kept; the held-out scenes
// of validation are rendered as before, so the held-out set does not depend
// on a cache.
//
// Frames: T_W_C of the optical frame in the scene's world, images and depth
// exactly as synth::render_frame makes them (a cache read gives the same
// bytes as a render, checked when the cache is opened).
//
// File layout (little-endian, one file):
//   [0, 4096)        "long3r frame cache\n", then the key (one JSON line:
//                    format, the synth fields the frames depend on, the
//                    render size), zero-padded
//   intrinsics       per scene: fx, fy, cx, cy (double)
//   poses            per scene and frame: T_W_C, 4 x 4 row-major (double)
//   frames           from the next 4096 boundary, per scene and frame, a
//                    record of depth ([S, S] float32) then BGR ([S, S, 3]
//                    uint8), padded to 64 bytes
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>

#include "long3r/train/train_config.hpp"
#include "long3r/train/train_data.hpp"

namespace long3r {

// A cache file that cannot be used: unreadable, cut short, of another format,
// made for other scenes, or disagreeing with the generator. The message names
// the file and what is wrong.
class FrameCacheError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class FrameCache {
 public:
  // Renders every frame of the training scenes [train_seed_begin,
  // train_seed_begin + train_scenes) of `config` at render_size x
  // render_size into `path` (written atomically: the file appears complete
  // or not at all). Scenes are rendered `threads` at a time. progress, when
  // set, is called after each scene with (scenes done, scenes).
  static void write(const std::string& path, const SynthDataConfig& config, int render_size,
                    int threads, const std::function<void(int64_t, int64_t)>& progress = {});

  // Maps `path` read-only. Refuses (FrameCacheError) a file whose key differs
  // from `config` at render_size (naming the field), a file shorter than its
  // layout, and one whose frames differ from the generator's: `verify_frames`
  // frames spread over the scenes are rendered and compared byte for byte.
  FrameCache(const std::string& path, const SynthDataConfig& config, int render_size,
             int verify_frames = 2);
  ~FrameCache();
  FrameCache(const FrameCache&) = delete;
  FrameCache& operator=(const FrameCache&) = delete;

  // A file name that says which scenes a cache of `config` at render_size
  // holds ("synth_64px_1000-2999x240_<hash of the key>.frames"): the same
  // for every configuration that draws the same frames, so that they share
  // one cache.
  static std::string file_name(const SynthDataConfig& config, int render_size);

  // Whether the cache holds the scene of this seed.
  bool covers(uint64_t seed) const;
  // Frame `index` of scene `seed` (copied out of the mapping). Throws
  // std::out_of_range outside the cache.
  RawFrame frame(uint64_t seed, int64_t index) const;

  const std::string& path() const { return path_; }
  int64_t scenes() const { return scenes_; }
  int64_t frames_per_scene() const { return frames_; }
  int render_size() const { return size_; }
  std::size_t file_bytes() const { return bytes_; }

 private:
  std::string path_;
  uint64_t seed_begin_ = 0;
  int64_t scenes_ = 0, frames_ = 0;
  int size_ = 0;
  const unsigned char* map_ = nullptr;
  std::size_t bytes_ = 0;
};

}  // namespace long3r
