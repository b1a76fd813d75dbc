#!/usr/bin/env python3
"""Regenerates the five golden cases made with the official DUSt3R and Spann3R
code (test/data/golden/dust3r_pair_*, spann3r_seq_*), or checks the stored ones.

  python3 scripts/golden_official.py --dust3r DUST3R_DIR --spann3r SPANN3R_DIR --check
  python3 scripts/golden_official.py --dust3r DUST3R_DIR --spann3r SPANN3R_DIR --out DIR
  more: --case NAME (repeatable, default all five), --ref DIR (the stored cases,
  default test/data/golden), --weights-from DIR (load DIR/<case>/weights.safetensors
  instead of building the weights from the seed), --tol (default 1e-4)

DUST3R_DIR: a working tree of github.com/naver/dust3r with its croco submodule
in DUST3R_DIR/croco. SPANN3R_DIR: one of github.com/HengyiWang/spann3r; the
Spann3R cases use its own dust3r and croco copies, as its code does. Nothing of
the official code is copied: it is imported from those paths and run.

Where everything comes from. The recipe is each stored case.json: config,
seed, redrawn prefixes, residual_branch_scale, memory_qk_scale, target_dmax,
memory sizes, tensor list. The weights are built from the seed as
config.param_init says; head_out_scale is calibrated again, as
round(target_dmax / max |xyz| of a run without it, 2). The input images are
copied from the stored io.safetensors: case.json names their generator and
seeds but not its code, so they cannot be drawn again. io holds the official
forward call's outputs and intermediates, taken by forward hooks and by a
subclass of the official SpatialMemory that records what its methods compute
(watching torch.softmax, torch.mean and torch.topk while they run). case.json
is the stored one with the measured values recomputed (tensors, stats, weight
rescaling, memory numbers, verification, file sizes).

--check writes nothing: it compares weights and io with the stored files
tensor by tensor (max abs diff, and that over max |stored|; integers must be
equal), lists the case.json values that differ, and exits 1 when a tensor is
missing, misshapen or off by more than --tol.

Needs python3 with torch 1.13 and numpy. Stand-ins replace modules Debian 12
lacks: huggingface_hub (the hub-loading base class, unused here), packaging
(dust3r's version assert) and einops, whose one call here (rearrange
'b (nh nw) c -> b c nh nw' in the DPT head) becomes the equal transpose +
reshape; that returns a contiguous tensor, as in the stored run (a permuted,
channels-last view such as einops returns makes torch pick convolution
kernels that round differently). Without curope the official slow RoPE runs.
Bit-identical io needs the stored run's numerics: Debian 12's torch on an
AVX-512 CPU, one torch thread (set here) and OpenBLAS's pthread build with two
or more threads (LD_LIBRARY_PATH=/usr/lib/x86_64-linux-gnu/openblas-pthread);
elsewhere float32 rounding differs, by about 1e-6 relative.
"""
import argparse
import contextlib
import copy
import json
import math
import os
import struct
import sys
from functools import partial

import numpy as np
import torch
import torch.nn as nn

import official_stand_ins  # beside this script

CASES = ["dust3r_pair_sq224", "dust3r_pair_land112x80", "dust3r_pair_port80x112",
         "spann3r_seq_sq224", "spann3r_seq_land96x64"]
NUMPY_DTYPE = {"F32": "<f4", "I64": "<i8"}
REF = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "test", "data", "golden")
BASE_PATH = list(sys.path)


def rearrange_dpt(t, pattern, nh, nw):
    """einops.rearrange's one call in the DPT head, contiguous (see the docstring)."""
    assert pattern == "b (nh nw) c -> b c nh nw", pattern
    return t.transpose(1, 2).reshape(t.shape[0], t.shape[2], nh, nw)


def encode(tensors, metadata):
    """safetensors bytes as the stored files have them (metadata first)."""
    header, blobs, offset = {"__metadata__": metadata}, [], 0
    for name, t in tensors.items():
        dtype = "I64" if t.dtype == torch.int64 else "F32"
        data = t.detach().contiguous().numpy().astype(NUMPY_DTYPE[dtype]).tobytes()
        header[name] = {"dtype": dtype, "shape": list(t.shape),
                        "data_offsets": [offset, offset + len(data)]}
        blobs.append(data)
        offset += len(data)
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)
    return struct.pack("<Q", len(text)) + text + b"".join(blobs)


