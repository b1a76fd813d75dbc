// 3D spatio-temporal memory; see include/long3r/memory/spatio_temporal_memory.hpp.
#include "long3r/memory/spatio_temporal_memory.hpp"

#include <ATen/ATen.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <tuple>
#include <utility>

#include "long3r/memory/spann3r_memory.hpp"  // spann3r_similarity, spann3r_prune_score

namespace long3r {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Keeps floor(position / voxel) inside int64 for any finite input.
constexpr double kVoxelIndexLimit = 4.0e18;

at::Tensor maybe_detach(const at::Tensor& t, bool keep_graph) {
  return keep_graph ? t : t.detach();
}

}  // namespace

// ---------------------------------------------------------------------------
// Free functions.
// ---------------------------------------------------------------------------

at::Tensor token_positions(const at::Tensor& pointmap, const at::Tensor& conf, int64_t patch) {
  TORCH_CHECK(pointmap.dim() == 4 && pointmap.size(3) == 3,
              "token_positions: pointmap must be [B,H,W,3]");
  TORCH_CHECK(conf.dim() == 3 && conf.size(0) == pointmap.size(0) &&
                  conf.size(1) == pointmap.size(1) && conf.size(2) == pointmap.size(2),
              "token_positions: conf must be [B,H,W] matching the pointmap");
  TORCH_CHECK(patch > 0, "token_positions: patch must be positive");
  const int64_t batch = pointmap.size(0);
  const int64_t height = pointmap.size(1);
  const int64_t width = pointmap.size(2);
  TORCH_CHECK(height % patch == 0 && width % patch == 0,
              "token_positions: H and W must be multiples of the patch size");
  const int64_t hp = height / patch;
  const int64_t wp = width / patch;
  const int64_t tokens = hp * wp;
  const int64_t area = patch * patch;

  const at::Tensor pts = pointmap.reshape({batch, hp, patch, wp, patch, 3})
                             .permute({0, 1, 3, 2, 4, 5})
                             .reshape({batch, tokens, area, 3});
  const at::Tensor w = conf.to(pointmap.scalar_type())
                           .reshape({batch, hp, patch, wp, patch})
                           .permute({0, 1, 3, 2, 4})
                           .reshape({batch, tokens, area, 1});
  const at::Tensor num = (pts * w).sum(2);
  const at::Tensor den = w.sum(2);
  const at::Tensor ok = den > 0;
  // Divide by a safe denominator so that the unused branch has no NaN gradient.
  const at::Tensor weighted = num / at::where(ok, den, at::ones_like(den));
  return at::where(ok, weighted, pts.mean(2));
}

at::Tensor neighbour_distances(const at::Tensor& positions, at::IntArrayRef grid_hw) {
  TORCH_CHECK(positions.dim() == 3 && positions.size(2) == 3,
              "neighbour_distances: positions must be [B,P,3]");
  TORCH_CHECK(grid_hw.size() == 2, "neighbour_distances: grid_hw must be {H, W}");
  const int64_t batch = positions.size(0);
  const int64_t height = grid_hw[0];
  const int64_t width = grid_hw[1];
  TORCH_CHECK(height > 0 && width > 0 && height * width == positions.size(1),
              "neighbour_distances: grid H*W must equal the token count");
  TORCH_CHECK(height * width >= 2, "neighbour_distances: a token needs a neighbour");

  const at::Tensor pos = positions.detach().to(at::kDouble).reshape({batch, height, width, 3});
  at::Tensor sum = at::zeros({batch, height, width}, pos.options());
  at::Tensor count = at::zeros({height, width}, pos.options());
  for (int64_t dy = -1; dy <= 1; ++dy) {
    for (int64_t dx = -1; dx <= 1; ++dx) {
      if (dy == 0 && dx == 0) continue;
      // Tokens (y, x) whose neighbour (y + dy, x + dx) exists.
      const int64_t y0 = std::max<int64_t>(0, -dy);
      const int64_t x0 = std::max<int64_t>(0, -dx);
      const int64_t h = height - std::abs(dy);
      const int64_t w = width - std::abs(dx);
      if (h <= 0 || w <= 0) continue;
      const at::Tensor self = pos.narrow(1, y0, h).narrow(2, x0, w);
      const at::Tensor other = pos.narrow(1, y0 + dy, h).narrow(2, x0 + dx, w);
      sum.narrow(1, y0, h).narrow(2, x0, w).add_((self - other).pow(2).sum(-1).sqrt());
      count.narrow(0, y0, h).narrow(1, x0, w).add_(1.0);
    }
  }
  return (sum / count).reshape({batch, height * width});
}

