#!/usr/bin/env python3
"""Writes the golden cases of DUSt3R's linear head (LinearPts3d, official
head_type='linear') from an official DUSt3R checkout, in the layout of the
other golden cases (test/data/golden/README.md): weights.safetensors with the
model configuration in its metadata, io.safetensors with inputs, outputs and
intermediates of one official forward pass, and case.json.

  python3 scripts/golden_linear_head.py --dust3r DUST3R_DIR [--out test/data/golden]

DUST3R_DIR is a working tree of github.com/naver/dust3r with its croco
submodule checked out (or --croco CROCO_DIR). Needs only torch and numpy: the
packages the official code imports for other purposes (huggingface_hub,
packaging, einops) are replaced by stand-ins that the linear head never
calls. Nothing of the official code is copied; it is imported and run.
"""
import argparse
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

CASES = [
    # name, (H, W) of both views, seed
    ("dust3r_linear_sq64", (64, 64), 2101),
    ("dust3r_linear_port64x48", (64, 48), 2102),
]
ARCH = dict(patch_size=8, enc_embed_dim=32, enc_depth=3, enc_num_heads=2,
            dec_embed_dim=16, dec_depth=4, dec_num_heads=2, mlp_ratio=4)


def write_safetensors(path, tensors, metadata=None):
    header = {}
    blobs = []
    offset = 0
    for name, t in tensors.items():
        t = t.detach().contiguous().cpu()
        if t.dtype == torch.float32:
            dtype, data = "F32", t.numpy().astype("<f4").tobytes()
        elif t.dtype == torch.int64:
            dtype, data = "I64", t.numpy().astype("<i8").tobytes()
        else:
            raise ValueError("unsupported dtype %s for %s" % (t.dtype, name))
        header[name] = {"dtype": dtype, "shape": list(t.shape),
                        "data_offsets": [offset, offset + len(data)]}
        blobs.append(data)
        offset += len(data)
    if metadata:
        header["__metadata__"] = metadata
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * ((8 - len(text) % 8) % 8)
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(struct.pack("<Q", len(text)))
        f.write(text)
        for b in blobs:
            f.write(b)
    os.replace(tmp, path)


def model_config(H, W):
    d = {"output_mode": "pts3d", "head_type": "linear", "depth_mode": ["exp", "-inf", "inf"],
         "conf_mode": ["exp", 1, "inf"], "freeze": "none", "landscape_only": True,
         "patch_embed_cls": "PatchEmbedDust3R", "img_size": [max(H, W), max(H, W)],
         "norm_layer": "LayerNorm(eps=1e-6)", "norm_im2_in_dec": True, "pos_embed": "RoPE100",
         "mask_ratio": 0.9}
    d.update(ARCH)
    return {"model": "AsymmetricCroCo3DStereo", "dust3r": d}


def build(AsymmetricCroCo3DStereo, H, W, seed):
    torch.manual_seed(seed)
    side = max(H, W)
    net = AsymmetricCroCo3DStereo(
        output_mode="pts3d", head_type="linear", depth_mode=("exp", -math.inf, math.inf),
        conf_mode=("exp", 1, math.inf), freeze="none", landscape_only=True,
        patch_embed_cls="PatchEmbedDust3R", img_size=(side, side),
        norm_layer=partial(nn.LayerNorm, eps=1e-6), norm_im2_in_dec=True, pos_embed="RoPE100",
        **ARCH)
    # dec_blocks2 starts as a copy of dec_blocks and LayerNorms as (1, 0): perturb
    # them so that a port that mixed the branches up or skipped a norm fails.
    g = torch.Generator().manual_seed(seed + 1)
    with torch.no_grad():
        for name, p in net.named_parameters():
            if name.startswith("dec_blocks2.") or ".norm" in name or name.startswith(
                    ("enc_norm", "dec_norm")):
                p.add_(0.1 * torch.randn(p.shape, generator=g))
    return net.eval()