def decode(blob):
    n = struct.unpack("<Q", blob[:8])[0]
    header = json.loads(blob[8:8 + n])
    header.pop("__metadata__", None)
    out = {}
    for name, h in header.items():
        begin, end = (8 + n + o for o in h["data_offsets"])
        arr = np.frombuffer(blob[begin:end], dtype=NUMPY_DTYPE[h["dtype"]]).reshape(h["shape"])
        out[name] = torch.from_numpy(arr.copy())
    return out


def read(path):
    with open(path, "rb") as f:
        return f.read()


def import_official(root, c):
    """The official classes from one checkout, its DPT head built at the widths c."""
    for name in [m for m in sys.modules if m.split(".")[0] in ("dust3r", "models", "croco", "spann3r")]:
        del sys.modules[name]
    sys.path[:] = [os.path.abspath(root)] + BASE_PATH
    with contextlib.redirect_stdout(sys.stderr):
        import dust3r.heads
        from dust3r.heads.dpt_head import PixelwiseTaskWithDPT
        from dust3r.heads.postprocess import postprocess
        from dust3r.model import AsymmetricCroCo3DStereo

        def create_dpt_head(net, has_conf=False):  # the official one hardcodes the widths
            return PixelwiseTaskWithDPT(
                num_channels=c["num_channels"], feature_dim=c["feature_dim"], last_dim=c["last_dim"],
                layer_dims=c["layer_dims"], hooks_idx=c["hooks"], dim_tokens=c["dim_tokens"],
                output_width_ratio=c["output_width_ratio"], stride_level=c["stride_level"],
                patch_size=c["patch_size"], use_bn=c["use_bn"], postprocess=postprocess,
                depth_mode=net.depth_mode, conf_mode=net.conf_mode, head_type=c["head_type"])
        dust3r.heads.create_dpt_head = create_dpt_head
        if not os.path.isdir(os.path.join(root, "spann3r")):
            return AsymmetricCroCo3DStereo, None
        import spann3r.model
        return AsymmetricCroCo3DStereo, spann3r.model


def dust3r_kwargs(d):
    assert d["norm_layer"] == "LayerNorm(eps=1e-6)"
    mode = lambda m: tuple(float(v) if v in ("inf", "-inf") else v for v in m)  # noqa: E731
    kw = {k: d[k] for k in (
        "output_mode", "head_type", "freeze", "landscape_only", "patch_embed_cls", "patch_size",
        "enc_embed_dim", "enc_depth", "enc_num_heads", "dec_embed_dim", "dec_depth", "dec_num_heads",
        "mlp_ratio", "norm_im2_in_dec", "pos_embed", "mask_ratio")}
    return dict(kw, depth_mode=mode(d["depth_mode"]), conf_mode=mode(d["conf_mode"]),
                img_size=tuple(d["img_size"]), norm_layer=partial(nn.LayerNorm, eps=1e-6))


def construct(cfg, official):
    """torch.manual_seed(seed), then the official constructor at the tiny widths."""
    Asym, spann3r_model = official
    kw = dust3r_kwargs(cfg["dust3r"])
    torch.manual_seed(cfg["seed"])
    if cfg["model"] == "AsymmetricCroCo3DStereo":
        return Asym(**kw)
    # Spann3R gets its DUSt3R by from_pretrained(name, landscape_only=True) and
    # hardcodes ViT-L/base widths: the same modules are built at the tiny ones.
    Asym.from_pretrained = classmethod(lambda cls, name, **over: cls(**dict(kw, **over)))
    s, ve = cfg["spann3r"], cfg["spann3r"]["value_encoder"]

    class TinySpann3R(spann3r_model.Spann3R):
        def set_memory_encoder(self, enc_embed_dim, memory_dropout):
            super().set_memory_encoder(
                enc_depth=ve["depth"], enc_embed_dim=ve["embed_dim"], out_dim=ve["out_dim"],
                enc_num_heads=ve["num_heads"], mlp_ratio=ve["mlp_ratio"], memory_dropout=memory_dropout)
            self.norm_q, self.norm_k, self.norm_v = (nn.LayerNorm(ve["embed_dim"]) for _ in range(3))

        def set_attn_head(self):
            super().set_attn_head(enc_embed_dim=kw["enc_embed_dim"] + kw["dec_embed_dim"],
                                  out_dim=kw["enc_embed_dim"])
    return TinySpann3R(dus3r_name="tiny", use_feat=s["use_feat"], mem_pos_enc=s["mem_pos_enc"],
                       memory_dropout=s["memory_dropout"])


