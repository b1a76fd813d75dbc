// Spann3R's spatial memory; see include/long3r/memory/spann3r_memory.hpp.
#include "long3r/memory/spann3r_memory.hpp"

#include <ATen/ATen.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace long3r {
namespace {

// F.normalize(x, p=2, dim=-1): x / max(|x|, 1e-12).
at::Tensor l2_normalize(const at::Tensor& x) {
  return x / x.norm(2, {-1}, /*keepdim=*/true).clamp_min(1e-12);
}

int64_t count_of(const at::Tensor& count) { return count.defined() ? count.item<int64_t>() : 0; }

}  // namespace

int64_t Spann3rReadStats::n_zeroed() const { return count_of(zeroed_count); }
int64_t Spann3rReadStats::n_empty_rows() const { return count_of(empty_row_count); }

double spann3r_similarity(const at::Tensor& key, const at::Tensor& window) {
  TORCH_CHECK(key.dim() == 3, "spann3r_similarity: key must be [B,P,C]");
  TORCH_CHECK(window.dim() == 3 && window.size(0) == key.size(0) && window.size(2) == key.size(2),
              "spann3r_similarity: window must be [B,T*P,C] with the key's B and C");
  const int64_t p = key.size(1);
  TORCH_CHECK(p > 0 && window.size(1) > 0 && window.size(1) % p == 0,
              "spann3r_similarity: window length ", window.size(1),
              " is not a positive multiple of P = ", p);
  const at::Tensor w = window.reshape({window.size(0), -1, p, window.size(2)});
  const at::Tensor corr = (l2_normalize(key).unsqueeze(1) * l2_normalize(w)).sum(-1);  // [B,T,P]
  return corr.mean(-1).max().item<double>();
}

at::Tensor spann3r_prune_score(const at::Tensor& attention, const at::Tensor& age,
                               int64_t protect_below) {
  // Protected tokens (age 0 gives 0/0 or x/0 here) are overwritten with 1e8.
  at::Tensor score = attention / age;
  if (protect_below > 0) score.masked_fill_(age < protect_below, 1e8);
  return score;
}

at::Tensor spann3r_prune_order(const at::Tensor& mem_attn, const at::Tensor& mem_count,
                               int64_t work_mem_size, int64_t top_k) {
  TORCH_CHECK(mem_attn.dim() == 2 && mem_count.sizes() == mem_attn.sizes(),
              "spann3r_prune_order: mem_attn and mem_count must both be [B,M]");
  TORCH_CHECK(top_k > 0 && top_k <= mem_attn.size(1), "spann3r_prune_order: top_k = ", top_k,
              " must be in [1, M = ", mem_attn.size(1), "]");
  const at::Tensor score = spann3r_prune_score(mem_attn, mem_count, work_mem_size + 5);
  // Same layout as the official [B, M, 1] call, so that torch orders ties alike.
  const at::Tensor index = std::get<1>(at::topk(score.unsqueeze(-1), top_k, /*dim=*/1,
                                                /*largest=*/true, /*sorted=*/true));
  return index.squeeze(-1);
}

Spann3rMemory::Spann3rMemory(const GatingNorms& norms, const Spann3rMemoryConfig& config)
    : norms_(norms), config_(config) {
  TORCH_CHECK(config_.long_mem_size >= 0, "Spann3rMemory: long_mem_size must be >= 0");
  TORCH_CHECK(config_.work_mem_size >= 0, "Spann3rMemory: work_mem_size must be >= 0");
  TORCH_CHECK(config_.num_patches >= 0, "Spann3rMemory: num_patches must be >= 0");
  reset();
}

int64_t Spann3rMemory::top_k() const {
  return config_.top_k > 0 ? config_.top_k : config_.long_mem_size;
}

void Spann3rMemory::reset() {
  keys_ = values_ = mem_attn_ = mem_count_ = at::Tensor();
  num_patches_ = config_.num_patches;
  working_frames_ = 0;
  long_mem_counter_ = 0;
  last_read_ = Spann3rReadStats();
  last_add_ = Spann3rAddStats();
}