std::vector<double> image_voxel_size(const at::Tensor& positions, at::IntArrayRef grid_hw,
                                     VoxelStatistic statistic, double percentile) {
  TORCH_CHECK(percentile >= 0.0 && percentile <= 100.0,
              "image_voxel_size: percentile must be in [0, 100]");
  const at::Tensor d = neighbour_distances(positions, grid_hw).cpu();
  std::vector<double> out;
  out.reserve(static_cast<size_t>(d.size(0)));
  for (int64_t b = 0; b < d.size(0); ++b) {
    const at::Tensor row = d[b].masked_select(d[b].isfinite());
    if (row.numel() == 0) {
      out.push_back(kNaN);
    } else if (statistic == VoxelStatistic::kMin) {
      out.push_back(row.min().item<double>());
    } else {
      out.push_back(at::quantile(row, percentile / 100.0).item<double>());
    }
  }
  return out;
}

at::Tensor select_long_term_tokens(const at::Tensor& positions, const at::Tensor& attention,
                                   const at::Tensor& frame_index, const at::Tensor& order,
                                   double voxel_size, int64_t capacity) {
  TORCH_CHECK(positions.dim() == 2 && positions.size(1) == 3,
              "select_long_term_tokens: positions must be [N,3]");
  const int64_t n = positions.size(0);
  TORCH_CHECK(attention.dim() == 1 && attention.size(0) == n && frame_index.dim() == 1 &&
                  frame_index.size(0) == n && order.dim() == 1 && order.size(0) == n,
              "select_long_term_tokens: attention, frame_index, order must be [N]");
  TORCH_CHECK(capacity >= 0, "select_long_term_tokens: capacity must be >= 0");
  const at::Device device = positions.device();
  const at::TensorOptions long_opts = at::TensorOptions().dtype(at::kLong).device(device);
  if (n == 0) return at::empty({0}, long_opts);

  // Rank of every token in the total order (attention, frame, order), built by
  // stable sorts from the least to the most significant key.
  const at::Tensor att = attention.detach().to(device, at::kDouble);
  const at::Tensor frame = frame_index.detach().to(device, at::kLong);
  const at::Tensor ord = order.detach().to(device, at::kLong);
  at::Tensor perm = std::get<1>(at::sort(ord, /*stable=*/true, 0, false));
  perm = perm.index_select(
      0, std::get<1>(at::sort(frame.index_select(0, perm), /*stable=*/true, 0, false)));
  perm = perm.index_select(
      0, std::get<1>(at::sort(att.index_select(0, perm), /*stable=*/true, 0, false)));
  at::Tensor rank = at::empty({n}, long_opts);
  rank.index_put_({perm}, at::arange(n, long_opts));

  // Voxel group of each token; by default every token is its own group.
  at::Tensor group = at::arange(n, long_opts);
  int64_t num_groups = n;
  if (std::isfinite(voxel_size) && voxel_size > 0.0) {
    const at::Tensor scaled = positions.detach().to(at::kDouble) / voxel_size;
    const at::Tensor finite = scaled.isfinite().all(1);
    const at::Tensor finite_idx = finite.nonzero().squeeze(1);
    if (finite_idx.numel() > 0) {
      const at::Tensor voxel = scaled.index_select(0, finite_idx)
                                   .floor()
                                   .clamp(-kVoxelIndexLimit, kVoxelIndexLimit)
                                   .to(at::kLong);
      // Voxel ids [0, G) in lexicographic order of the voxel index. When the
      // occupied box is small enough, one int64 per voxel and a 1-D unique
      // give the same ids as unique_dim over the rows, several times faster.
      const at::Tensor lo = std::get<0>(voxel.min(0));
      // The extent decides the packing: one read to the host for all three.
      const at::Tensor extent = (std::get<0>(voxel.max(0)) - lo + 1).to(at::kCPU);
      const int64_t ex = extent[0].item<int64_t>(), ey = extent[1].item<int64_t>(),
                    ez = extent[2].item<int64_t>();
      at::Tensor unique_voxels, voxel_id;
      if (static_cast<double>(ex) * static_cast<double>(ey) * static_cast<double>(ez) < 4.0e18) {
        const at::Tensor v = voxel - lo;
        const at::Tensor packed = (v.select(1, 0) * ey + v.select(1, 1)) * ez + v.select(1, 2);
        std::tie(unique_voxels, voxel_id, std::ignore) =
            at::_unique2(packed, /*sorted=*/true, /*return_inverse=*/true);
      } else {
        std::tie(unique_voxels, voxel_id, std::ignore) =
            at::unique_dim(voxel, 0, /*sorted=*/true, /*return_inverse=*/true);
      }
      // Non-finite tokens keep their own id, shifted past G.
      const int64_t voxels = unique_voxels.size(0);
      group = group + voxels;
      group.index_put_({finite_idx}, voxel_id);
      num_groups = voxels + n;
    }
  }
  // Sorting (group, rank) puts each group's greatest token last in its run.
  TORCH_CHECK(num_groups <= std::numeric_limits<int64_t>::max() / n,
              "select_long_term_tokens: too many tokens");
  const at::Tensor sorted = std::get<0>(at::sort(group * n + rank));
  const at::Tensor sorted_group = at::div(sorted, n, "floor");
  const at::Tensor last =
      at::cat({sorted_group.narrow(0, 1, n - 1) != sorted_group.narrow(0, 0, n - 1),
               at::ones({1}, long_opts.dtype(at::kBool))});
  at::Tensor winners = sorted.masked_select(last).remainder(n);  // ranks of the kept tokens
  if (winners.size(0) > capacity) winners = std::get<0>(winners.topk(capacity));
  return std::get<0>(at::sort(perm.index_select(0, winners)));
}