def perturb(net, cfg):
    """config.param_init after the constructor, all but the head output scale."""
    g = torch.Generator().manual_seed(cfg["seed"] + 1)
    randn = lambda shape: torch.randn(shape, generator=g)  # noqa: E731
    with torch.no_grad():
        for name, m in net.named_modules():
            if isinstance(m, nn.LayerNorm):
                m.weight.copy_(1 + 0.1 * randn(m.weight.shape))
                m.bias.copy_(0.05 * randn(m.bias.shape))
                continue
            redraw = name.startswith(tuple(cfg["redrawn_prefixes"]))
            if redraw and isinstance(m, (nn.Linear, nn.Conv2d, nn.ConvTranspose2d)):
                fan_in, fan_out = nn.init._calculate_fan_in_and_fan_out(m.weight)
                a = math.sqrt(6.0 / (fan_in + fan_out))
                m.weight.copy_(torch.empty(m.weight.shape).uniform_(-a, a, generator=g))
                if not isinstance(m, nn.Linear) and m.bias is not None:
                    m.bias.copy_((2 * torch.rand(m.bias.shape, generator=g) - 1) / math.sqrt(fan_in))
            if isinstance(m, nn.Linear) and m.bias is not None:
                m.bias.add_(0.02 * randn(m.bias.shape))
        for name, m in net.named_modules():  # attn.proj, cross_attn.proj, mlp.fc2
            if isinstance(m, nn.Linear) and name.endswith(("attn.proj", "mlp.fc2")):
                m.weight.mul_(cfg["residual_branch_scale"])
                m.bias.mul_(cfg["residual_branch_scale"])
        for m in (getattr(net, "norm_q", None), getattr(net, "norm_k", None)):
            if m is not None:
                m.weight.mul_(cfg["memory_qk_scale"])
                m.bias.mul_(cfg["memory_qk_scale"])


def dpt(net, h):
    return getattr(getattr(net, "dust3r", net), "downstream_head%d" % h).dpt


def scale_heads(net, scales):
    with torch.no_grad():
        for h, s in enumerate(scales, 1):
            dpt(net, h).head[4].weight.mul_(s)
            dpt(net, h).head[4].bias.mul_(s)


class Hooks:
    """Forward hooks that keep every output of the modules they watch."""

    def __init__(self):
        self.rec, self.handles = {}, []

    def on(self, module, name):
        keep = lambda m, i, o: self.rec.setdefault(name, []).append(o)  # noqa: E731
        self.handles.append(module.register_forward_hook(keep))

    def heads(self, net):
        for h in (1, 2):
            d = dpt(net, h)
            self.on(d, "head%d.raw" % h)
            for j in range(4):
                self.on(d.act_postprocess[j], "head%d.act_postprocess%d" % (h, j))
                self.on(d.scratch.layer_rn[j], "head%d.layer_rn%d" % (h, j))
                self.on(getattr(d.scratch, "refinenet%d" % (j + 1)), "head%d.refinenet%d" % (h, j + 1))

    def remove(self):
        for handle in self.handles:
            handle.remove()


@contextlib.contextmanager
def watch(name, sink):
    """Keeps a copy of what torch.<name> returns while the block runs."""
    real = getattr(torch, name)

    def spy(*args, **kwargs):
        out = real(*args, **kwargs)
        sink.append(out.clone() if torch.is_tensor(out) else tuple(o.clone() for o in out))
        return out
    setattr(torch, name, spy)
    try:
        yield
    finally:
        setattr(torch, name, real)