at::Tensor Spann3rMemory::read(const at::Tensor& query, bool residual, bool keep_attention) {
  TORCH_CHECK(!empty(), "Spann3rMemory::read: the memory is empty");
  TORCH_CHECK(query.dim() == 3 && query.size(0) == keys_.size(0) && query.size(2) == keys_.size(2),
              "Spann3rMemory::read: query must be [B,P,C] with B = ", keys_.size(0),
              " and C = ", keys_.size(2), ", got ", query.sizes());
  const GatedRead r = gated_read(
      query, keys_, values_, norms_,
      config_.attn_thresh > 0.0 ? std::optional<double>(config_.attn_thresh) : std::nullopt);
  Spann3rReadStats stats;
  stats.memory_tokens = keys_.size(1);
  if (keep_attention) stats.attention = r.weights;
  if (r.empty_rows.defined()) {
    stats.zeroed_count = (r.weights < config_.attn_thresh).sum();
    stats.empty_row_count = r.empty_rows.sum();
  }
  at::Tensor out = r.readout;
  if (residual) out = out + query;

  stats.attention_increment = r.gated_weights.sum(-2);  // [B, M]
  mem_attn_ = mem_attn_ + stats.attention_increment;
  last_read_ = std::move(stats);
  return out;
}

void Spann3rMemory::add_mem(const at::Tensor& key, const at::Tensor& value) {
  TORCH_CHECK(key.dim() == 3 && key.size(1) > 0, "Spann3rMemory: key must be [B,P,C], got ",
              key.sizes());
  TORCH_CHECK(value.sizes() == key.sizes(), "Spann3rMemory: value ", value.sizes(),
              " must match key ", key.sizes());
  if (num_patches_ == 0) num_patches_ = key.size(1);
  TORCH_CHECK(key.size(1) == num_patches_, "Spann3rMemory: key has ", key.size(1),
              " tokens, the memory holds frames of ", num_patches_);
  // float32 counters and attention sums whatever the keys' precision.
  const at::Tensor zeros = at::zeros({key.size(0), key.size(1)}, key.options().dtype(at::kFloat));
  if (!keys_.defined()) {
    keys_ = key.contiguous().clone();
    values_ = value.contiguous().clone();
    mem_count_ = zeros;
    mem_attn_ = zeros.clone();
    return;
  }
  TORCH_CHECK(key.size(0) == keys_.size(0) && key.size(2) == keys_.size(2), "Spann3rMemory: key ",
              key.sizes(), " does not match the memory ", keys_.sizes());
  keys_ = at::cat({keys_, key}, 1);
  values_ = at::cat({values_, value}, 1);
  mem_count_ = at::cat({mem_count_ + 1, zeros}, 1);
  mem_attn_ = at::cat({mem_attn_, zeros}, 1);
}