// ---------------------------------------------------------------------------
// SpatioTemporalMemory.
// ---------------------------------------------------------------------------

template <class F>
SpatioTemporalMemory::Tokens SpatioTemporalMemory::Tokens::zip(const Tokens& other, F f) const {
  Tokens out;
  out.batched = batched;
  const int64_t d = batched ? 1 : 0;  // token dimension of the per-stream fields
  struct Field {
    at::Tensor Tokens::*member;
    int64_t dim;
  };
  const Field fields[] = {{&Tokens::keys, d},      {&Tokens::values, d}, {&Tokens::positions, d},
                          {&Tokens::attention, d}, {&Tokens::frame, 0},  {&Tokens::order, 0},
                          {&Tokens::payload, d}};
  for (const Field& fd : fields) {
    at::Tensor Tokens::*field = fd.member;
    const int64_t dim = fd.dim;
    if ((this->*field).defined()) out.*field = f(this->*field, other.*field, dim);
  }
  return out;
}

template <class F>
SpatioTemporalMemory::Tokens SpatioTemporalMemory::Tokens::map(F f) const {
  return zip(*this, [&](const at::Tensor& t, const at::Tensor&, int64_t dim) { return f(t, dim); });
}

SpatioTemporalMemory::Tokens SpatioTemporalMemory::Tokens::stream(int64_t b) const {
  // Per-stream fields have their tokens on dim 1; frame / order are shared.
  Tokens out = map([&](const at::Tensor& t, int64_t dim) { return dim == 1 ? t[b] : t; });
  out.batched = false;
  return out;
}

SpatioTemporalMemory::Tokens SpatioTemporalMemory::Tokens::empty() const {
  return map([](const at::Tensor& t, int64_t dim) {
    std::vector<int64_t> shape = t.sizes().vec();
    shape[static_cast<size_t>(dim)] = 0;
    return at::empty(shape, t.options());
  });
}

SpatioTemporalMemory::Tokens SpatioTemporalMemory::Tokens::narrow(int64_t start,
                                                                  int64_t length) const {
  return map([&](const at::Tensor& t, int64_t dim) { return t.narrow(dim, start, length); });
}

