// LONG3R 3D spatio-temporal memory (paper 3.4, spec "3D spatio-temporal memory").
//
// Holds the memory tokens written by the refined decoder: a short-term window of
// the last K frames (never pruned) and a long-term store that keeps at most one
// token per voxel of an adaptive size, and at most L tokens. Each token carries
// key, value, 3D position, cumulative attention and frame index; they move
// together through append, move to long-term, pruning and every accessor.
//
// Positions are in the coordinate frame of camera 0 (the frame of the stream's
// pointmaps); voxel sizes are in the same units.
//
// Batch: B independent streams. Short-term memory holds the same number of tokens
// for every stream; long-term sizes differ per stream (each has its own voxel
// size and pruning). The accessors return a padded batch [B, S, ...] with
// S = short_size() + max_b long_size(b):
//   token s of stream b:  [0, short_size())         short-term, oldest frame first,
//                                                    each frame in token (row-major) order
//                         [short_size(), +long(b))   long-term, in insertion order
//                         [short_size()+long(b), S)  padding (valid_mask() false)
// For B = 1 there is never padding. Not thread-safe.
#pragma once

#include <ATen/core/Tensor.h>

#include <cstdint>
#include <deque>
#include <functional>
#include <vector>

#include "long3r/memory/memory_config.hpp"  // SpatioTemporalMemoryConfig
#include "long3r/memory/memory_gating.hpp"
#include "long3r/model/loading/state_dict.hpp"

namespace long3r {

class SpatioTemporalMemory {
 public:
  explicit SpatioTemporalMemory(SpatioTemporalMemoryConfig config = SpatioTemporalMemoryConfig());

  const SpatioTemporalMemoryConfig& config() const { return config_; }

  // Training: tokens are stored as given (the graph spans the steps). Inference
  // (default): tokens are stored detached.
  void set_training(bool training) { training_ = training; }
  bool training() const { return training_; }

  // Appends one frame to short-term memory with zero cumulative attention.
  //   keys, values [B,P,C]; positions [B,P,3] (camera-0 frame, e.g. from
  //   token_positions()); grid_hw = {H, W} token grid with H*W = P, row-major.
  // Updates v_img / v_scene from this frame, then while more than K frames are in
  // short-term moves the oldest frame's tokens to long-term and prunes it.
  // B and C are fixed by the first frame until reset(); P may vary per frame.
  //   payload [B,P,D] (optional): per-token data derived from the key and value
  //   that travels with the token (the model keeps each memory block's projected
  //   key and value there so that they are computed once per token, not once
  //   per read). Given with every frame or with none until reset().
  void add_frame(const at::Tensor& keys, const at::Tensor& values, const at::Tensor& positions,
                 int64_t frame_index, at::IntArrayRef grid_hw,
                 const at::Tensor& payload = at::Tensor());

  // Padded batch of the whole memory in the layout above. Undefined tensors
  // before the first frame.
  at::Tensor keys() const;           // [B,S,C], zeros at padding
  at::Tensor values() const;         // [B,S,C], zeros at padding
  at::Tensor positions() const;      // [B,S,3], zeros at padding
  at::Tensor attention() const;      // [B,S] float32 cumulative attention, 0 at padding
  at::Tensor frame_indices() const;  // [B,S] int64, -1 at padding
  at::Tensor valid_mask() const;     // [B,S] bool

  // a_s += increment[b, s] for every valid token, in the layout above (padding
  // entries are ignored). increment: [B,S] with S = padded_size(), e.g.
  // GatingResult::attention_increment of a gating over keys()/values().
  void add_attention(const at::Tensor& increment);

  // Payload of the tokens index [B,R] (positions in the layout above; entries of
  // padded rows may point at any valid token, e.g. 0) -> [B,R,D]. Reads only the
  // R selected rows, without assembling the whole memory. Needs a payload.
  at::Tensor gather_payload(const at::Tensor& index) const;
  bool has_payload() const { return payload_dim_ > 0; }

  // memory_gating() over the whole memory with config().tau and training(), then
  // add_attention() with its increment. With an empty memory: fused = features.
  GatingResult read(const at::Tensor& queries, const at::Tensor& features,
                    const GatingNorms& norms);

  int64_t batch_size() const { return batch_; }  // 0 before the first frame
  int64_t frames_added() const { return frames_added_; }
  // kSpann3r: whether the last add_frame() skipped its frame (similarity).
  bool last_frame_skipped() const { return last_skipped_; }
  int64_t short_frames() const { return static_cast<int64_t>(short_frame_sizes_.size()); }
  int64_t short_size() const;                // tokens in short-term (same for all streams)
  std::vector<int64_t> long_sizes() const;   // long-term tokens per stream
  std::vector<int64_t> total_sizes() const;  // short + long per stream
  int64_t padded_size() const;               // S = short_size() + max long size
  bool empty() const { return padded_size() == 0; }

  // v_img of the last added frame and the running mean v_scene, per stream. A
  // frame whose d_i are all non-finite has v_img = NaN and does not enter the
  // mean; v_scene is NaN until a frame has a finite v_img.
  std::vector<double> last_v_img() const;
  std::vector<double> v_scene() const;

  void reset();