bool Spann3rMemory::add_mem_check(const at::Tensor& key, const at::Tensor& value) {
  TORCH_CHECK(key.dim() == 3, "Spann3rMemory::add_mem_check: key must be [B,P,C]");
  if (num_patches_ == 0) num_patches_ = key.size(1);
  Spann3rAddStats stats;
  stats.similarity = std::numeric_limits<double>::quiet_NaN();
  // An all-dropped memory (long_mem_size = work_mem_size = 0) counts as none.
  if (!empty() && config_.sim_thresh != 1.0) {
    TORCH_CHECK(key.size(1) == num_patches_, "Spann3rMemory::add_mem_check: key has ", key.size(1),
                " tokens, the memory holds frames of ", num_patches_);
    // As the official slice mem_k[:, -wm*P:], where -0 means "everything".
    const int64_t window = working_frames_ * num_patches_;
    const int64_t start = window == 0 ? 0 : std::max<int64_t>(0, size() - window);
    stats.checked = true;
    stats.similarity = spann3r_similarity(key, keys_.narrow(1, start, size() - start));
    stats.skipped = stats.similarity > config_.sim_thresh;
  }
  if (stats.skipped) {
    last_add_ = std::move(stats);
    return false;
  }

  add_mem(key, value);
  ++working_frames_;
  if (working_frames_ > config_.work_mem_size) {
    --working_frames_;
    if (config_.long_mem_size == 0) {
      // No long memory: the oldest frame leaves.
      const int64_t keep = size() - num_patches_;
      keys_ = keys_.narrow(1, num_patches_, keep);
      values_ = values_.narrow(1, num_patches_, keep);
      mem_count_ = mem_count_.narrow(1, num_patches_, keep);
      mem_attn_ = mem_attn_.narrow(1, num_patches_, keep);
    } else {
      long_mem_counter_ += num_patches_;
    }
  }
  if (long_mem_counter_ > config_.long_mem_size) {
    stats.pruned = true;
    stats.tokens_before_prune = size();
    stats.kept_indices = spann3r_prune_order(mem_attn_, mem_count_, config_.work_mem_size, top_k());
    gather(stats.kept_indices);
    long_mem_counter_ = top_k() - working_frames_ * num_patches_;
  }
  last_add_ = std::move(stats);
  return true;
}

void Spann3rMemory::gather(const at::Tensor& index) {
  TORCH_CHECK(keys_.defined(), "Spann3rMemory::gather: the memory is empty");
  TORCH_CHECK(
      index.dim() == 2 && index.size(0) == keys_.size(0) && index.scalar_type() == at::kLong,
      "Spann3rMemory::gather: index must be [B,R] int64 with B = ", keys_.size(0));
  const at::Tensor idx = index.to(keys_.device());
  const at::Tensor idx_c = idx.unsqueeze(-1).expand({-1, -1, keys_.size(2)});
  keys_ = at::gather(keys_, 1, idx_c);
  values_ = at::gather(values_, 1, idx_c);
  mem_attn_ = at::gather(mem_attn_, 1, idx);
  mem_count_ = at::gather(mem_count_, 1, idx);
}

Spann3rMemoryState Spann3rMemory::state() const {
  Spann3rMemoryState s;
  s.keys = keys_;
  s.values = values_;
  s.mem_attn = mem_attn_;
  s.mem_count = mem_count_;
  s.working_frames = working_frames_;
  s.long_mem_counter = long_mem_counter_;
  s.num_patches = num_patches_;
  return s;
}

void Spann3rMemory::set_state(const Spann3rMemoryState& s) {
  if (!s.keys.defined()) {
    reset();
    return;
  }
  TORCH_CHECK(s.keys.dim() == 3, "Spann3rMemory::set_state: keys must be [B,M,C]");
  TORCH_CHECK(s.values.defined() && s.values.sizes() == s.keys.sizes(),
              "Spann3rMemory::set_state: values must match keys");
  const std::vector<int64_t> bm = {s.keys.size(0), s.keys.size(1)};
  TORCH_CHECK(s.mem_attn.defined() && s.mem_attn.sizes() == at::IntArrayRef(bm) &&
                  s.mem_count.defined() && s.mem_count.sizes() == at::IntArrayRef(bm),
              "Spann3rMemory::set_state: mem_attn and mem_count must be [B,M]");
  const auto device = s.keys.device();
  TORCH_CHECK(s.values.device() == device && s.mem_attn.device() == device &&
                  s.mem_count.device() == device,
              "Spann3rMemory::set_state: all tensors must be on one device");
  TORCH_CHECK(s.working_frames >= 0 && s.long_mem_counter >= 0 && s.num_patches >= 0,
              "Spann3rMemory::set_state: negative counter");
  keys_ = s.keys;
  values_ = s.values;
  mem_attn_ = s.mem_attn;
  mem_count_ = s.mem_count;
  working_frames_ = s.working_frames;
  long_mem_counter_ = s.long_mem_counter;
  num_patches_ = s.num_patches;
  last_read_ = Spann3rReadStats();
  last_add_ = Spann3rAddStats();
}

}  // namespace long3r