def run_pair(net, inputs):
    hooks = Hooks()
    for name in ["patch_embed", "enc_norm", "decoder_embed", "dec_norm"]:
        hooks.on(getattr(net, name), name)
    for k, blk in enumerate(net.enc_blocks):
        hooks.on(blk, "enc_block%d" % k)
    for b, blocks in ((1, net.dec_blocks), (2, net.dec_blocks2)):
        for k, blk in enumerate(blocks):
            hooks.on(blk, "dec%d.block%d" % (b, k))
    hooks.heads(net)
    io = {k: inputs[k] for k in ("view1.img", "view1.true_shape", "view2.img", "view2.true_shape")}
    views = [dict(img=io["view%d.img" % v], true_shape=io["view%d.true_shape" % v], instance=[str(v - 1)])
             for v in (1, 2)]
    with torch.no_grad():
        res1, res2 = net(*views)
    hooks.remove()
    rec = hooks.rec
    io.update({"res1.pts3d": res1["pts3d"], "res1.conf": res1["conf"],
               "res2.pts3d_in_other_view": res2["pts3d_in_other_view"], "res2.conf": res2["conf"]})
    tokens, pos = rec.pop("patch_embed")[0]  # both views are encoded as one batch of 2
    io["img1.pos"], io["img2.pos"] = pos[:1], pos[1:]
    rec["enc_out"] = rec.pop("enc_norm")
    for name, t in [("patch_embed", tokens)] + [(k, v[0]) for k, v in rec.items() if k.startswith("enc_")]:
        io["img1." + name], io["img2." + name] = t[:1], t[1:]
    io["dec1.embed"], io["dec2.embed"] = rec["decoder_embed"]
    io["dec1.final"], io["dec2.final"] = rec["dec_norm"]
    io.update({k: v[0][0] for k, v in rec.items() if ".block" in k})
    io.update({k: v[0] for k, v in rec.items() if k.startswith("head")})
    return dict(io=io, pts=[res1["pts3d"], res2["pts3d_in_other_view"]],
                conf=[res1["conf"], res2["conf"]], memory=None, raw=[rec["head1.raw"], rec["head2.raw"]])


def recording_memory(SpatialMemory, mem):
    class RecordingMemory(SpatialMemory):
        """The official memory at the case's sizes, keeping what each step did."""

        def __init__(self, *args, **kwargs):
            super().__init__(*args, long_mem_size=mem["long_mem_size"],
                             work_mem_size=mem["work_mem_size"], **kwargs)
            self.steps, self.reads, self.prunes = [], [], []

        def check_sim(self, feat_k, thresh=0.7):
            corr = []
            with watch("mean", corr):
                skipped = super().check_sim(feat_k, thresh)
            self.step.update(skipped=skipped, corr=corr, wm_before=self.wm)
            return skipped

        def add_mem_check(self, feat_k, feat_v, *args, **kwargs):
            self.step = dict(pruned=False, before=0 if self.mem_k is None else self.mem_k.shape[1])
            super().add_mem_check(feat_k, feat_v, *args, **kwargs)
            self.step.update(tokens=self.mem_k.shape[1], wm=self.wm, lm=self.lm,
                             count=self.mem_count.flatten().clone(), attn=self.mem_attn.flatten().clone())
            self.steps.append(self.step)

        def memory_prune(self):
            top = []
            prune = dict(step=len(self.steps), count=self.mem_count.flatten().clone(),
                         attn=self.mem_attn.flatten().clone())
            with watch("topk", top):
                super().memory_prune()
            self.prunes.append(dict(prune, indices=top[0][1].flatten()))
            self.step["pruned"] = True

        def memory_read(self, feat, res=True):
            softmax, tokens = [], self.mem_k.shape[1]
            with watch("softmax", softmax):
                out = super().memory_read(feat, res)
            self.reads.append(dict(out=out, tokens=tokens, attn=softmax[0][0]))
            return out
    return RecordingMemory


