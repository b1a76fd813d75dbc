// Tests of Spann3R's spatial memory (include/long3r/memory/spann3r_memory.hpp) against
// the official reference runs in the golden spann3r_seq_* cases: reads, the
// similarity check, pruning and the counters, each step in isolation on the
// memory rebuilt from the stored per-step tensors, then a whole run driven by
// the class alone; plus batching and edge cases on small hand-made inputs.
#include <ATen/ATen.h>
#include <c10/core/InferenceMode.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "long3r/memory/spann3r_memory.hpp"
#include "long3r/model/loading/safetensors.hpp"
#include "support/test_support.hpp"

namespace {

using long3r::GatingNorms;
using long3r::Spann3rMemory;
using long3r::Spann3rMemoryConfig;
using long3r::Spann3rMemoryState;

// The golden README's parity tolerance: max|x - ref| / max|ref|.
constexpr double kRelTol = 1e-4;
// check_sim values in case.json are float32 results; their distance to the 0.95
// threshold is >= 1e-3 (>= 0.05 with topk-tied tokens in the window).
constexpr double kSimTol = 1e-5;

using long3r::test::rel_diff;

std::vector<int64_t> to_vec(const at::Tensor& t) {
  const at::Tensor c = t.to(at::kLong).contiguous().reshape({-1});
  return std::vector<int64_t>(c.data_ptr<int64_t>(), c.data_ptr<int64_t>() + c.numel());
}

// One golden case: its io tensors, the model's norm_q/k/v and case.json.
struct Golden {
  std::string name;
  long3r::TensorFile io;
  GatingNorms norms;
  Spann3rMemoryConfig config;
  nlohmann::json memory;  // case.json "memory"
  int64_t steps = 0;
  int64_t patches = 0;