SpatioTemporalMemory::Tokens SpatioTemporalMemory::Tokens::index_select(
    const at::Tensor& index) const {
  return map(
      [&](const at::Tensor& t, int64_t dim) { return t.index_select(dim, index.to(t.device())); });
}

SpatioTemporalMemory::Tokens SpatioTemporalMemory::Tokens::cat(const Tokens& more) const {
  return zip(more, [](const at::Tensor& a, const at::Tensor& b, int64_t dim) {
    return at::cat({a, b}, dim);
  });
}

SpatioTemporalMemory::SpatioTemporalMemory(SpatioTemporalMemoryConfig config) : config_(config) {
  TORCH_CHECK(config_.short_term_frames >= 0, "SpatioTemporalMemory: K must be >= 0");
  TORCH_CHECK(config_.long_term_capacity >= 0, "SpatioTemporalMemory: L must be >= 0");
  TORCH_CHECK(config_.tau >= 0.0, "SpatioTemporalMemory: tau must be >= 0");
  TORCH_CHECK(config_.voxel_percentile >= 0.0 && config_.voxel_percentile <= 100.0,
              "SpatioTemporalMemory: voxel_percentile must be in [0, 100]");
  TORCH_CHECK(config_.sim_thresh > -1.0 && config_.sim_thresh <= 1.0,
              "SpatioTemporalMemory: sim_thresh must be in (-1, 1]");
}

void SpatioTemporalMemory::reset() {
  batch_ = 0;
  channels_ = 0;
  payload_dim_ = 0;
  frames_added_ = 0;
  next_order_ = 0;
  last_skipped_ = false;
  short_term_ = Tokens();
  short_frame_sizes_.clear();
  streams_.clear();
  layout_ = Layout();
  layout_valid_ = false;
}

namespace {
const char* const kTokenFields[] = {"keys", "values", "positions", "attention", "frame", "order"};
}  // namespace

StateDict SpatioTemporalMemory::state() const {
  StateDict out;
  put_int(out, "batch", batch_);
  if (batch_ == 0) return out;
  put_int(out, "channels", channels_);
  put_int(out, "frames_added", frames_added_);
  put_int(out, "next_order", next_order_);
  put_int(out, "last_skipped", last_skipped_ ? 1 : 0);
  put_int(out, "frame_of_last_add", frame_of_last_add_);
  out["short.frame_sizes"] = at::tensor(
      std::vector<int64_t>(short_frame_sizes_.begin(), short_frame_sizes_.end()), at::kLong);
  auto put_tokens = [&](const std::string& prefix, const Tokens& t) {
    const at::Tensor* fields[] = {&t.keys,      &t.values, &t.positions,
                                  &t.attention, &t.frame,  &t.order};
    for (std::size_t i = 0; i < 6; ++i) out[prefix + kTokenFields[i]] = fields[i]->detach();
  };
  put_tokens("short.", short_term_);
  for (int64_t b = 0; b < batch_; ++b) {
    const Stream& st = streams_[static_cast<size_t>(b)];
    const std::string p = "stream." + std::to_string(b) + ".";
    put_tokens(p + "long.", st.long_term);
    put_real(out, p + "v_img_last", st.v_img_last);
    put_real(out, p + "v_img_sum", st.v_img_sum);
    put_int(out, p + "v_img_count", st.v_img_count);
  }
  return out;
}