def run_sequence(net, inputs, spann3r_model, mem):
    imgs, shapes = inputs["frames.img"], inputs["frames.true_shape"]
    frames = [dict(img=imgs[i:i + 1], true_shape=shapes[i:i + 1]) for i in range(len(imgs))]
    hooks = Hooks()
    for name in ("attn_head_1", "attn_head_2", "value_out"):
        hooks.on(getattr(net, name), name)
    hooks.heads(net)
    official_memory = spann3r_model.SpatialMemory
    spann3r_model.SpatialMemory = recording_memory(official_memory, mem)
    try:
        with torch.no_grad(), contextlib.redirect_stdout(sys.stderr):
            preds, _, sp = net(frames, return_memory=True)
    finally:
        spann3r_model.SpatialMemory = official_memory
        hooks.remove()
    rec, thr = hooks.rec, sp.attn_thresh
    io = {"frames.img": imgs, "frames.true_shape": shapes,
          "pred.pts3d": torch.cat([p["pts3d" if i == 0 else "pts3d_in_other_view"]
                                   for i, p in enumerate(preds)]),
          "pred.conf": torch.cat([p["conf"] for p in preds]),
          "step.feat_k1": torch.cat(rec["attn_head_1"]), "step.feat_k2": torch.cat(rec["attn_head_2"]),
          "step.cur_v": torch.cat(rec["value_out"]),
          "read.feat_fuse": torch.cat([r["out"] for r in sp.reads]),
          "read.mem_tokens": torch.tensor([r["tokens"] for r in sp.reads]),
          "read.n_zeroed": torch.tensor([int((r["attn"] < thr).sum()) for r in sp.reads])}
    for j, r in enumerate(sp.reads):
        idx = ((r["attn"] - thr).abs() <= 1e-3 * thr).nonzero()
        io["read%d.near_thresh_idx" % j] = idx
        io["read%d.near_thresh_attn" % j] = r["attn"][idx[:, 0], idx[:, 1]]
    io["step.mem_tokens_after"] = torch.tensor([s["tokens"] for s in sp.steps])
    io["step.added"] = torch.tensor([int(not s["skipped"]) for s in sp.steps])
    for key in ("pruned", "wm", "lm"):
        io["step." + key] = torch.tensor([int(s[key]) for s in sp.steps])
    for k, s in enumerate(sp.steps):
        io["step%d.mem_count" % k], io["step%d.mem_attn" % k] = s["count"], s["attn"]
    for j, p in enumerate(sp.prunes):
        io["prune%d.step" % j], io["prune%d.indices" % j] = torch.tensor([p["step"]]), p["indices"]
        io["prune%d.mem_count_before" % j], io["prune%d.mem_attn_before" % j] = p["count"], p["attn"]
    io.update({"final_mem.k": sp.mem_k, "final_mem.v": sp.mem_v, "final_mem.count": sp.mem_count,
               "final_mem.attn": sp.mem_attn})
    return dict(io=io, pts=[io["pred.pts3d"]], conf=[io["pred.conf"]], memory=sp,
                raw=[rec["head1.raw"], rec["head2.raw"]])


def run(net, case, inputs, official, dtype=torch.float32):
    """The recorded call sequence: io (the case's tensors), pts, conf, memory, raw."""
    net = net.to(dtype).eval()
    if dtype != torch.float32:  # the official forward hands the heads float32 tokens
        for h in (1, 2):
            dpt(net, h).register_forward_pre_hook(lambda m, args: ([t.to(dtype) for t in args[0]],))
        inputs = {k: v.to(dtype) if v.is_floating_point() else v for k, v in inputs.items()}
    if case["kind"] == "dust3r_pair":
        result = run_pair(net, inputs)
    else:
        result = run_sequence(net, inputs, official[1], case["config"]["spatial_memory"])
    names = [t["name"] for t in case["tensors"]]
    missing = [n for n in names if n not in result["io"]]
    if missing:
        sys.exit("%s: the run produced no %s" % (case["case"], ", ".join(missing)))
    return dict(result, io={n: result["io"][n] for n in names})


def rel(a, b):
    return float((a.double() - b.double()).abs().max() / b.double().abs().max())


