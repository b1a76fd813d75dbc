// long3r_golden: numerical parity of the inference engine against golden
// reference cases (official DUSt3R / Spann3R runs; format described in
// test/data/golden/README.md).
//
//   long3r_golden [--tol T] [--device D] [--precision P] CASE_DIR...
//
// Each CASE_DIR holds weights.safetensors (state_dict + config metadata) and
// io.safetensors (inputs, outputs, intermediates). The case kind, widths,
// depths, image sizes and memory settings all come from those files. Every
// stored tensor is compared: one line per tensor
//   name  max|diff|/max|ref|  OK/FAIL
// Exit status: 0 when every tensor is within the tolerance (relative, default
// 1e-4) and none was left uncompared; 1 otherwise; 2 on bad usage.
// --precision bfloat16 / float16 (and --device) run the same cases converted
// to that precision, to measure its deviation: each line then shows how far
// that precision moves the tensor from the official float32 run. The verdict
// (and --tol) then covers the model's outputs only (pred.*, res1.*, res2.*);
// intermediates and the memory's discrete decisions (tokens near attn_thresh,
// pruned sets), which a lower precision legitimately flips, are printed as
// "info".
#include <ATen/ATen.h>
#include <ATen/Context.h>
#include <c10/core/InferenceMode.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <iostream>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "long3r/config/cli_options.hpp"
#include "long3r/model/loading/safetensors.hpp"
#include "long3r/model/network/dust3r_model.hpp"
#include "long3r/model/network/model_config.hpp"
#include "long3r/model/network/spann3r_model.hpp"
#include "long3r/model/runtime/inference.hpp"

namespace {

using long3r::TensorMap;

std::string shape_str(const at::Tensor& t) {
  std::string s = "[";
  for (int64_t k = 0; k < t.dim(); ++k) s += (k ? ", " : "") + std::to_string(t.size(k));
  return s + "]";
}

// Collects the per-tensor verdicts of one case.
class Report {
 public:
  // outputs_only: only the model outputs decide (reduced precision).
  Report(const TensorMap& ref, double tol, bool outputs_only)
      : ref_(ref), tol_(tol), outputs_only_(outputs_only) {}

  // Relative max difference of a float tensor (integers: exact).
  void compare(const std::string& name, const at::Tensor& got) { compare_as(name, ref(name), got); }

  void compare_as(const std::string& name, const at::Tensor& want, const at::Tensor& got,
                  const std::string& note = "") {
    done_.insert(name);
    if (!got.defined()) return line(name, "missing in the port", false);
    const at::Tensor w = want.cpu(), g = got.detach().cpu();
    if (!w.sizes().equals(g.sizes())) {
      return line(name, "shape " + shape_str(g) + " vs reference " + shape_str(w), false);
    }
    if (!at::isFloatingType(w.scalar_type())) {
      const int64_t bad = w.numel() == 0 ? 0 : w.ne(g.to(w.scalar_type())).sum().item<int64_t>();
      return line(name, bad == 0 ? "exact" : std::to_string(bad) + " entries differ", bad == 0,
                  note);
    }
    if (w.numel() == 0) return line(name, "empty", true, note);
    const at::Tensor wd = w.to(at::kDouble), gd = g.to(at::kDouble);
    const double scale = wd.abs().max().item<double>();
    const double diff = (wd - gd).abs().max().item<double>();
    const double rel = scale > 0 ? diff / scale : diff;
    if (!std::isfinite(rel)) return line(name, "non-finite values", false, note);
    char buf[64];
    std::snprintf(buf, sizeof(buf), "%.3e", rel);
    if (judged(name)) worst_ = std::max(worst_, rel);
    line(name, buf, rel <= tol_, note);
  }

  // A tensor checked in another way (inputs, bookkeeping), with its verdict.
  void check(const std::string& name, bool ok, const std::string& what) {
    done_.insert(name);
    line(name, what, ok);
  }

  const at::Tensor& ref(const std::string& name) const {
    const auto it = ref_.find(name);
    if (it == ref_.end()) throw std::runtime_error("reference tensor " + name + " missing");
    return it->second;
  }
  bool has(const std::string& name) const { return ref_.count(name) != 0; }