def run_case(AsymmetricCroCo3DStereo, out_dir, name, shape, seed):
    H, W = shape
    net = build(AsymmetricCroCo3DStereo, H, W, seed)
    g = torch.Generator().manual_seed(seed + 2)
    # Smooth random images in [-1, 1]: a low-resolution draw upsampled.
    imgs = [torch.nn.functional.interpolate(torch.rand(1, 3, H // 8, W // 8, generator=g) * 2 - 1,
                                            size=(H, W), mode="bilinear", align_corners=False)
            for _ in range(2)]
    true_shape = torch.tensor([[H, W]], dtype=torch.int64)
    io = {"view1.img": imgs[0], "view1.true_shape": true_shape,
          "view2.img": imgs[1], "view2.true_shape": true_shape}
    # Intermediates by forward hooks on the official modules.
    enc_calls = []
    hooks = [net.patch_embed.register_forward_hook(lambda m, i, o: enc_calls.append(("patch_embed", o)))]
    for k, blk in enumerate(net.enc_blocks):
        hooks.append(blk.register_forward_hook(
            lambda m, i, o, k=k: enc_calls.append(("enc_block%d" % k, o))))
    hooks.append(net.enc_norm.register_forward_hook(lambda m, i, o: enc_calls.append(("enc_out", o))))
    dec = {}
    embeds = []
    hooks.append(net.decoder_embed.register_forward_hook(lambda m, i, o: embeds.append(o)))
    for b, blocks in ((1, net.dec_blocks), (2, net.dec_blocks2)):
        for k, blk in enumerate(blocks):
            hooks.append(blk.register_forward_hook(
                lambda m, i, o, b=b, k=k: dec.__setitem__("dec%d.block%d" % (b, k), o[0])))
    finals = []
    hooks.append(net.dec_norm.register_forward_hook(lambda m, i, o: finals.append(o)))
    raws = {}
    for b, head in ((1, net.downstream_head1), (2, net.downstream_head2)):
        # pixel_shuffle output = the head's raw map before postprocess
        hooks.append(head.proj.register_forward_hook(
            lambda m, i, o, b=b: raws.__setitem__(b, o)))
    with torch.no_grad():
        res1, res2 = net(dict(img=imgs[0], true_shape=true_shape, instance=["0"]),
                         dict(img=imgs[1], true_shape=true_shape, instance=["1"]))
    for h in hooks:
        h.remove()
    # Both views have one shape: the official code encodes them as one batch of 2.
    for key, t in enc_calls:
        if isinstance(t, tuple):
            t, pos = t
            io["img1.pos"], io["img2.pos"] = pos[0:1].long(), pos[1:2].long()
        io["img1." + key], io["img2." + key] = t[0:1], t[1:2]
    io["dec1.embed"], io["dec2.embed"] = embeds[0], embeds[1]
    for k in range(ARCH["dec_depth"] - 1):
        io["dec1.block%d" % k] = dec["dec1.block%d" % k]
        io["dec2.block%d" % k] = dec["dec2.block%d" % k]
    io["dec1.final"], io["dec2.final"] = finals[0], finals[1]
    p = ARCH["patch_size"]
    for b in (1, 2):
        feat = raws[b].transpose(-1, -2).reshape(1, -1, H // p, W // p)
        io["head%d.raw" % b] = torch.nn.functional.pixel_shuffle(feat, p)
    io["res1.pts3d"], io["res1.conf"] = res1["pts3d"], res1["conf"]
    io["res2.pts3d_in_other_view"], io["res2.conf"] = res2["pts3d_in_other_view"], res2["conf"]

    case_dir = os.path.join(out_dir, name)
    os.makedirs(case_dir, exist_ok=True)
    cfg = model_config(H, W)
    write_safetensors(os.path.join(case_dir, "weights.safetensors"),
                      {k: v.float() for k, v in net.state_dict().items()},
                      {"config": json.dumps(cfg)})
    write_safetensors(os.path.join(case_dir, "io.safetensors"), io)
    # float64 rerun of the same official code: the rounding already in the reference.
    net64 = build(AsymmetricCroCo3DStereo, H, W, seed).double()
    for head in (net64.downstream_head1, net64.downstream_head2):
        # the official forward casts the decoder tokens to float32 for the heads
        head.proj.register_forward_pre_hook(lambda m, i: (i[0].double(),))
    with torch.no_grad():
        r1, r2 = net64(dict(img=imgs[0].double(), true_shape=true_shape, instance=["0"]),
                       dict(img=imgs[1].double(), true_shape=true_shape, instance=["1"]))
    rel = lambda a, b: float((a.double() - b).abs().max() / b.abs().max())
    case = {
        "case": name, "kind": "dust3r_pair",
        "summary": "DUSt3R pair inference with the linear head (LinearPts3d), H=%d W=%d, patch %d, "
                   "tiny random model" % (H, W, p),
        "config": cfg, "seed": seed,
        "weights": "torch.manual_seed(seed), the official constructor (CroCo init; the heads keep "
                   "PyTorch's defaults); then dec_blocks2 and every LayerNorm += 0.1 * randn "
                   "(generator seed + 1)",
        "images": "bilinear upsampling of uniform [-1, 1] draws at 1/8 size (generator seed + 2)",
        "call_sequence": ["res1, res2 = model(view1, view2) under torch.no_grad(), model.eval()",
                          "head{1,2}.raw: pixel_shuffle(proj(dec_norm tokens)) before postprocess"],
        "tensors": [{"name": k, "dtype": "I64" if v.dtype == torch.int64 else "F32",
                     "shape": list(v.shape)} for k, v in io.items()],
        "verification": {"float64_rel_diff": {
            "res1.pts3d": rel(res1["pts3d"], r1["pts3d"]),
            "res2.pts3d_in_other_view": rel(res2["pts3d_in_other_view"], r2["pts3d_in_other_view"]),
            "res1.conf": rel(res1["conf"], r1["conf"]), "res2.conf": rel(res2["conf"], r2["conf"])}},
        "produced_with": {"torch": torch.__version__},
    }
    with open(os.path.join(case_dir, "case.json"), "w") as f:
        json.dump(case, f, indent=1)
    print("%s: %d tensors, float64 rel diff %s" % (name, len(io), case["verification"]))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dust3r", required=True, help="naver/dust3r working tree")
    ap.add_argument("--croco", help="naver/croco working tree (default: DUST3R/croco)")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "..", "test", "data",
                                                  "golden"))
    a = ap.parse_args()
    official_stand_ins.install()
    croco = os.path.abspath(a.croco or os.path.join(a.dust3r, "croco"))
    if not os.path.isdir(os.path.join(croco, "models")):
        sys.exit("no croco/models in %s: check out the croco submodule or pass --croco" % croco)
    sys.path.insert(0, croco)
    sys.path.insert(0, os.path.abspath(a.dust3r))
    torch.set_num_threads(1)
    from dust3r.model import AsymmetricCroCo3DStereo  # noqa: E402 (official code)
    for name, shape, seed in CASES:
        run_case(AsymmetricCroCo3DStereo, a.out, name, shape, seed)


if __name__ == "__main__":
    main()