def max_xyz(result):
    """Per head, max |xyz| of the raw head output over all its calls."""
    return [max(float(r[:, :3].norm(dim=1).max()) for r in raws) for raws in result["raw"]]


def point_stats(pts, conf):
    norm = pts.norm(dim=-1)
    d = math.log(1 + float(norm.max()))  # max |xyz| before the exp
    return {"max_abs_pts3d": float(pts.abs().max()), "max_norm_pts3d": float(norm.max()),
            "mean_norm_pts3d": float(norm.mean()), "min_conf": float(conf.min()),
            "max_conf": float(conf.max()), "max_xyz_norm_before_exp": d,
            "rel_error_amplification_at_max": d * math.exp(d) / math.expm1(d)}


def memory_numbers(sp, mem, P):
    thr, tied_end, checks, prunes = sp.attn_thresh, 0, [], []
    for k, s in enumerate(sp.steps):
        if s["corr"]:  # step 0 compares nothing
            checks.append({"step": k, "max_mean_corr": float(s["corr"][0].max()), "skipped": s["skipped"],
                           "window_has_topk_tied_tokens": s["before"] - s["wm_before"] * P < tied_end})
        for p in (p for p in sp.prunes if p["step"] == k):
            protected = p["count"] < mem["work_mem_size"] + 5  # weight 1e8: tied, kept first
            weights = (p["attn"] / p["count"])[~protected].sort(descending=True).values
            tied_end = int(protected.sum())
            kept = len(p["indices"]) - tied_end
            last, first = float(weights[kept - 1]), float(weights[kept])
            prunes.append({
                "step": k, "tokens_before": len(p["count"]), "tokens_after": len(p["indices"]),
                "protected_tokens": tied_end, "unprotected_tokens": len(weights), "unprotected_kept": kept,
                "unprotected_with_zero_weight": int((weights == 0).sum()),
                "boundary": {"last_kept": last, "first_dropped": first, "rel_gap": (last - first) / last}})
    dist = [(r["attn"] - thr).abs() / thr for r in sp.reads]
    return {
        "tokens_per_frame": P, "long_mem_size": mem["long_mem_size"], "work_mem_size": mem["work_mem_size"],
        "memory_prune_calls": len(prunes), "prune_steps": [p["step"] for p in prunes],
        "reads_after_first_prune": len(sp.reads) - prunes[0]["step"] if prunes else 0,
        "tokens_after_each_step": [s["tokens"] for s in sp.steps],
        "tokens_at_each_read": [r["tokens"] for r in sp.reads], "check_sim": checks,
        "check_sim_min_distance_to_thresh": min(abs(c["max_mean_corr"] - sp.sim_thresh) for c in checks),
        "prunes": prunes, "attn_thresh_min_rel_distance_per_read": [float(d.min()) for d in dist],
        "attn_weights_within_rel_distance_of_thresh_per_read": [
            {e: int((d <= float(e)).sum()) for e in ("1e-06", "1e-05", "1e-04", "1e-03")} for d in dist],
        "attn_fraction_below_thresh_per_read": [float((r["attn"] < thr).float().mean()) for r in sp.reads]}