void SpatioTemporalMemory::restore(const StateReader& state, const at::TensorOptions& options,
                                   const PayloadFn& payload) {
  constexpr int64_t kMaxBatch = 1 << 16;
  constexpr int64_t kMax = int64_t{1} << 53;
  const int64_t batch = state.integer("batch", 0, kMaxBatch);
  SpatioTemporalMemory m(config_);
  m.training_ = training_;
  if (batch == 0) {
    *this = std::move(m);
    return;
  }
  m.batch_ = batch;
  m.channels_ = state.integer("channels", 1, kMax);
  m.frames_added_ = state.integer("frames_added", 1, kMax);
  m.next_order_ = state.integer("next_order", 0, kMax);
  m.last_skipped_ = state.integer("last_skipped", 0, 1) == 1;
  m.frame_of_last_add_ = state.integer("frame_of_last_add", 0, kMax);
  const at::Tensor sizes = state.int64("short.frame_sizes", {-1});
  int64_t short_tokens = 0;
  for (int64_t i = 0; i < sizes.size(0); ++i) {
    const int64_t n = sizes[i].item<int64_t>();
    if (n <= 0) state.fail("short.frame_sizes", "a frame of " + std::to_string(n) + " tokens");
    short_tokens += n;
    m.short_frame_sizes_.push_back(n);
  }
  if (m.short_frames() > config_.short_term_frames) {
    state.fail("short.frame_sizes", std::to_string(m.short_frames()) +
                                        " short-term frames, more than this memory's K = " +
                                        std::to_string(config_.short_term_frames));
  }
  const int64_t C = m.channels_;
  const at::TensorOptions device_only = at::TensorOptions().device(options.device());
  // One token set: per-stream fields [B?, N, ...], frame / order [N].
  auto read_tokens = [&](const std::string& prefix, bool batched, int64_t n) {
    Tokens t;
    t.batched = batched;
    if (batched) {
      t.keys = state.floating(prefix + "keys", {batch, n, C});
      t.values = state.floating(prefix + "values", {batch, n, C});
      t.positions = state.floating(prefix + "positions", {batch, n, 3}, /*finite=*/false);
      t.attention = state.floating(prefix + "attention", {batch, n});
    } else {
      t.keys = state.floating(prefix + "keys", {n, C});
      t.values = state.floating(prefix + "values", {n, C});
      t.positions = state.floating(prefix + "positions", {n, 3}, /*finite=*/false);
      t.attention = state.floating(prefix + "attention", {n});
    }
    t.frame = state.int64(prefix + "frame", {n});
    t.order = state.int64(prefix + "order", {n});
    t.keys = t.keys.to(options);
    t.values = t.values.to(options);
    t.positions = t.positions.to(device_only);
    t.attention = t.attention.to(device_only.dtype(at::kFloat));
    t.frame = t.frame.to(device_only);
    t.order = t.order.to(device_only);
    return t;
  };
  m.short_term_ = read_tokens("short.", true, short_tokens);
  for (int64_t b = 0; b < batch; ++b) {
    const std::string p = "stream." + std::to_string(b) + ".";
    Stream st;
    const int64_t n = state.has(p + "long.frame") ? state.int64(p + "long.frame", {-1}).size(0) : 0;
    if (n > config_.long_term_capacity) {
      state.fail(p + "long.frame",
                 std::to_string(n) + " long-term tokens, more than this " +
                     "memory's L = " + std::to_string(config_.long_term_capacity));
    }
    st.long_term = read_tokens(p + "long.", false, n);
    st.v_img_last = state.real(p + "v_img_last");
    st.v_img_sum = state.real(p + "v_img_sum");
    st.v_img_count = state.integer(p + "v_img_count", 0, kMax);
    m.streams_.push_back(std::move(st));
  }
  if (payload) {
    m.short_term_.payload = payload(m.short_term_.keys, m.short_term_.values);
    m.payload_dim_ = m.short_term_.payload.size(2);
    for (Stream& st : m.streams_) {
      Tokens& lt = st.long_term;
      lt.payload = lt.size() == 0
                       ? at::empty({0, m.payload_dim_}, m.short_term_.payload.options())
                       : payload(lt.keys.unsqueeze(0), lt.values.unsqueeze(0)).squeeze(0);
    }
  }
  *this = std::move(m);
}