  // Lists reference tensors nothing compared; returns the number of failures.
  int finish() {
    for (const auto& kv : ref_) {
      if (done_.count(kv.first) == 0) {
        std::printf("%-34s  %-12s  FAIL (stored tensor not compared)\n", kv.first.c_str(), "-");
        ++failures_;
      }
    }
    return failures_;
  }
  double worst() const { return worst_; }

 private:
  bool judged(const std::string& name) const {
    if (!outputs_only_) return true;
    for (const char* prefix : {"pred.", "res1.", "res2."}) {
      if (name.rfind(prefix, 0) == 0) return true;
    }
    return false;
  }
  void line(const std::string& name, const std::string& value, bool ok,
            const std::string& note = "") {
    const bool counts = judged(name);
    if (!ok && counts) ++failures_;
    std::printf("%-34s  %-12s  %s%s%s\n", name.c_str(), value.c_str(),
                !counts ? "info" : (ok ? "OK" : "FAIL"), note.empty() ? "" : "  ", note.c_str());
  }

  const TensorMap& ref_;
  double tol_;
  bool outputs_only_;
  std::set<std::string> done_;
  int failures_ = 0;
  double worst_ = 0.0;
};

// true_shape rows must be the (H, W) of the images they describe.
void check_true_shape(Report& r, const std::string& name, const at::Tensor& images) {
  const at::Tensor ts = r.ref(name);
  bool ok = ts.dim() == 2 && ts.size(0) == images.size(0) && ts.size(1) == 2;
  if (ok) {
    const at::Tensor want =
        at::tensor({images.size(2), images.size(3)}, at::kLong).expand({images.size(0), 2});
    ok = ts.to(at::kLong).equal(want);
  }
  r.check(name, ok, ok ? "input" : "inconsistent with the images");
}

void run_dust3r_pair(const long3r::ModelConfig& config, const long3r::TensorFile& weights,
                     const std::string& source, const long3r::InferenceTarget& target, Report& r) {
  long3r::Dust3rModel model(config);
  model.load_weights(weights.tensors, source);
  model.to(target);
  const at::Tensor img1 = r.ref("view1.img"), img2 = r.ref("view2.img");
  r.check("view1.img", true, "input");
  r.check("view2.img", true, "input");
  check_true_shape(r, "view1.true_shape", img1);
  check_true_shape(r, "view2.true_shape", img2);
  TensorMap got;
  model.infer(img1, img2, long3r::Trace(&got));
  for (const auto& kv : got) {
    if (r.has(kv.first)) r.compare(kv.first, kv.second);
  }
}

// ---------------------------------------------------------------------------
// Spann3R sequences.
//
// Memory tensors are compared token by token through token identities: token
// p of the frame added at step k is k * P + p in both runs. The reference
// order is rebuilt from step.added / step.pruned / prune{j}.indices (README:
// "The memory can be rebuilt from the per-step tensors"), the port's from its
// own memory. A prune orders the tokens tied at score 1e8 in a torch-specific
// way, so memory contents are compared after aligning the port's tokens to the
// reference order; a different token set is a failure.

std::vector<int64_t> to_vec(const at::Tensor& t) {
  const at::Tensor c = t.to(at::kLong).contiguous().cpu();
  return std::vector<int64_t>(c.data_ptr<int64_t>(), c.data_ptr<int64_t>() + c.numel());
}

at::Tensor int_tensor(const std::vector<int64_t>& v) {
  return at::tensor(v, at::TensorOptions().dtype(at::kLong));
}

// Positions in `mine` of the reference tokens, or empty if the sets differ.
std::vector<int64_t> alignment(const std::vector<int64_t>& mine, const std::vector<int64_t>& ref) {
  if (mine.size() != ref.size()) return {};
  std::map<int64_t, int64_t> pos;
  for (std::size_t i = 0; i < mine.size(); ++i) pos[mine[i]] = static_cast<int64_t>(i);
  std::vector<int64_t> perm;
  for (int64_t id : ref) {
    const auto it = pos.find(id);
    if (it == pos.end()) return {};
    perm.push_back(it->second);
  }
  return perm;
}

bool is_identity(const std::vector<int64_t>& perm) {
  for (std::size_t i = 0; i < perm.size(); ++i) {
    if (perm[i] != static_cast<int64_t>(i)) return false;
  }
  return true;
}

// Compares a per-token tensor (tokens along `dim`) after aligning the port's
// tokens to the reference order.
void compare_tokens(Report& r, const std::string& name, const at::Tensor& want,
                    const at::Tensor& got, int64_t dim, const std::vector<int64_t>& my_ids,
                    const std::vector<int64_t>& ref_ids) {
  if (!got.defined() || got.size(dim) != static_cast<int64_t>(my_ids.size())) {
    return r.check(name, false, "port memory size differs");
  }
  const std::vector<int64_t> perm = alignment(my_ids, ref_ids);
  if (perm.empty() && !ref_ids.empty()) {
    return r.check(name, false,
                   "token sets differ (" + std::to_string(my_ids.size()) + " vs " +
                       std::to_string(ref_ids.size()) + " tokens)");
  }
  const at::Tensor aligned = got.index_select(dim, int_tensor(perm).to(got.device()));
  r.compare_as(name, want, aligned, is_identity(perm) ? "" : "(token order aligned)");
}

struct PortPrune {
  int64_t step = 0;
  std::vector<int64_t> ids_before;       // token ids before the prune, memory order
  std::vector<int64_t> kept;             // indices the port kept, its order
  at::Tensor count_before, attn_before;  // [M]
};

void run_spann3r_sequence(const long3r::ModelConfig& config, const long3r::TensorFile& weights,
                          const std::string& source, const long3r::InferenceTarget& target,
                          Report& r) {
  long3r::Spann3rModel model(config);
  model.load_weights(weights.tensors, source);
  model.to(target);
  const at::Tensor frames = r.ref("frames.img");
  r.check("frames.img", true, "input");
  check_true_shape(r, "frames.true_shape", frames);
  const int64_t N = frames.size(0);
  if (N < 2) throw std::runtime_error("a sequence needs at least 2 frames");
  const double thresh = config.spatial_memory.attn_thresh;
  const int64_t protect_below = config.spatial_memory.work_mem_size + 5;

  TensorMap got;
  model.set_trace(long3r::Trace(&got));
  const std::vector<int64_t> ref_added = to_vec(r.ref("step.added"));
  const std::vector<int64_t> ref_pruned = to_vec(r.ref("step.pruned"));

  std::vector<at::Tensor> pts, conf;
  std::vector<int64_t> mem_after, added, pruned, wm, lm, read_tokens, read_zeroed;
  std::vector<int64_t> my_ids, ref_ids;
  std::vector<PortPrune> port_prunes;
  std::vector<std::vector<int64_t>> ref_ids_before_prune;  // per reference prune
  long3r::Spann3rMemoryState prev;
  int ref_prune_j = 0;
  long3r::Spann3rMemoryState final_state;

  for (int64_t i = 0; i < N; ++i) {
    const auto out = model.push(frames.narrow(0, i, 1));
    if (i == 0) {
      if (out) throw std::runtime_error("the first frame produced an output");
      continue;
    }
    if (!out) throw std::runtime_error("step " + std::to_string(i - 1) + " produced no output");
    const int64_t k = i - 1;
    pts.push_back(out->pts3d);
    conf.push_back(out->conf);
    const long3r::Spann3rMemory& m = model.memory();
    const int64_t P = m.num_patches();

    if (k >= 1) {
      // Read of step k: memory after step k-1, query feat_k2 of step k-1.
      const long3r::Spann3rReadStats& rd = m.last_read();
      read_tokens.push_back(rd.memory_tokens);
      read_zeroed.push_back(rd.n_zeroed());
      const std::string base = "read" + std::to_string(k - 1) + ".";
      if (r.has(base + "near_thresh_idx")) {
        const at::Tensor idx = r.ref(base + "near_thresh_idx");
        const at::Tensor want = r.ref(base + "near_thresh_attn");
        const std::vector<int64_t> perm = alignment(my_ids, ref_ids);
        const at::Tensor attn = rd.attention.defined() ? rd.attention.cpu() : at::Tensor();
        std::vector<float> mine;
        bool ok = attn.defined() && (idx.size(0) == 0 || !perm.empty());
        int64_t flipped = 0;
        for (int64_t e = 0; ok && e < idx.size(0); ++e) {
          const int64_t p = idx[e][0].item<int64_t>(), x = idx[e][1].item<int64_t>();
          const float w = attn[0][p][perm.at(static_cast<std::size_t>(x))].item<float>();
          mine.push_back(w);
          const bool kept_ref = want[e].item<double>() >= thresh, kept_mine = w >= thresh;
          if (kept_ref != kept_mine) ++flipped;
        }
        if (!ok) {
          r.check(base + "near_thresh_idx", false, "port attention unavailable");
          r.check(base + "near_thresh_attn", false, "port attention unavailable");
        } else {
          r.check(base + "near_thresh_idx", flipped == 0,
                  std::to_string(idx.size(0)) + " near, " + std::to_string(flipped) +
                      " on the other side of attn_thresh");
          r.compare_as(base + "near_thresh_attn", want,
                       at::tensor(mine, at::TensorOptions().dtype(at::kFloat)));
        }
      }
    }

    // Update of step k.
    const long3r::Spann3rAddStats& ad = m.last_add();
    std::vector<int64_t> my_before = my_ids, ref_before = ref_ids;
    if (!ad.skipped) {
      for (int64_t p = 0; p < P; ++p) my_before.push_back(k * P + p);
    }
    if (k < static_cast<int64_t>(ref_added.size()) && ref_added[k] != 0) {
      for (int64_t p = 0; p < P; ++p) ref_before.push_back(k * P + p);
    }
    my_ids = my_before;
    if (ad.pruned) {
      PortPrune pr;
      pr.step = k;
      pr.ids_before = my_before;
      pr.kept = to_vec(ad.kept_indices[0]);
      // The memory just before the prune: the previous state, this step's
      // read increment, one more frame of age, and the new tokens at zero.
      at::Tensor count = prev.mem_count.defined() ? prev.mem_count[0] + 1 : at::empty({0});
      at::Tensor attn = prev.mem_attn.defined() ? prev.mem_attn[0] : at::empty({0});
      if (k >= 1 && attn.numel() > 0) attn = attn + m.last_read().attention_increment[0];
      pr.count_before = at::cat({count.cpu(), at::zeros({P})});
      pr.attn_before = at::cat({attn.cpu(), at::zeros({P})});
      // Self-check of that reconstruction against what the prune kept.
      const at::Tensor kept = int_tensor(pr.kept);
      if (!pr.count_before.index_select(0, kept).equal(m.mem_count()[0].cpu()) ||
          !pr.attn_before.index_select(0, kept).equal(m.mem_attn()[0].cpu())) {
        throw std::runtime_error("pre-prune memory of step " + std::to_string(k) +
                                 " could not be reconstructed");
      }
      my_ids.clear();
      for (int64_t j : pr.kept) my_ids.push_back(my_before.at(static_cast<std::size_t>(j)));
      port_prunes.push_back(std::move(pr));
    }
    ref_ids = ref_before;
    if (k < static_cast<int64_t>(ref_pruned.size()) && ref_pruned[k] != 0) {
      const std::string name = "prune" + std::to_string(ref_prune_j) + ".indices";
      ref_ids_before_prune.push_back(ref_before);
      ref_ids.clear();
      if (r.has(name)) {
        for (int64_t j : to_vec(r.ref(name)))
          ref_ids.push_back(ref_before.at(static_cast<std::size_t>(j)));
      }
      ++ref_prune_j;
    }

    mem_after.push_back(m.size());
    added.push_back(ad.skipped ? 0 : 1);
    pruned.push_back(ad.pruned ? 1 : 0);
    wm.push_back(m.working_frames());
    lm.push_back(m.long_mem_counter());
    const std::string sk = "step" + std::to_string(k) + ".";
    if (r.has(sk + "mem_count")) {
      compare_tokens(r, sk + "mem_count", r.ref(sk + "mem_count"), m.mem_count()[0], 0, my_ids,
                     ref_ids);
    }
    if (r.has(sk + "mem_attn")) {
      compare_tokens(r, sk + "mem_attn", r.ref(sk + "mem_attn"), m.mem_attn()[0], 0, my_ids,
                     ref_ids);
    }
    prev = m.state();
    final_state = prev;
  }
  const auto last = model.flush();
  if (!last) throw std::runtime_error("flush produced no output");
  pts.push_back(last->pts3d);
  conf.push_back(last->conf);

  // Stacked per-step tensors.
  auto stack = [&](const std::string& suffix, int64_t first_step) {
    std::vector<at::Tensor> parts;
    for (int64_t k = first_step; k < N - 1; ++k) {
      const auto it = got.find("step" + std::to_string(k) + "." + suffix);
      if (it == got.end()) return at::Tensor();
      parts.push_back(it->second);
    }
    return at::cat(parts);
  };
  r.compare("pred.pts3d", at::cat(pts));
  r.compare("pred.conf", at::cat(conf));
  r.compare("step.feat_k1", stack("feat_k1", 0));
  r.compare("step.feat_k2", stack("feat_k2", 0));
  r.compare("step.cur_v", stack("cur_v", 0));
  if (N > 2) r.compare("read.feat_fuse", stack("feat_fuse", 1));
  r.compare("read.mem_tokens", int_tensor(read_tokens));
  r.compare("read.n_zeroed", int_tensor(read_zeroed));
  r.compare("step.mem_tokens_after", int_tensor(mem_after));
  r.compare("step.added", int_tensor(added));
  r.compare("step.pruned", int_tensor(pruned));
  r.compare("step.wm", int_tensor(wm));
  r.compare("step.lm", int_tensor(lm));

  for (int j = 0; r.has("prune" + std::to_string(j) + ".indices"); ++j) {
    const std::string base = "prune" + std::to_string(j) + ".";
    if (j >= static_cast<int>(port_prunes.size())) {
      for (const char* n : {"step", "indices", "mem_count_before", "mem_attn_before"}) {
        r.check(base + n, false, "the port did not prune");
      }
      continue;
    }
    const PortPrune& pr = port_prunes[static_cast<std::size_t>(j)];
    r.compare(base + "step", int_tensor({pr.step}));
    const std::vector<int64_t>& ref_before = ref_ids_before_prune.at(static_cast<std::size_t>(j));
    // Kept tokens: the same set; those tied at 1e8 (protected) first in any
    // order, the rest in the same (descending score) order.
    const at::Tensor ref_count = r.ref(base + "mem_count_before");
    std::vector<int64_t> ref_kept, my_kept;
    for (int64_t x : to_vec(r.ref(base + "indices")))
      ref_kept.push_back(ref_before.at(static_cast<std::size_t>(x)));
    for (int64_t x : pr.kept) my_kept.push_back(pr.ids_before.at(static_cast<std::size_t>(x)));
    int64_t n_tied = 0;
    for (int64_t x : to_vec(r.ref(base + "indices"))) {
      if (ref_count[x].item<double>() < static_cast<double>(protect_below)) ++n_tied;
    }
    std::vector<int64_t> a = ref_kept, b = my_kept;
    std::sort(a.begin(), a.end());
    std::sort(b.begin(), b.end());
    bool ok = a == b;
    std::string what = ok ? "same set" : "kept sets differ";
    if (ok) {
      std::vector<int64_t> ta(ref_kept.begin(), ref_kept.begin() + n_tied);
      std::vector<int64_t> tb(my_kept.begin(), my_kept.begin() + n_tied);
      std::sort(ta.begin(), ta.end());
      std::sort(tb.begin(), tb.end());
      const bool tail_same =
          std::equal(ref_kept.begin() + n_tied, ref_kept.end(), my_kept.begin() + n_tied);
      ok = ta == tb && tail_same;
      what += ref_kept == my_kept ? ", same order"
                                  : (ok ? ", tied group in another order" : ", order differs");
    }
    r.check(base + "indices", ok, what);
    compare_tokens(r, base + "mem_count_before", ref_count, pr.count_before, 0, pr.ids_before,
                   ref_before);
    compare_tokens(r, base + "mem_attn_before", r.ref(base + "mem_attn_before"), pr.attn_before, 0,
                   pr.ids_before, ref_before);
  }

  compare_tokens(r, "final_mem.k", r.ref("final_mem.k"), final_state.keys, 1, my_ids, ref_ids);
  compare_tokens(r, "final_mem.v", r.ref("final_mem.v"), final_state.values, 1, my_ids, ref_ids);
  compare_tokens(r, "final_mem.count", r.ref("final_mem.count"),
                 final_state.mem_count.unsqueeze(-1), 1, my_ids, ref_ids);
  compare_tokens(r, "final_mem.attn", r.ref("final_mem.attn"), final_state.mem_attn.unsqueeze(-1),
                 1, my_ids, ref_ids);
}

}  // namespace