def describe(case, result, f64, rerun, blobs, calibration):
    """The stored case.json with the measured values recomputed."""
    out, io, sp = copy.deepcopy(case), result["io"], result["memory"]
    meaning = {t["name"]: t["meaning"] for t in case["tensors"]}
    out["tensors"] = [{"name": n, "dtype": "I64" if t.dtype == torch.int64 else "F32",
                       "shape": list(t.shape), "meaning": meaning[n]} for n, t in io.items()]
    if calibration:
        out["config"]["head_out_scale"] = out["weight_rescaling"]["head_out_scale"] = calibration[0]
        out["weight_rescaling"]["max_xyz_norm_before_scaling"] = calibration[1]
    names = ("head1", "head2") if sp is None else ("preds",)
    out["stats"] = {n: point_stats(p, c) for n, p, c in zip(names, result["pts"], result["conf"])}
    out["stats"]["max_abs_any_float_tensor"] = max(float(t.abs().max()) for t in io.values()
                                                   if t.is_floating_point() and t.numel())
    outputs = (["res1.pts3d", "res1.conf", "res2.pts3d_in_other_view", "res2.conf"] if sp is None
               else ["pred.pts3d", "pred.conf", "read.feat_fuse"])
    f64_diff = {k: rel(f64["io"][k], io[k]) for k in outputs}
    if sp is not None:
        tokens_per_frame = io["step.feat_k1"].shape[1]
        out["memory"].update(memory_numbers(sp, case["config"]["spatial_memory"], tokens_per_frame))
        sp64, thr = f64["memory"], sp.attn_thresh
        schedule = lambda m: [(s["tokens"], s["skipped"], s["pruned"]) for s in m.steps]  # noqa: E731
        f64_diff.update(
            same_memory_schedule=schedule(sp) == schedule(sp64),
            same_attn_thresh_masks=all(torch.equal(a["attn"] < thr, b["attn"] < thr)
                                       for a, b in zip(sp.reads, sp64.reads)),
            same_prune_sets=all(set(a["indices"].tolist()) == set(b["indices"].tolist())
                                for a, b in zip(sp.prunes, sp64.prunes)))
    same = lambda a, b: all(torch.equal(a[k], v) for k, v in b.items())  # noqa: E731
    out["verification"].update(
        weights_roundtrip="bit-exact" if same(decode(blobs[0]), rerun[0]) else "differs",
        io_roundtrip="bit-exact" if same(decode(blobs[1]), io) else "differs",
        rerun_from_reloaded_weights_max_abs_diff=max(
            float((rerun[1][k].double() - v.double()).abs().max()) for k, v in io.items() if v.numel()),
        rerun_bit_identical=same(rerun[1], io), float64_rel_diff=f64_diff)
    out["file_bytes"] = {"weights": len(blobs[0]), "io": len(blobs[1])}
    return out


def compare_tensors(label, mine, ref, tol):
    bad = identical = 0
    for k in list(ref) + [k for k in mine if k not in ref]:
        a, b = mine.get(k), ref.get(k)
        if a is None or b is None or a.shape != b.shape or a.dtype != b.dtype:
            info = ("missing here" if a is None else "not stored" if b is None else
                    "%s %s, stored %s %s" % (a.dtype, list(a.shape), b.dtype, list(b.shape)))
            print("  FAIL %s %s: %s" % (label, k, info))
            bad += 1
            continue
        diff = float((a.double() - b.double()).abs().max()) if a.numel() else 0.0
        scale = float(b.double().abs().max()) if b.numel() else 0.0
        r = diff / scale if scale else math.inf if diff else 0.0
        equal = torch.equal(a, b)
        ok = equal or (a.is_floating_point() and r <= tol)
        identical, bad = identical + equal, bad + (not ok)
        print("  %s %s %s %s max_abs %.3g rel %.3g" % (
            "same" if equal else "ok  " if ok else "FAIL", label, k, list(a.shape), diff, r))
    print("  %s: %d tensors, %d bit-identical, %d failing" % (label, len(ref), identical, bad))
    return bad


def differing_fields(mine, ref, path=""):
    if isinstance(ref, dict) and isinstance(mine, dict):
        return [d for k in ref for d in differing_fields(mine.get(k), ref[k], path + "." + k)]
    if isinstance(ref, list) and isinstance(mine, list) and len(ref) == len(mine):
        return [d for i, (a, b) in enumerate(zip(mine, ref))
                for d in differing_fields(a, b, "%s[%d]" % (path, i))]
    return [] if mine == ref else ["%s: %r, stored %r" % (path[1:], mine, ref)]