void SpatioTemporalMemory::add_frame(const at::Tensor& keys, const at::Tensor& values,
                                     const at::Tensor& positions, int64_t frame_index,
                                     at::IntArrayRef grid_hw, const at::Tensor& payload) {
  TORCH_CHECK(keys.dim() == 3, "add_frame: keys must be [B,P,C]");
  TORCH_CHECK(values.sizes() == keys.sizes(), "add_frame: values must match keys");
  const int64_t batch = keys.size(0);
  const int64_t tokens = keys.size(1);
  const int64_t channels = keys.size(2);
  TORCH_CHECK(batch > 0 && tokens > 0, "add_frame: empty frame");
  TORCH_CHECK(positions.dim() == 3 && positions.size(0) == batch && positions.size(1) == tokens &&
                  positions.size(2) == 3,
              "add_frame: positions must be [B,P,3]");
  TORCH_CHECK(grid_hw.size() == 2 && grid_hw[0] * grid_hw[1] == tokens,
              "add_frame: grid_hw must be {H, W} with H*W = P");
  if (payload.defined()) {
    TORCH_CHECK(payload.dim() == 3 && payload.size(0) == batch && payload.size(1) == tokens &&
                    payload.size(2) > 0,
                "add_frame: payload must be [B,P,D] with D > 0");
  }
  const at::TensorOptions long_opts = keys.options().dtype(at::kLong);
  Tokens incoming;
  incoming.batched = true;
  incoming.keys = maybe_detach(keys, training_);
  incoming.values = maybe_detach(values, training_);
  incoming.positions = maybe_detach(positions, training_);
  incoming.attention = at::zeros({batch, tokens}, keys.options().dtype(at::kFloat));
  incoming.frame = at::full({tokens}, frame_index, long_opts);
  incoming.order = at::arange(next_order_, next_order_ + tokens, long_opts);
  if (payload.defined()) incoming.payload = maybe_detach(payload, training_);
  if (batch_ == 0) {
    batch_ = batch;
    channels_ = channels;
    payload_dim_ = payload.defined() ? payload.size(2) : 0;
    short_term_ = incoming.empty();
    streams_.assign(static_cast<size_t>(batch), Stream());
    for (Stream& s : streams_) s.long_term = incoming.stream(0).empty();
  }
  TORCH_CHECK(batch == batch_ && channels == channels_,
              "add_frame: batch size and channels are fixed until reset()");
  TORCH_CHECK((payload.defined() ? payload.size(2) : 0) == payload_dim_,
              "add_frame: the payload (given or not, and its D) is fixed until reset()");

  last_skipped_ = false;
  if (config_.long_term_policy == LongTermPolicy::kSpann3r && config_.sim_thresh < 1.0 &&
      !short_frame_sizes_.empty()) {
    // Spann3R's similarity skip against every short-term frame of the same size.
    const at::Tensor k = keys.detach().to(at::kFloat);
    int64_t offset = 0;
    double best = -1.0;
    for (const int64_t n : short_frame_sizes_) {
      if (n == tokens) {
        best = std::max(
            best,
            spann3r_similarity(k, short_term_.keys.narrow(1, offset, n).detach().to(at::kFloat)));
      }
      offset += n;
    }
    if (best > config_.sim_thresh) {
      last_skipped_ = true;
      return;
    }
  }

  const std::vector<double> v_img =
      image_voxel_size(positions, grid_hw, config_.voxel_statistic, config_.voxel_percentile);
  for (int64_t b = 0; b < batch_; ++b) {
    Stream& s = streams_[static_cast<size_t>(b)];
    s.v_img_last = v_img[static_cast<size_t>(b)];
    if (std::isfinite(s.v_img_last)) {
      s.v_img_sum += s.v_img_last;
      ++s.v_img_count;
    }
  }

  // As the stored tensors (a no-op unless a later frame differs).
  incoming.positions = incoming.positions.to(short_term_.positions);
  if (payload_dim_ > 0) incoming.payload = incoming.payload.to(short_term_.payload);
  short_term_ = short_term_.cat(incoming);
  next_order_ += tokens;
  short_frame_sizes_.push_back(tokens);
  ++frames_added_;
  frame_of_last_add_ = frame_index;
  layout_valid_ = false;

  while (short_frames() > config_.short_term_frames) move_oldest_frame_to_long_term();
}

void SpatioTemporalMemory::move_oldest_frame_to_long_term() {
  const int64_t n = short_frame_sizes_.front();
  short_frame_sizes_.pop_front();
  const Tokens oldest = short_term_.narrow(0, n);
  short_term_ = short_term_.narrow(n, short_term_.size() - n);
  const std::vector<double> scene = v_scene();
  for (int64_t b = 0; b < batch_; ++b) {
    Tokens& lt = streams_[static_cast<size_t>(b)].long_term;
    lt = lt.cat(oldest.stream(b));
    const at::Tensor kept =
        config_.long_term_policy == LongTermPolicy::kSpann3r
            // No voxels (NaN size): the L greatest by attention per frame of age.
            ? select_long_term_tokens(
                  lt.positions,
                  spann3r_prune_score(lt.attention.detach().to(at::kDouble),
                                      (frame_of_last_add_ - lt.frame)
                                          .clamp_min(1)
                                          .to(lt.attention.device(), at::kDouble),
                                      /*protect_below=*/0),
                  lt.frame, lt.order, std::numeric_limits<double>::quiet_NaN(),
                  config_.long_term_capacity)
            : select_long_term_tokens(lt.positions, lt.attention, lt.frame, lt.order,
                                      scene[static_cast<size_t>(b)], config_.long_term_capacity);
    if (kept.size(0) < lt.size()) lt = lt.index_select(kept);
  }
  layout_valid_ = false;
}