  const at::Tensor& t(const std::string& key) const {
    const auto it = io.tensors.find(key);
    if (it == io.tensors.end()) throw std::runtime_error(name + ": no tensor " + key);
    return it->second;
  }
  int64_t step_value(const std::string& key, int64_t k) const { return t(key)[k].item<int64_t>(); }
  // [1, P, C] inputs of step k.
  at::Tensor key(int64_t k) const { return t("step.feat_k1")[k].unsqueeze(0); }
  at::Tensor value(int64_t k) const {
    return (t("step.cur_v")[k] + t("step.feat_k1")[k]).unsqueeze(0);
  }
  at::Tensor query(int64_t k) const { return t("step.feat_k2")[k].unsqueeze(0); }
  // Index j of the prune that ran at step k (-1 if none).
  int64_t prune_index(int64_t k) const {
    int64_t j = 0;
    for (int64_t s = 0; s < k; ++s) j += step_value("step.pruned", s);
    return step_value("step.pruned", k) ? j : -1;
  }
  const nlohmann::json* check_sim(int64_t k) const {
    for (const auto& e : memory.at("check_sim")) {
      if (e.at("step").get<int64_t>() == k) return &e;
    }
    return nullptr;
  }
};

const Golden& golden(const std::string& name) {
  static std::map<std::string, std::unique_ptr<Golden>> cache;
  auto& slot = cache[name];
  if (slot) return *slot;
  const std::string dir = std::string(LONG3R_GOLDEN_DIR) + "/" + name + "/";
  auto g = std::make_unique<Golden>();
  g->name = name;
  g->io = long3r::load_safetensors(dir + "io.safetensors");
  const long3r::TensorFile w = long3r::load_safetensors(dir + "weights.safetensors");
  auto norm = [&](const std::string& n) {
    return long3r::LayerNormParams{w.tensors.at(n + ".weight"), w.tensors.at(n + ".bias"), 1e-5};
  };
  g->norms = {norm("norm_q"), norm("norm_k"), norm("norm_v")};
  std::ifstream in(dir + "case.json");
  std::stringstream ss;
  ss << in.rdbuf();
  const nlohmann::json cj = nlohmann::json::parse(ss.str());
  const auto& sm = cj.at("config").at("spatial_memory");
  g->config.long_mem_size = sm.at("long_mem_size").get<int64_t>();
  g->config.work_mem_size = sm.at("work_mem_size").get<int64_t>();
  g->config.attn_thresh = sm.at("attn_thresh").get<double>();
  g->config.sim_thresh = sm.at("sim_thresh").get<double>();
  g->config.top_k = sm.at("top_k").get<int64_t>();
  // num_patches stays 0: the official forward takes it from the first key.
  g->patches = sm.at("num_patches").get<int64_t>();
  g->memory = cj.at("memory");
  g->steps = g->t("step.feat_k1").size(0);
  slot = std::move(g);
  return *slot;
}

// The memory after each step, rebuilt as the golden README describes (appends
// of the stored keys and values, gathers with the stored prune indices), with
// the stored counters. ids[m] = step * P + p of the frame token at position m.
struct RefMemory {
  at::Tensor k, v, attn, count;  // [1,M,C], [1,M,C], [1,M], [1,M]
  std::vector<int64_t> ids;
  int64_t wm = 0, lm = 0;
};

std::vector<RefMemory> rebuild(const Golden& g) {
  std::vector<RefMemory> out;
  RefMemory cur;
  for (int64_t k = 0; k < g.steps; ++k) {
    if (g.step_value("step.added", k)) {
      const at::Tensor zeros_count = at::zeros({1, g.patches});
      cur.k = cur.k.defined() ? at::cat({cur.k, g.key(k)}, 1) : g.key(k);
      cur.v = cur.v.defined() ? at::cat({cur.v, g.value(k)}, 1) : g.value(k);
      cur.count = cur.count.defined() ? at::cat({cur.count + 1, zeros_count}, 1) : zeros_count;
      for (int64_t p = 0; p < g.patches; ++p) cur.ids.push_back(k * g.patches + p);
    }
    const int64_t j = g.prune_index(k);
    if (j >= 0) {
      const at::Tensor idx = g.t("prune" + std::to_string(j) + ".indices");
      const auto idx_v = to_vec(idx);
      cur.k = cur.k.index_select(1, idx);
      cur.v = cur.v.index_select(1, idx);
      cur.count = cur.count.index_select(1, idx);
      std::vector<int64_t> ids;
      for (int64_t i : idx_v) ids.push_back(cur.ids[i]);
      cur.ids = ids;
    }
    // The counts follow from the rules above; the stored ones must agree.
    const at::Tensor stored_count = g.t("step" + std::to_string(k) + ".mem_count").unsqueeze(0);
    EXPECT_TRUE(at::equal(cur.count, stored_count)) << g.name << " step " << k;
    cur.attn = g.t("step" + std::to_string(k) + ".mem_attn").unsqueeze(0);
    cur.wm = g.step_value("step.wm", k);
    cur.lm = g.step_value("step.lm", k);
    EXPECT_EQ(cur.k.size(1), g.step_value("step.mem_tokens_after", k));
    out.push_back(cur);
  }
  return out;
}

Spann3rMemoryState to_state(const Golden& g, const RefMemory& r) {
  Spann3rMemoryState s;
  s.keys = r.k;
  s.values = r.v;
  s.mem_attn = r.attn;
  s.mem_count = r.count;
  s.working_frames = r.wm;
  s.long_mem_counter = r.lm;
  s.num_patches = g.patches;
  return s;
}

// Stored mem_attn of the tokens present before step k's add, right after step
// k's read (k >= 1): the prefix of the stored counter after step k, or of the one
// stored just before step k's prune.
at::Tensor attn_after_read(const Golden& g, const std::vector<RefMemory>& ref, int64_t k) {
  const int64_t m = ref[k - 1].k.size(1);
  const int64_t j = g.prune_index(k);
  const at::Tensor a = j >= 0 ? g.t("prune" + std::to_string(j) + ".mem_attn_before")
                              : g.t("step" + std::to_string(k) + ".mem_attn");
  return a.narrow(0, 0, m).unsqueeze(0);
}

// perm with mine[perm[i]] == golden[i]; empty if the two are not the same set.
std::vector<int64_t> match_ids(const std::vector<int64_t>& mine,
                               const std::vector<int64_t>& golden) {
  if (mine.size() != golden.size()) return {};
  std::map<int64_t, int64_t> where;
  for (std::size_t i = 0; i < mine.size(); ++i) where[mine[i]] = static_cast<int64_t>(i);
  std::vector<int64_t> perm;
  for (int64_t id : golden) {
    const auto it = where.find(id);
    if (it == where.end()) return {};
    perm.push_back(it->second);
  }
  return perm;
}

// Compares a prune order with the stored one: the same kept set, the tokens
// tied at 1e8 (protected) first, the others in exactly the stored order. Returns
// whether the whole order, tied tokens included, is the stored one.
bool expect_same_prune(const std::vector<int64_t>& mine, const std::vector<int64_t>& stored,
                       const at::Tensor& count_before, int64_t work_mem_size,
                       const std::string& where) {
  EXPECT_EQ(mine.size(), stored.size()) << where;
  if (mine.size() != stored.size()) return false;
  const auto count = count_before.to(at::kDouble).contiguous();
  const double* c = count.data_ptr<double>();
  auto is_protected = [&](int64_t i) { return c[i] < static_cast<double>(work_mem_size + 5); };
  std::size_t tied = 0;
  while (tied < stored.size() && is_protected(stored[tied])) ++tied;
  for (std::size_t i = tied; i < stored.size(); ++i) {
    EXPECT_FALSE(is_protected(stored[i])) << where << ": protected token after the tied group";
  }
  std::vector<int64_t> a(mine.begin(), mine.begin() + tied),
      b(stored.begin(), stored.begin() + tied);
  std::sort(a.begin(), a.end());
  std::sort(b.begin(), b.end());
  EXPECT_EQ(a, b) << where << ": tied (protected) group";
  EXPECT_EQ(std::vector<int64_t>(mine.begin() + tied, mine.end()),
            std::vector<int64_t>(stored.begin() + tied, stored.end()))
      << where << ": unprotected tokens, descending score";
  return mine == stored;
}

class Spann3rGolden : public ::testing::TestWithParam<const char*> {
 protected:
  const Golden& g() const { return golden(GetParam()); }
};

// Each memory_read on the memory rebuilt from the stored tensors reproduces the
// stored fused features, zero count, near-threshold weights and the mem_attn
// increment.
TEST_P(Spann3rGolden, IsolatedReads) {
  c10::InferenceMode guard;
  const Golden& gd = g();
  const auto ref = rebuild(gd);
  Spann3rMemory mem(gd.norms, gd.config);
  double worst_fuse = 0, worst_attn = 0, worst_near = 0;
  int64_t near_total = 0;
  for (int64_t k = 1; k < gd.steps; ++k) {
    const std::string where =
        gd.name + " read " + std::to_string(k - 1) + " (step " + std::to_string(k) + ")";
    mem.set_state(to_state(gd, ref[k - 1]));
    const at::Tensor out = mem.read(gd.query(k - 1), /*residual=*/true, /*keep_attention=*/true);
    const double d_fuse = rel_diff(out[0], gd.t("read.feat_fuse")[k - 1]);
    EXPECT_LE(d_fuse, kRelTol) << where;
    worst_fuse = std::max(worst_fuse, d_fuse);
    const auto& st = mem.last_read();
    EXPECT_EQ(st.memory_tokens, gd.step_value("read.mem_tokens", k - 1)) << where;
    EXPECT_EQ(st.n_zeroed(), gd.step_value("read.n_zeroed", k - 1)) << where;
    EXPECT_EQ(st.n_empty_rows(), 0) << where;

    // Near-threshold weights: same side of attn_thresh, close values.
    const std::string r = "read" + std::to_string(k - 1);
    const auto idx = to_vec(gd.t(r + ".near_thresh_idx"));
    const at::Tensor near = gd.t(r + ".near_thresh_attn").to(at::kDouble);
    const at::Tensor w = st.attention.to(at::kDouble);
    for (int64_t i = 0; i < near.size(0); ++i) {
      const double mine = w[0][idx[2 * i]][idx[2 * i + 1]].item<double>();
      const double stored = near[i].item<double>();
      // Compared in float, as the read compares.
      const float thresh = static_cast<float>(gd.config.attn_thresh);
      EXPECT_EQ(static_cast<float>(mine) < thresh, static_cast<float>(stored) < thresh)
          << where << " weight (" << idx[2 * i] << ", " << idx[2 * i + 1] << ")";
      const double d = std::abs(mine - stored) / stored;
      EXPECT_LE(d, kRelTol) << where;
      worst_near = std::max(worst_near, d);
      ++near_total;
    }

    const double d_attn = rel_diff(mem.mem_attn(), attn_after_read(gd, ref, k));
    EXPECT_LE(d_attn, kRelTol) << where << ": mem_attn after the read";
    worst_attn = std::max(worst_attn, d_attn);
    // The read leaves everything but mem_attn alone.
    EXPECT_TRUE(at::equal(mem.mem_count(), ref[k - 1].count));
    EXPECT_EQ(mem.size(), ref[k - 1].k.size(1));
  }
  std::printf(
      "[%s] isolated reads: feat_fuse max rel diff %.3g, mem_attn %.3g, %lld near-threshold "
      "weights max rel diff %.3g\n",
      gd.name.c_str(), worst_fuse, worst_attn, static_cast<long long>(near_total), worst_near);
}

// The residual-free read and the increment are W' norm_v(V) and sum_p W'.
TEST_P(Spann3rGolden, ReadWithoutResidual) {
  c10::InferenceMode guard;
  const Golden& gd = g();
  const auto ref = rebuild(gd);
  Spann3rMemory mem(gd.norms, gd.config);
  const int64_t k = gd.steps - 1;
  mem.set_state(to_state(gd, ref[k - 1]));
  const at::Tensor out = mem.read(gd.query(k - 1), /*residual=*/false);
  const at::Tensor expected = gd.t("read.feat_fuse")[k - 1] - gd.query(k - 1)[0];
  EXPECT_LE(rel_diff(out[0], expected), kRelTol);
  EXPECT_EQ(mem.last_read().attention_increment.sizes(), mem.mem_attn().sizes());
  EXPECT_NEAR(mem.last_read().attention_increment.sum().item<double>(),
              static_cast<double>(gd.patches), 1e-3);
  EXPECT_FALSE(mem.last_read().attention.defined());
}

// The stored prune inputs give the stored kept set and order.
TEST_P(Spann3rGolden, PruneOrder) {
  c10::InferenceMode guard;
  const Golden& gd = g();
  const auto& prunes = gd.memory.at("prunes");
  ASSERT_EQ(static_cast<int64_t>(prunes.size()), gd.memory.at("memory_prune_calls").get<int64_t>());
  ASSERT_FALSE(prunes.empty());
  for (std::size_t j = 0; j < prunes.size(); ++j) {
    const std::string p = "prune" + std::to_string(j);
    const at::Tensor attn = gd.t(p + ".mem_attn_before").unsqueeze(0);
    const at::Tensor count = gd.t(p + ".mem_count_before").unsqueeze(0);
    EXPECT_EQ(attn.size(1), prunes[j].at("tokens_before").get<int64_t>());
    EXPECT_EQ((count < static_cast<double>(gd.config.work_mem_size + 5)).sum().item<int64_t>(),
              prunes[j].at("protected_tokens").get<int64_t>());
    const at::Tensor order =
        long3r::spann3r_prune_order(attn, count, gd.config.work_mem_size, gd.config.top_k);
    ASSERT_EQ(order.sizes(), at::IntArrayRef({1, prunes[j].at("tokens_after").get<int64_t>()}));
    const bool same = expect_same_prune(to_vec(order), to_vec(gd.t(p + ".indices")), count[0],
                                        gd.config.work_mem_size, gd.name + " " + p);
    std::printf("[%s] %s: kept set matches; tied-group order %s the stored one\n", gd.name.c_str(),
                p.c_str(), same ? "equals" : "differs from");
  }
}

// Each add_mem_check on the rebuilt memory (with the stored counters after that
// step's read) makes the stored decision, similarity, prune and bookkeeping.
TEST_P(Spann3rGolden, IsolatedAddSteps) {
  c10::InferenceMode guard;
  const Golden& gd = g();
  const auto ref = rebuild(gd);
  Spann3rMemory mem(gd.norms, gd.config);
  double worst_sim = 0, worst_attn = 0;
  for (int64_t k = 0; k < gd.steps; ++k) {
    const std::string where = gd.name + " step " + std::to_string(k);
    std::vector<int64_t> ids;
    if (k == 0) {
      mem.reset();
    } else {
      Spann3rMemoryState s = to_state(gd, ref[k - 1]);
      s.mem_attn = attn_after_read(gd, ref, k);
      mem.set_state(s);
      ids = ref[k - 1].ids;
    }
    const bool added = mem.add_mem_check(gd.key(k), gd.value(k));
    const auto& st = mem.last_add();
    EXPECT_EQ(added, gd.step_value("step.added", k) == 1) << where;
    EXPECT_EQ(st.skipped, !added) << where;
    if (k == 0) {
      EXPECT_FALSE(st.checked);
      EXPECT_TRUE(std::isnan(st.similarity));
    } else {
      const auto* cs = gd.check_sim(k);
      ASSERT_NE(cs, nullptr) << where;
      EXPECT_TRUE(st.checked) << where;
      const double d = std::abs(st.similarity - cs->at("max_mean_corr").get<double>());
      EXPECT_LE(d, kSimTol) << where;
      worst_sim = std::max(worst_sim, d);
      EXPECT_EQ(st.skipped, cs->at("skipped").get<bool>()) << where;
    }
    if (added) {
      for (int64_t p = 0; p < gd.patches; ++p) ids.push_back(k * gd.patches + p);
    }
    const int64_t j = gd.prune_index(k);
    EXPECT_EQ(st.pruned, j >= 0) << where;
    bool same_order = true;
    if (st.pruned && j >= 0) {
      const std::string p = "prune" + std::to_string(j);
      EXPECT_EQ(st.tokens_before_prune, gd.t(p + ".mem_count_before").size(0)) << where;
      const auto kept = to_vec(st.kept_indices);
      same_order = expect_same_prune(kept, to_vec(gd.t(p + ".indices")),
                                     gd.t(p + ".mem_count_before"), gd.config.work_mem_size, where);
      std::vector<int64_t> pruned_ids;
      for (int64_t i : kept) pruned_ids.push_back(ids[i]);
      ids = pruned_ids;
    }
    EXPECT_EQ(mem.size(), gd.step_value("step.mem_tokens_after", k)) << where;
    EXPECT_EQ(mem.working_frames(), gd.step_value("step.wm", k)) << where;
    EXPECT_EQ(mem.long_mem_counter(), gd.step_value("step.lm", k)) << where;
    EXPECT_EQ(mem.num_patches(), gd.patches);
    const auto perm = match_ids(ids, ref[k].ids);
    ASSERT_EQ(perm.size(), ref[k].ids.size()) << where << ": different token sets";
    EXPECT_EQ(same_order, ids == ref[k].ids) << where;
    const at::Tensor pi = at::tensor(perm, at::kLong);
    EXPECT_TRUE(at::equal(mem.mem_count().index_select(1, pi), ref[k].count)) << where;
    EXPECT_TRUE(at::equal(mem.keys().index_select(1, pi), ref[k].k)) << where;
    EXPECT_TRUE(at::equal(mem.values().index_select(1, pi), ref[k].v)) << where;
    const double d = rel_diff(mem.mem_attn().index_select(1, pi), ref[k].attn);
    EXPECT_LE(d, kRelTol) << where;
    worst_attn = std::max(worst_attn, d);
  }
  std::printf(
      "[%s] isolated add_mem_check: similarity max abs diff %.3g, mem_attn max rel diff "
      "%.3g\n",
      gd.name.c_str(), worst_sim, worst_attn);
}

// The class accumulates mem_attn and mem_count like the official run when the
// memory's structure follows the stored one (add_mem, gather by stored indices).
TEST_P(Spann3rGolden, CumulativeCounters) {
  c10::InferenceMode guard;
  const Golden& gd = g();
  const auto ref = rebuild(gd);
  Spann3rMemory mem(gd.norms, gd.config);
  double worst = 0;
  for (int64_t k = 0; k < gd.steps; ++k) {
    if (k > 0) mem.read(gd.query(k - 1));
    if (gd.step_value("step.added", k)) mem.add_mem(gd.key(k), gd.value(k));
    const int64_t j = gd.prune_index(k);
    if (j >= 0) mem.gather(gd.t("prune" + std::to_string(j) + ".indices").unsqueeze(0));
    const std::string where = gd.name + " step " + std::to_string(k);
    EXPECT_TRUE(at::equal(mem.mem_count(), ref[k].count)) << where;
    const double d = rel_diff(mem.mem_attn(), ref[k].attn);
    EXPECT_LE(d, kRelTol) << where;
    worst = std::max(worst, d);
  }
  EXPECT_LE(rel_diff(mem.mem_attn().unsqueeze(-1), gd.t("final_mem.attn")), kRelTol);
  EXPECT_TRUE(at::equal(mem.mem_count().unsqueeze(-1), gd.t("final_mem.count")));
  EXPECT_TRUE(at::equal(mem.keys(), gd.t("final_mem.k")));
  std::printf("[%s] cumulative mem_attn (stored structure): max rel diff %.3g\n", gd.name.c_str(),
              worst);
}

// The whole run driven by the class alone: stored keys, values and queries in,
// every decision and every memory state as in the official run.
TEST_P(Spann3rGolden, EndToEndReplay) {
  c10::InferenceMode guard;
  const Golden& gd = g();
  const auto ref = rebuild(gd);
  Spann3rMemory mem(gd.norms, gd.config);
  std::vector<int64_t> ids;
  double worst_fuse = 0, worst_attn = 0, worst_sim = 0;
  bool order_reproduced = true;
  int64_t n_pruned = 0;
  for (int64_t k = 0; k < gd.steps; ++k) {
    const std::string where = gd.name + " step " + std::to_string(k);
    if (k > 0) {
      const at::Tensor out = mem.read(gd.query(k - 1));
      const double d = rel_diff(out[0], gd.t("read.feat_fuse")[k - 1]);
      EXPECT_LE(d, kRelTol) << where;
      worst_fuse = std::max(worst_fuse, d);
      EXPECT_EQ(mem.last_read().n_zeroed(), gd.step_value("read.n_zeroed", k - 1)) << where;
      EXPECT_EQ(mem.last_read().memory_tokens, gd.step_value("read.mem_tokens", k - 1)) << where;
    }
    // Whether the similarity window holds the stored window's tokens in the
    // stored order (then the value must match, not just the decision).
    bool same_window = true;
    if (k > 0) {
      const std::size_t w = static_cast<std::size_t>(ref[k - 1].wm * gd.patches);
      same_window = ids.size() >= w && ids.size() == ref[k - 1].ids.size() &&
                    std::equal(ids.end() - w, ids.end(), ref[k - 1].ids.end() - w);
    }
    const bool added = mem.add_mem_check(gd.key(k), gd.value(k));
    const auto& st = mem.last_add();
    EXPECT_EQ(added, gd.step_value("step.added", k) == 1) << where;
    if (k > 0) {
      const auto* cs = gd.check_sim(k);
      ASSERT_NE(cs, nullptr);
      EXPECT_EQ(st.skipped, cs->at("skipped").get<bool>()) << where;
      if (same_window) {
        const double d = std::abs(st.similarity - cs->at("max_mean_corr").get<double>());
        EXPECT_LE(d, kSimTol) << where;
        worst_sim = std::max(worst_sim, d);
      }
    }
    if (added) {
      for (int64_t p = 0; p < gd.patches; ++p) ids.push_back(k * gd.patches + p);
    }
    const int64_t j = gd.prune_index(k);
    EXPECT_EQ(st.pruned, j >= 0) << where;
    if (st.pruned) {
      ++n_pruned;
      std::vector<int64_t> kept_ids;
      for (int64_t i : to_vec(st.kept_indices)) kept_ids.push_back(ids[i]);
      ids = kept_ids;
    }
    EXPECT_EQ(mem.size(), gd.step_value("step.mem_tokens_after", k)) << where;
    EXPECT_EQ(mem.working_frames(), gd.step_value("step.wm", k)) << where;
    EXPECT_EQ(mem.long_mem_counter(), gd.step_value("step.lm", k)) << where;
    const auto perm = match_ids(ids, ref[k].ids);
    ASSERT_EQ(perm.size(), ref[k].ids.size()) << where << ": different token sets";
    order_reproduced = order_reproduced && ids == ref[k].ids;
    const at::Tensor pi = at::tensor(perm, at::kLong);
    EXPECT_TRUE(at::equal(mem.mem_count().index_select(1, pi), ref[k].count)) << where;
    const double d = rel_diff(mem.mem_attn().index_select(1, pi), ref[k].attn);
    EXPECT_LE(d, kRelTol) << where;
    worst_attn = std::max(worst_attn, d);
    if (k == gd.steps - 1) {
      EXPECT_TRUE(at::equal(mem.keys().index_select(1, pi), gd.t("final_mem.k"))) << where;
      EXPECT_TRUE(at::equal(mem.values().index_select(1, pi), gd.t("final_mem.v"))) << where;
    }
  }
  EXPECT_EQ(n_pruned, gd.memory.at("memory_prune_calls").get<int64_t>());
  std::printf(
      "[%s] end-to-end replay: feat_fuse max rel diff %.3g, mem_attn %.3g, similarity "
      "max abs diff %.3g, memory order %s\n",
      gd.name.c_str(), worst_fuse, worst_attn, worst_sim,
      order_reproduced ? "identical to the stored one" : "differs (ties)");
}

// B = 2: two streams with the same keys (so the batch-wide similarity skip
// makes the same decisions as each stream alone) and different values and
// queries (so reads, mem_attn and prune choices differ per stream) give, per
// stream, what a B = 1 memory gives.
TEST_P(Spann3rGolden, BatchOfTwoMatchesSingleStreams) {
  c10::InferenceMode guard;
  const Golden& gd = g();
  // Deterministic perturbations (no RNG state shared with other tests).
  const at::Tensor noise =
      at::sin(at::arange(gd.steps * gd.patches * gd.key(0).size(2), at::kFloat) * 0.37)
          .reshape({gd.steps, gd.patches, -1});
  auto value1 = [&](int64_t k) { return gd.value(k) * 0.5 + noise[k].unsqueeze(0); };
  auto query1 = [&](int64_t k) { return gd.query(k) + noise[k].flip({0}).unsqueeze(0); };
  Spann3rMemory a(gd.norms, gd.config), b(gd.norms, gd.config), ab(gd.norms, gd.config);
  bool prune_differs = false;
  for (int64_t k = 0; k < gd.steps; ++k) {
    const std::string where = gd.name + " step " + std::to_string(k);
    if (k > 0) {
      const at::Tensor oa = a.read(gd.query(k - 1));
      const at::Tensor ob = b.read(query1(k - 1));
      const at::Tensor oab = ab.read(at::cat({gd.query(k - 1), query1(k - 1)}, 0));
      EXPECT_LE(rel_diff(oab, at::cat({oa, ob}, 0)), 1e-6) << where;
      EXPECT_EQ(ab.last_read().n_zeroed(), a.last_read().n_zeroed() + b.last_read().n_zeroed());
    }
    const bool added_a = a.add_mem_check(gd.key(k), gd.value(k));
    const bool added_b = b.add_mem_check(gd.key(k), value1(k));
    ASSERT_EQ(added_a, added_b) << where << ": precondition of this test";
    const bool added =
        ab.add_mem_check(at::cat({gd.key(k), gd.key(k)}, 0), at::cat({gd.value(k), value1(k)}, 0));
    EXPECT_EQ(added, added_a) << where;
    EXPECT_EQ(ab.last_add().pruned, a.last_add().pruned) << where;
    EXPECT_EQ(ab.last_add().pruned, b.last_add().pruned) << where;
    if (ab.last_add().pruned) {
      EXPECT_TRUE(at::equal(ab.last_add().kept_indices,
                            at::cat({a.last_add().kept_indices, b.last_add().kept_indices}, 0)))
          << where;
      prune_differs =
          prune_differs || !at::equal(a.last_add().kept_indices, b.last_add().kept_indices);
    }
    ASSERT_EQ(ab.size(), a.size()) << where;
    EXPECT_EQ(ab.batch_size(), 2);
    EXPECT_TRUE(at::equal(ab.keys(), at::cat({a.keys(), b.keys()}, 0))) << where;
    EXPECT_TRUE(at::equal(ab.values(), at::cat({a.values(), b.values()}, 0))) << where;
    EXPECT_TRUE(at::equal(ab.mem_count(), at::cat({a.mem_count(), b.mem_count()}, 0))) << where;
    EXPECT_LE(rel_diff(ab.mem_attn(), at::cat({a.mem_attn(), b.mem_attn()}, 0)), 1e-6) << where;
  }
  // Otherwise the test would not show that streams are pruned independently.
  EXPECT_TRUE(prune_differs);
}

INSTANTIATE_TEST_SUITE_P(GoldenCases, Spann3rGolden,
                         ::testing::Values("spann3r_seq_sq224", "spann3r_seq_land96x64"),
                         [](const ::testing::TestParamInfo<const char*>& info) {
                           return std::string(info.param);
                         });

// ---- Small hand-made cases ----

GatingNorms plain_norms(int64_t c) {
  const long3r::LayerNormParams n{at::ones({c}), at::zeros({c}), 1e-5};
  return {n, n, n};
}

TEST(Spann3rMemory, DefaultsAreTheOfficialOnes) {
  const Spann3rMemoryConfig c;
  EXPECT_EQ(c.long_mem_size, 4000);
  EXPECT_EQ(c.work_mem_size, 5);
  EXPECT_DOUBLE_EQ(c.attn_thresh, 5e-4);
  EXPECT_DOUBLE_EQ(c.sim_thresh, 0.95);
  EXPECT_EQ(c.num_patches, 0);
  const Spann3rMemory mem(plain_norms(4), c);
  EXPECT_EQ(mem.top_k(), 4000);
  EXPECT_TRUE(mem.empty());
  EXPECT_EQ(mem.size(), 0);
}

TEST(Spann3rMemory, ReadOfEmptyMemoryThrowsAndShapesAreChecked) {
  c10::InferenceMode guard;
  Spann3rMemory mem(plain_norms(4));
  EXPECT_THROW(mem.read(at::randn({1, 3, 4})), c10::Error);
  mem.add_mem_check(at::randn({1, 3, 4}), at::randn({1, 3, 4}));
  EXPECT_THROW(mem.read(at::randn({1, 3, 5})), c10::Error);
  EXPECT_THROW(mem.read(at::randn({2, 3, 4})), c10::Error);
  EXPECT_THROW(mem.add_mem_check(at::randn({1, 2, 4}), at::randn({1, 2, 4})), c10::Error);
  EXPECT_THROW(mem.add_mem(at::randn({1, 3, 4}), at::randn({1, 3, 5})), c10::Error);
}

// Frames with orthogonal keys are never similar; a repeated key is skipped,
// sim_thresh = 1 turns the check off.
TEST(Spann3rMemory, SimilaritySkip) {
  c10::InferenceMode guard;
  const at::Tensor eye = at::eye(8).reshape({1, 8, 8});
  auto frame = [&](int64_t i) { return eye.narrow(1, 2 * i, 2); };  // [1, 2, 8]
  Spann3rMemoryConfig cfg;
  cfg.work_mem_size = 2;
  Spann3rMemory mem(plain_norms(8), cfg);
  EXPECT_TRUE(mem.add_mem_check(frame(0), frame(0)));
  EXPECT_EQ(mem.num_patches(), 2);
  EXPECT_TRUE(mem.add_mem_check(frame(1), frame(1)));
  EXPECT_DOUBLE_EQ(mem.last_add().similarity, 0.0);
  EXPECT_FALSE(mem.add_mem_check(frame(1) * 3.0, frame(1)));  // cosine 1
  EXPECT_TRUE(mem.last_add().skipped);
  EXPECT_NEAR(mem.last_add().similarity, 1.0, 1e-6);
  EXPECT_EQ(mem.size(), 4);
  EXPECT_TRUE(at::equal(mem.mem_count(), at::tensor({1.f, 1.f, 0.f, 0.f}).reshape({1, 4})));
  // Frame 0 leaves the working memory window (2 frames) after frame 2 arrives.
  EXPECT_TRUE(mem.add_mem_check(frame(2), frame(2)));
  EXPECT_EQ(mem.working_frames(), 2);
  EXPECT_EQ(mem.long_mem_counter(), 2);
  EXPECT_TRUE(mem.add_mem_check(frame(0), frame(0)));  // only frames 1, 2 compared
  EXPECT_DOUBLE_EQ(mem.last_add().similarity, 0.0);

  cfg.sim_thresh = 1.0;
  Spann3rMemory off(plain_norms(8), cfg);
  EXPECT_TRUE(off.add_mem_check(frame(0), frame(0)));
  EXPECT_TRUE(off.add_mem_check(frame(0), frame(0)));
  EXPECT_FALSE(off.last_add().checked);
  EXPECT_EQ(off.size(), 4);
}

// long_mem_size = 0: the oldest frame leaves once the working memory is full.
TEST(Spann3rMemory, NoLongMemoryDropsOldestFrame) {
  c10::InferenceMode guard;
  Spann3rMemoryConfig cfg;
  cfg.long_mem_size = 0;
  cfg.work_mem_size = 2;
  cfg.sim_thresh = 1.0;
  Spann3rMemory mem(plain_norms(4), cfg);
  std::vector<at::Tensor> keys;
  for (int i = 0; i < 4; ++i) {
    keys.push_back(at::full({1, 3, 4}, static_cast<float>(i)));
    mem.add_mem_check(keys.back(), keys.back());
  }
  EXPECT_EQ(mem.size(), 6);
  EXPECT_EQ(mem.long_mem_counter(), 0);
  EXPECT_FALSE(mem.last_add().pruned);
  EXPECT_TRUE(at::equal(mem.keys(), at::cat({keys[2], keys[3]}, 1)));
  EXPECT_TRUE(
      at::equal(mem.mem_count(), at::tensor({1.f, 1.f, 1.f, 0.f, 0.f, 0.f}).reshape({1, 6})));
}

// A prune keeps protected tokens (count < work_mem_size + 5) first, then the
// others by mem_attn / mem_count, descending, and gathers every tensor.
TEST(Spann3rMemory, PruneKeepsProtectedThenBestScores) {
  c10::InferenceMode guard;
  Spann3rMemoryConfig cfg;
  cfg.work_mem_size = 1;
  cfg.long_mem_size = 8;
  cfg.sim_thresh = 1.0;
  Spann3rMemory mem(plain_norms(2), cfg);
  // 9 frames of 1 token: counts 8..0 (protected: count < 6, 6 tokens).
  for (int i = 0; i < 9; ++i)
    mem.add_mem(at::full({1, 1, 2}, static_cast<float>(i)),
                at::full({1, 1, 2}, static_cast<float>(-i)));
  Spann3rMemoryState s = mem.state();
  s.mem_attn = at::tensor({8.f, 1.4f, 3.5f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f})
                   .reshape({1, 9});  // scores 1, 0.2, 0.5
  s.working_frames = 1;
  s.long_mem_counter = 8;
  mem.set_state(s);
  const Spann3rMemoryState before = mem.state();
  // The 10th frame pushes the counter to 9 > 8: prune to top_k = 8 of 10 tokens.
  ASSERT_TRUE(mem.add_mem_check(at::full({1, 1, 2}, 9.f), at::full({1, 1, 2}, -9.f)));
  const auto& st = mem.last_add();
  ASSERT_TRUE(st.pruned);
  EXPECT_EQ(st.tokens_before_prune, 10);
  const auto kept = to_vec(st.kept_indices);
  ASSERT_EQ(kept.size(), 8u);
  // Counts now 9..0: protected = tokens 4..9 (count < 6), then token 0 (score
  // 8/9) and token 2 (3.5/7); token 1 (1.4/8) and token 3 (count 6, mem_attn 0)
  // are dropped.
  std::vector<int64_t> tied(kept.begin(), kept.begin() + 6);
  std::sort(tied.begin(), tied.end());
  EXPECT_EQ(tied, (std::vector<int64_t>{4, 5, 6, 7, 8, 9}));
  EXPECT_EQ(kept[6], 0);
  EXPECT_EQ(kept[7], 2);
  EXPECT_EQ(mem.size(), 8);
  EXPECT_EQ(mem.long_mem_counter(), 7);  // top_k - wm * P
  const at::Tensor idx = st.kept_indices[0];
  EXPECT_TRUE(at::equal(mem.values()[0], (-mem.keys()[0])));
  EXPECT_TRUE(at::equal(mem.keys()[0].select(1, 0), idx.to(at::kFloat)));
  EXPECT_FLOAT_EQ(mem.mem_attn()[0][6].item<float>(), 8.f);
  EXPECT_FLOAT_EQ(mem.mem_count()[0][7].item<float>(), 7.f);
  // The snapshot taken before is untouched.
  EXPECT_EQ(before.keys.size(1), 9);
  EXPECT_FLOAT_EQ(before.mem_count[0][0].item<float>(), 8.f);
}

// A query whose weights all fall below attn_thresh reads nothing (the official
// code would produce NaN there) and the row is counted.
TEST(Spann3rMemory, AllBelowThresholdRowReadsNothing) {
  c10::InferenceMode guard;
  Spann3rMemoryConfig cfg;
  cfg.attn_thresh = 0.3;  // above 1/M for M = 4 uniform weights
  Spann3rMemory mem(plain_norms(4), cfg);
  const at::Tensor k = at::tensor({1.f, -1.f, 0.f, 0.f, 0.f, 0.f, 1.f, -1.f}).reshape({1, 2, 4});
  mem.add_mem(k, k);
  mem.add_mem(-k, -k);
  // Query orthogonal-ish to every key after the norm: uniform weights 0.25.
  const at::Tensor q = at::tensor({1.f, 1.f, -1.f, -1.f}).reshape({1, 1, 4});
  const at::Tensor out = mem.read(q, /*residual=*/true, /*keep_attention=*/true);
  EXPECT_NEAR(mem.last_read().attention.max().item<float>(), 0.25f, 1e-6);
  EXPECT_EQ(mem.last_read().n_zeroed(), 4);
  EXPECT_EQ(mem.last_read().n_empty_rows(), 1);
  EXPECT_TRUE(at::equal(out, q));
  EXPECT_TRUE(at::equal(mem.mem_attn(), at::zeros({1, 4})));
}

}  // namespace