int main(int argc, char** argv) {
  double tol = 1e-4;
  std::vector<std::string> dirs;
  long3r::CliOptions cli(
      "long3r_golden",
      "Compares every tensor of each golden case (see test/data/golden/README.md)."
      " Exit status 0 when all are within the tolerance, 1 otherwise.");
  cli.positional("CASE_DIR", &dirs, "weights.safetensors and io.safetensors of one case")
      .required();
  cli.option("--tol", "T", &tol, "relative tolerance").above(0);
  bool skip_unsupported = false;
  cli.flag("--skip-unsupported", &skip_unsupported,
           "exit 77 (ctest's skip) when this machine cannot serve --device / --precision, e.g. "
           "bfloat16 without native support, instead of 2");
  long3r::InferenceConfig inference;
  long3r::add_inference_options(cli, &inference);
  if (const auto rc = cli.parse_or_exit(argc, argv)) return *rc;
  long3r::InferenceTarget target;
  // Parity in full float32 on a GPU too: no TF32 matmuls or convolutions.
  at::globalContext().setAllowTF32CuBLAS(false);
  at::globalContext().setAllowTF32CuDNN(false);
  try {
    target = long3r::resolve_inference_target(inference);
  } catch (const long3r::InferenceUnsupportedError& e) {
    std::fprintf(stderr, "long3r_golden: %s%s\n", skip_unsupported ? "skipped: " : "", e.what());
    return skip_unsupported ? 77 : 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "long3r_golden: %s\n", e.what());
    return 2;
  }
  std::printf("cpu %s\n", long3r::describe_cpu().c_str());
  std::printf("running in %s\n", long3r::describe(target).c_str());

  int failed_cases = 0;
  for (const std::string& dir : dirs) {
    std::printf("== %s\n", dir.c_str());
    int failures = 0;
    double worst = 0.0;
    try {
      const long3r::TensorFile io = long3r::load_safetensors(dir + "/io.safetensors");
      const std::string source = dir + "/weights.safetensors";
      const long3r::TensorFile weights = long3r::load_safetensors(source);
      const long3r::ModelConfig config =
          long3r::model_config_from_metadata(weights.metadata, source);
      Report report(io.tensors, tol, target.dtype != at::kFloat);
      if (config.kind == long3r::ModelKind::kDust3r) {
        run_dust3r_pair(config, weights, source, target, report);
      } else {
        run_spann3r_sequence(config, weights, source, target, report);
      }
      failures = report.finish();
      worst = report.worst();
    } catch (const std::exception& e) {
      std::printf("ERROR: %s\n", e.what());
      failures = 1;
    }
    std::printf("== %s: %s (max relative difference %.3e%s, tolerance %.1e)\n", dir.c_str(),
                failures == 0 ? "PASS" : "FAIL", worst,
                target.dtype != at::kFloat ? " of the outputs" : "", tol);
    if (failures != 0) ++failed_cases;
  }
  return failed_cases == 0 ? 0 : 1;
}