int64_t SpatioTemporalMemory::short_size() const { return batch_ == 0 ? 0 : short_term_.size(); }

std::vector<int64_t> SpatioTemporalMemory::long_sizes() const {
  std::vector<int64_t> out;
  for (const Stream& s : streams_) out.push_back(s.long_term.frame.size(0));
  return out;
}

std::vector<int64_t> SpatioTemporalMemory::total_sizes() const {
  std::vector<int64_t> out = long_sizes();
  for (int64_t& n : out) n += short_size();
  return out;
}

int64_t SpatioTemporalMemory::padded_size() const {
  int64_t longest = 0;
  for (const Stream& s : streams_) longest = std::max(longest, s.long_term.frame.size(0));
  return short_size() + longest;
}

std::vector<double> SpatioTemporalMemory::last_v_img() const {
  std::vector<double> out;
  for (const Stream& s : streams_) out.push_back(s.v_img_last);
  return out;
}

std::vector<double> SpatioTemporalMemory::v_scene() const {
  std::vector<double> out;
  for (const Stream& s : streams_) {
    out.push_back(s.v_img_count > 0 ? s.v_img_sum / static_cast<double>(s.v_img_count) : kNaN);
  }
  return out;
}

at::Tensor SpatioTemporalMemory::assemble(const at::Tensor& short_part,
                                          const std::vector<at::Tensor>& long_parts,
                                          double pad) const {
  const int64_t total = padded_size();
  std::vector<at::Tensor> rows;
  rows.reserve(long_parts.size());
  for (int64_t b = 0; b < batch_; ++b) {
    const at::Tensor& lp = long_parts[static_cast<size_t>(b)];
    std::vector<at::Tensor> parts = {short_part[b], lp};
    const int64_t missing = total - short_part.size(1) - lp.size(0);
    if (missing > 0) {
      std::vector<int64_t> shape = lp.sizes().vec();
      shape[0] = missing;
      parts.push_back(at::full(shape, pad, lp.options()));
    }
    rows.push_back(at::cat(parts, 0));
  }
  if (rows.size() == 1) return rows[0].unsqueeze(0);
  return at::stack(rows, 0);
}

const SpatioTemporalMemory::Layout& SpatioTemporalMemory::layout() const {
  if (layout_valid_) return layout_;
  std::vector<at::Tensor> long_keys, long_values, long_positions, long_frames, long_valid;
  for (const Stream& s : streams_) {
    long_keys.push_back(s.long_term.keys);
    long_values.push_back(s.long_term.values);
    long_positions.push_back(s.long_term.positions);
    long_frames.push_back(s.long_term.frame);
    long_valid.push_back(
        at::ones({s.long_term.frame.size(0)}, s.long_term.frame.options().dtype(at::kBool)));
  }
  const int64_t ns = short_size();
  layout_.keys = assemble(short_term_.keys, long_keys, 0.0);
  layout_.values = assemble(short_term_.values, long_values, 0.0);
  layout_.positions = assemble(short_term_.positions, long_positions, 0.0);
  layout_.frame = assemble(short_term_.frame.unsqueeze(0).expand({batch_, ns}), long_frames, -1.0);
  layout_.valid = assemble(at::ones({batch_, ns}, short_term_.frame.options().dtype(at::kBool)),
                           long_valid, 0.0);
  layout_valid_ = true;
  return layout_;
}