def process(name, args, checkouts):
    with open(os.path.join(args.ref, name, "case.json")) as f:
        case = json.load(f)
    cfg = case["config"]
    official = import_official(checkouts[case["kind"]], cfg["dust3r"]["dpt_head"])
    inputs = decode(read(os.path.join(args.ref, name, "io.safetensors")))
    net, calibration = construct(cfg, official), None
    if args.weights_from:
        net.load_state_dict(decode(read(os.path.join(args.weights_from, name, "weights.safetensors"))))
    else:
        perturb(net, cfg)
        before = max_xyz(run(net, case, inputs, official))  # a run before the head output scale
        calibration = ([round(cfg["target_dmax"] / m, 2) for m in before], before)
        if calibration[0] != cfg["head_out_scale"]:
            print("%s: head_out_scale calibrates to %s, stored %s" % (
                name, calibration[0], cfg["head_out_scale"]))
        scale_heads(net, calibration[0])
        cfg = dict(cfg, head_out_scale=calibration[0])
    weights = {k: v.detach().clone() for k, v in net.state_dict().items()}
    result = run(net, case, inputs, official)
    blobs = (encode(weights, {"config": json.dumps(cfg, sort_keys=True)}),
             encode(result["io"], {"case": name}))
    fresh = construct(cfg, official)
    fresh.load_state_dict(decode(blobs[0]))
    rerun = (weights, run(fresh, case, inputs, official)["io"])
    f64 = run(fresh, case, inputs, official, torch.float64)
    described = describe(case, result, f64, rerun, blobs, calibration)
    if not args.check:
        folder = os.path.join(args.out, name)
        os.makedirs(folder, exist_ok=True)
        for fname, blob in zip(("weights.safetensors", "io.safetensors"), blobs):
            with open(os.path.join(folder, fname), "wb") as f:
                f.write(blob)
        with open(os.path.join(folder, "case.json"), "w") as f:
            json.dump(described, f, indent=1)
        print("%s: wrote %s (%d io tensors)" % (name, folder, len(result["io"])))
        return 0
    print("%s:" % name)
    bad = 0
    for label, blob in zip(("weights", "io"), blobs):
        stored = read(os.path.join(args.ref, name, label + ".safetensors"))
        bad += compare_tensors(label, decode(blob), decode(stored), args.tol)
        print("  %s.safetensors: %s" % (label, "byte-identical" if blob == stored else "bytes differ"))
    fields = differing_fields(described, case)
    print("  case.json: %d recomputed value(s) differ from the stored ones" % len(fields))
    for line in fields:
        print("    " + line)
    return bad


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dust3r", help="naver/dust3r working tree, croco in DUST3R/croco")
    ap.add_argument("--spann3r", help="HengyiWang/spann3r working tree")
    ap.add_argument("--case", action="append", choices=CASES, help="default: all five")
    ap.add_argument("--ref", default=os.path.normpath(REF),
                    help="the stored cases: recipes, input images, what --check compares with")
    ap.add_argument("--out", help="folder to write the cases into")
    ap.add_argument("--check", action="store_true", help="compare with --ref instead of writing")
    ap.add_argument("--weights-from", help="folder whose <case>/weights.safetensors to load")
    ap.add_argument("--tol", type=float, default=1e-4,
                    help="max abs diff / max |stored| allowed per float tensor")
    args = ap.parse_args()
    if not args.check and not args.out:
        ap.error("give --out DIR or --check")
    cases = args.case or CASES
    checkouts = {"dust3r_pair": args.dust3r, "spann3r_seq": args.spann3r}
    for name in cases:
        kind = "dust3r_pair" if name.startswith("dust3r") else "spann3r_seq"
        inside = "croco/models" if kind == "dust3r_pair" else "spann3r"
        if not checkouts[kind] or not os.path.isdir(os.path.join(checkouts[kind], inside)):
            ap.error("%s needs --%s, a checkout with %s" % (name, kind.split("_")[0], inside))
    official_stand_ins.install(rearrange=rearrange_dpt)
    torch.set_num_threads(1)
    maps = read("/proc/self/maps").decode().split("\n") if os.path.exists("/proc/self/maps") else []
    blas = sorted({line.split()[-1] for line in maps if "blas" in line.lower()})
    print("torch %s, %d thread(s), %s" % (torch.__version__, torch.get_num_threads(), ", ".join(blas)))
    failures = sum(process(name, args, checkouts) for name in cases)
    if args.check:
        print("%s: %d failing tensor(s) in %d case(s)" % (
            "FAIL" if failures else "PASS", failures, len(cases)))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