  // The whole memory as a state dict (state_dict.hpp): every token with its
  // key, value, position, attention, frame and order, the short-term frame
  // sizes, the counters and the voxel statistics. Payloads are not saved:
  // they are derived from keys and values, and restore() recomputes them.
  StateDict state() const;
  // Replaces the memory by a saved one. Keys and values go to `options`
  // (the model's device and dtype), the other tensors keep their dtype on
  // that device; `payload(keys [B,N,C], values)` -> [B,N,D] recomputes the
  // payloads when given. Everything is validated first (StateError naming
  // the entry; the memory is unchanged then), including the token counts
  // against this memory's K and L.
  using PayloadFn = std::function<at::Tensor(const at::Tensor&, const at::Tensor&)>;
  void restore(const StateReader& state, const at::TensorOptions& options,
               const PayloadFn& payload = {});

 private:
  // A set of N memory tokens: every per-token tensor, kept in step by
  // applying each operation to all fields through map() / zip(). In the
  // short-term set (batched) the per-stream fields are [B, N, ...] and frame /
  // order, shared by the streams, [N]; in a stream's long-term set all are
  // [N, ...].
  struct Tokens {
    at::Tensor keys;       // [.., N, C]
    at::Tensor values;     // [.., N, C]
    at::Tensor positions;  // [.., N, 3]
    at::Tensor attention;  // [.., N] float32
    at::Tensor frame;      // [N] int64
    at::Tensor order;      // [N] int64 insertion counter (tie-break among equal frames)
    at::Tensor payload;    // [.., N, D]; undefined without a payload
    bool batched = false;

    int64_t size() const { return frame.size(0); }
    // f(field, its token dimension) for every defined field, as a new set.
    template <class F>
    Tokens map(F f) const;
    // f(field, the same field of `other`, token dimension), as a new set.
    template <class F>
    Tokens zip(const Tokens& other, F f) const;
    Tokens stream(int64_t b) const;  // stream b of a batched set
    Tokens empty() const;            // no tokens, the same widths and options
    Tokens narrow(int64_t start, int64_t length) const;
    Tokens index_select(const at::Tensor& index) const;
    Tokens cat(const Tokens& more) const;  // these tokens, then more's
  };
  struct Stream {
    Tokens long_term;  // unbatched [N, ...]
    double v_img_last = 0.0;
    double v_img_sum = 0.0;
    int64_t v_img_count = 0;
  };
  struct Layout {
    at::Tensor keys, values, positions, frame, valid;
  };

  void move_oldest_frame_to_long_term();
  // cat(short_part[b], long_parts[b], padding) over b -> [B, S, ...].
  at::Tensor assemble(const at::Tensor& short_part, const std::vector<at::Tensor>& long_parts,
                      double pad) const;
  const Layout& layout() const;

  SpatioTemporalMemoryConfig config_;
  bool training_ = false;
  int64_t batch_ = 0;
  int64_t channels_ = 0;
  int64_t payload_dim_ = 0;  // D, 0 = no payload
  int64_t frames_added_ = 0;
  int64_t next_order_ = 0;
  bool last_skipped_ = false;
  int64_t frame_of_last_add_ = 0;
  Tokens short_term_;  // batched [B, N, ...]; frame/order [N]
  std::deque<int64_t> short_frame_sizes_;
  std::vector<Stream> streams_;
  mutable Layout layout_;  // cache of the padded layout, rebuilt after a change
  mutable bool layout_valid_ = false;
};

// Confidence-weighted mean of the pointmap over each token's patch (spec step 6).
//   pointmap [B,H,W,3], conf [B,H,W] -> [B,P,3], P = (H/patch)*(W/patch), tokens
//   row-major. A patch whose confidences sum to <= 0 gets its plain mean.
//   Differentiable in pointmap and conf.
at::Tensor token_positions(const at::Tensor& pointmap, const at::Tensor& conf, int64_t patch);

// d_i = mean 3D distance from token i to its existing 8-neighbours on the token
// grid (border tokens average over the neighbours they have). positions [B,P,3],
// grid_hw = {H,W}, H*W = P >= 2. Returns [B,P] float64 (no gradient).
at::Tensor neighbour_distances(const at::Tensor& positions, at::IntArrayRef grid_hw);

// v_img per stream: the statistic over the finite d_i (NaN if none is finite).
std::vector<double> image_voxel_size(const at::Tensor& positions, at::IntArrayRef grid_hw,
                                     VoxelStatistic statistic, double percentile);

// The long-term pruning rule on one stream's N tokens; returns the kept indices,
// ascending, int64 [M].
//   Total order of tokens: cumulative attention, then frame index, then `order`
//   (all ascending; the greater token wins every comparison).
//   1. voxel = floor(position / voxel_size); per voxel keep the greatest token.
//      Skipped when voxel_size is not finite and > 0. Tokens with a non-finite
//      position are never merged.
//   2. If more than `capacity` remain, keep the `capacity` greatest.
// positions [N,3], attention [N], frame_index [N], order [N] (distinct values).
at::Tensor select_long_term_tokens(const at::Tensor& positions, const at::Tensor& attention,
                                   const at::Tensor& frame_index, const at::Tensor& order,
                                   double voxel_size, int64_t capacity);

}  // namespace long3r