at::Tensor SpatioTemporalMemory::keys() const { return batch_ == 0 ? at::Tensor() : layout().keys; }
at::Tensor SpatioTemporalMemory::values() const {
  return batch_ == 0 ? at::Tensor() : layout().values;
}
at::Tensor SpatioTemporalMemory::positions() const {
  return batch_ == 0 ? at::Tensor() : layout().positions;
}
at::Tensor SpatioTemporalMemory::frame_indices() const {
  return batch_ == 0 ? at::Tensor() : layout().frame;
}
at::Tensor SpatioTemporalMemory::valid_mask() const {
  return batch_ == 0 ? at::Tensor() : layout().valid;
}

at::Tensor SpatioTemporalMemory::attention() const {
  if (batch_ == 0) return at::Tensor();
  std::vector<at::Tensor> parts;
  for (const Stream& s : streams_) parts.push_back(s.long_term.attention);
  return assemble(short_term_.attention, parts, 0.0);
}

void SpatioTemporalMemory::add_attention(const at::Tensor& increment) {
  TORCH_CHECK(batch_ > 0, "add_attention: memory is empty");
  TORCH_CHECK(
      increment.dim() == 2 && increment.size(0) == batch_ && increment.size(1) == padded_size(),
      "add_attention: increment must be [B,S] in the memory's current layout");
  const at::Tensor inc =
      maybe_detach(increment, training_).to(short_term_.attention.device(), at::kFloat);
  const int64_t ns = short_size();
  short_term_.attention = short_term_.attention + inc.narrow(1, 0, ns);
  for (int64_t b = 0; b < batch_; ++b) {
    Tokens& lt = streams_[static_cast<size_t>(b)].long_term;
    lt.attention = lt.attention + inc[b].narrow(0, ns, lt.attention.size(0));
  }
}

at::Tensor SpatioTemporalMemory::gather_payload(const at::Tensor& index) const {
  TORCH_CHECK(payload_dim_ > 0, "gather_payload: the memory holds no payload");
  TORCH_CHECK(index.dim() == 2 && index.size(0) == batch_,
              "gather_payload: index must be [B,R] with the memory's B");
  const int64_t ns = short_size();
  std::vector<at::Tensor> rows;
  rows.reserve(static_cast<size_t>(batch_));
  for (int64_t b = 0; b < batch_; ++b) {
    const at::Tensor& lt = streams_[static_cast<size_t>(b)].long_term.payload;
    const int64_t nl = lt.size(0);
    const at::Tensor idx = index[b].to(lt.device(), at::kLong);
    // index_select refuses an index out of range (on the device, without
    // reading the index back to the host), so no index is clamped into range.
    if (nl == 0) {
      rows.push_back(short_term_.payload[b].index_select(0, idx));
    } else if (ns == 0) {
      rows.push_back(lt.index_select(0, idx));
    } else {
      // Each part reads its own rows and row 0 for the other part's; each
      // output row keeps the part it belongs to.
      const at::Tensor in_short = idx < ns;
      const at::Tensor from_short =
          short_term_.payload[b].index_select(0, at::where(in_short, idx, at::zeros_like(idx)));
      const at::Tensor from_long =
          lt.index_select(0, at::where(in_short, at::zeros_like(idx), idx - ns));
      rows.push_back(at::where(in_short.unsqueeze(1), from_short, from_long));
    }
  }
  if (rows.size() == 1) return rows[0].unsqueeze(0);
  return at::stack(rows, 0);
}

GatingResult SpatioTemporalMemory::read(const at::Tensor& queries, const at::Tensor& features,
                                        const GatingNorms& norms) {
  if (batch_ == 0) {
    TORCH_CHECK(queries.dim() == 3, "read: queries must be [B,P,C]");
    const at::Tensor none = at::empty({queries.size(0), 0, queries.size(2)}, queries.options());
    return memory_gating(queries, none, none, features, norms, config_.tau, training_);
  }
  // The mask only matters when the streams' long-term sizes differ.
  const std::vector<int64_t> sizes = long_sizes();
  const bool padded =
      std::any_of(sizes.begin(), sizes.end(), [&](int64_t n) { return n != sizes.front(); });
  GatingResult r = memory_gating(queries, keys(), values(), features, norms, config_.tau, training_,
                                 padded ? valid_mask() : at::Tensor());
  add_attention(r.attention_increment);
  return r;
}

}  // namespace long3r
