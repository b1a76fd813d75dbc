// The streaming interface shared by every model variant (Spann3R, LONG3R).
//
// Frames are pushed one at a time. Step t runs when frame t+1 arrives and
// returns the result for frame t (one frame of latency, as both models
// define it); peek_last() returns the last frame from the coarse head without
// ending the stream (a pause in the input), flush() returns it and ends the
// stream; reset() clears every piece of state (memory, cached features).
// Pointmaps are in the coordinate frame of camera 0 of the current stream.
#pragma once

#include <ATen/core/Tensor.h>

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "long3r/model/loading/state_dict.hpp"
#include "long3r/model/runtime/inference_config.hpp"

namespace long3r {

// Per-step statistics of the memory, for logs, CSVs and diagnostics.
struct StepStats {
  int64_t mem_short_tokens = 0;       // short-term / working memory tokens
  int64_t mem_long_tokens = 0;        // long-term memory tokens
  int64_t relevant_tokens = -1;       // after memory gating; -1 = the variant has no gating
  double voxel_size = 0.0;            // LONG3R v_scene (pointmap units); 0 = not applicable
  bool memory_write_skipped = false;  // Spann3R similarity skip
  double encode_ms = 0.0;
  double decode_ms = 0.0;  // memory read + decoder + heads
  double memory_ms = 0.0;  // memory write and pruning
};

struct StreamOutput {
  int64_t frame_index = 0;        // 0-based index of the frame these outputs belong to
  at::Tensor pts3d;               // [B, H, W, 3] float32, camera-0 frame
  at::Tensor conf;                // [B, H, W] float32, >= 1
  bool from_coarse_head = false;  // true for the frame returned by peek_last() / flush()
  StepStats stats;
};

// What a saved stream state is valid for: the model variant, its
// configuration (JSON) and its weights (a fingerprint of the checkpoint's
// tensors; empty for weights never loaded from one).
struct ModelIdentity {
  std::string variant;
  std::string config_json;
  std::string weights;
};

class StreamingModel {
 public:
  virtual ~StreamingModel() = default;

  // image: [B, 3, H, W] float32, values (rgb - 0.5) / 0.5, on any device.
  // Returns the result of the previous frame; empty for the first frame.
  // All frames of a stream must have the same size.
  virtual std::optional<StreamOutput> push(const at::Tensor& image) = 0;

  // The last pushed frame's result from the coarse head (head 2 of the last
  // step) while its refined result still waits for the next frame. Changes no
  // state: a later push continues the stream and returns that frame's refined
  // result as usual. Empty before the first pair (the models need two frames).
  virtual std::optional<StreamOutput> peek_last() = 0;

  // The end of a stream: peek_last(), then reset().
  std::optional<StreamOutput> flush() {
    std::optional<StreamOutput> out = peek_last();
    reset();
    return out;
  }

  // Drops all state; the next push starts a new stream.
  virtual void reset() = 0;

  // Number of frames pushed in the current stream.
  virtual int64_t frames_pushed() const = 0;

  // "spann3r" or "long3r".
  virtual std::string variant() const = 0;

  // The stream between two pushes (memory, the newest frame's features,
  // counters) as a state dict, for sessions: restore_stream_state() of it
  // into a model of the same identity() continues the stream exactly (the
  // next push returns what this model's next push would). Tensors are shared
  // with the model, on its device. Throws std::logic_error where the model
  // cannot (training mode; a model without sessions).
  virtual StateDict stream_state() const;
  // Replaces the stream by a saved one, converted to this model's device and
  // precision. Validated first: StateError naming the entry, and the stream
  // is unchanged then.
  virtual void restore_stream_state(const StateDict& state);
  virtual ModelIdentity identity() const { return {variant(), "", ""}; }

  // Whether portrait frames (H > W) keep their token grid. A landscape-only
  // Spann3R (the official setting) runs them, as the official model does, on a
  // scrambled grid and returns transposed maps; callers refuse such input.
  virtual bool accepts_portrait() const { return true; }

  // The input size the checkpoint records as the one it was trained at
  // (ModelConfig::input_width / input_height), width then height; {0, 0}
  // where it records none.
  virtual std::array<int64_t, 2> recorded_input_size() const { return {0, 0}; }
};

// Loads a checkpoint and builds the StreamingModel variant its metadata config
// names (Spann3R or LONG3R), reading the file once, then moves and converts
// the weights once to the requested device and precision. The request is
// checked first (resolve_inference_target: ConfigError,
// InferenceUnsupportedError); memory sizes it sets replace the checkpoint's
// (apply_memory_overrides). Throws CheckpointError with a clear message for
// an unreadable or bad file and for kinds that do not stream (e.g. a DUSt3R
// pair model).
std::unique_ptr<StreamingModel> make_streaming_model(const std::string& path,
                                                     const InferenceConfig& inference = {});

struct ModelConfig;
// The memory sizes `inference` sets (short_term_frames, long_term_capacity;
// -1 leaves the checkpoint's) written into a LONG3R model's configuration,
// as make_streaming_model does. Throws ConfigError naming the parameter when
// one is set for a model that is not LONG3R.
void apply_memory_overrides(const InferenceConfig& inference, ModelConfig* config);

}  // namespace long3r
