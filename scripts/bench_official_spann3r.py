#!/usr/bin/python3
"""The official side of scripts/bench_vs_official.sh (see there).

  bench_official_spann3r.py make OFFICIAL_CHECKOUT OUT.pth [--seed N]
      builds the official ViT-L Spann3R (DUSt3R_ViTLarge_BaseDecoder_512_dpt's
      architecture, Spann3R's memory encoder and heads) with random weights
      and saves it in the official layout, {'model': state_dict}, as
      demo.py loads it.
  bench_official_spann3r.py time OFFICIAL_CHECKOUT MODEL.pth FRAME_DIR
      --threads T --precision float32|bfloat16 --out TIMES.json
      runs Spann3R.forward (eval mode, no grad) over the frames of FRAME_DIR
      (sorted PNGs, square, already the model size) and writes each step's
      wall time: step k runs the pair (frame k, frame k+1), as the official
      forward loop does (step 0 also encodes frame 0).

The official code is imported from OFFICIAL_CHECKOUT unchanged. Python
modules it imports that Debian does not package (huggingface_hub, einops,
packaging where missing) are replaced by small shim modules written to a
temporary folder at run time, covering only what the model code uses:
  huggingface_hub: __version__ and a PyTorchModelHubMixin base whose
      from_pretrained refuses (the model is built from a local file);
  einops: rearrange for the one pattern the DPT head uses;
  packaging: version.parse for the version assert of dust3r/model.py.
A module that is installed is used as it is.
"""

import argparse
import importlib.util
import json
import os
import sys
import tempfile
import time

SHIMS = {
    "huggingface_hub": '''
# Shim (long3r_ros scripts/bench_official_spann3r.py): only what dust3r's
# model class uses.
__version__ = "0.24.6"


class PyTorchModelHubMixin:
    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__()

    @classmethod
    def from_pretrained(cls, *args, **kwargs):
        raise RuntimeError("huggingface_hub shim: no downloads; pass a local checkpoint file")
''',
    "einops": '''
# Shim (long3r_ros scripts/bench_official_spann3r.py): the one pattern the
# DPT head uses.
def rearrange(t, pattern, **axes):
    if pattern.replace(" ", "") == "b(nhnw)c->bcnhnw":
        b, n, c = t.shape
        return t.transpose(1, 2).reshape(b, c, axes["nh"], axes["nw"])
    raise NotImplementedError("einops shim: pattern %r" % pattern)


def repeat(*args, **kwargs):
    raise NotImplementedError("einops shim: repeat")
''',
    "packaging": None,  # a package: written below
}
PACKAGING_VERSION = '''
# Shim (long3r_ros scripts/bench_official_spann3r.py): version.parse for
# dotted release numbers, enough for dust3r's version assert.
def parse(text):
    parts = []
    for p in str(text).split("."):
        digits = "".join(ch for ch in p if ch.isdigit())
        parts.append(int(digits) if digits else 0)
    return tuple(parts)
'''

# DUSt3R_ViTLarge_BaseDecoder_512_dpt, the DUSt3R that Spann3R is built on
# (as scripts/convert_checkpoint.py records it).
DUST3R_MODEL = (
    "AsymmetricCroCo3DStereo(pos_embed='RoPE100', patch_embed_cls='ManyAR_PatchEmbed', "
    "img_size=(512, 512), head_type='dpt', output_mode='pts3d', depth_mode=('exp', -inf, inf), "
    "conf_mode=('exp', 1, inf), enc_embed_dim=1024, enc_depth=24, enc_num_heads=16, "
    "dec_embed_dim=768, dec_depth=12, dec_num_heads=12)")


def install_shims():
    """Writes shim modules for the missing imports; returns their names."""
    folder = tempfile.mkdtemp(prefix="official_shims_")
    used = []
    for name, text in SHIMS.items():
        if importlib.util.find_spec(name) is not None:
            continue
        if name == "packaging":
            os.makedirs(os.path.join(folder, "packaging"))
            open(os.path.join(folder, "packaging", "__init__.py"), "w").close()
            with open(os.path.join(folder, "packaging", "version.py"), "w") as f:
                f.write(PACKAGING_VERSION)
        else:
            with open(os.path.join(folder, name + ".py"), "w") as f:
                f.write(text)
        used.append(name)
    sys.path.insert(0, folder)
    return used


def import_official(checkout):
    checkout = os.path.abspath(checkout)
    for sub in ("spann3r/model.py", "dust3r/model.py", "croco/models/croco.py"):
        if not os.path.isfile(os.path.join(checkout, sub)):
            sys.exit("%s: not a Spann3R checkout (no %s)" % (checkout, sub))
    shims = install_shims()
    if shims:
        print("official: shim modules for %s (not installed)" % ", ".join(shims), flush=True)
    sys.path.insert(0, checkout)
    from spann3r.model import Spann3R  # noqa: E402
    return Spann3R


def build_spann3r(Spann3R):
    """The official ViT-L Spann3R with random weights. Spann3R builds its
    DUSt3R from a DUSt3R checkpoint file (dust3r.model.load_model, which reads
    the architecture from the file's args): one with no weights."""
    import argparse as ap
    import contextlib
    import io
    import torch
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "dust3r_architecture.pth")
        torch.save({"args": ap.Namespace(model=DUST3R_MODEL), "model": {}}, path)
        # load_model prints every missing key (all of them, by design here).
        with contextlib.redirect_stdout(io.StringIO()):
            return Spann3R(dus3r_name=path)


def make(opts):
    import torch
    Spann3R = import_official(opts.checkout)
    torch.manual_seed(opts.seed)
    model = build_spann3r(Spann3R)
    torch.save({"model": model.state_dict()}, opts.output)
    n = sum(p.numel() for p in model.parameters())
    print("official: wrote %s (Spann3R ViT-L, random weights, %.1f M parameters)"
          % (opts.output, n / 1e6), flush=True)


def load_frames(folder):
    import numpy as np
    import torch
    from PIL import Image
    names = sorted(f for f in os.listdir(folder) if f.endswith(".png"))
    frames = []
    for name in names:
        rgb = np.asarray(Image.open(os.path.join(folder, name)).convert("RGB"), dtype=np.float32)
        img = torch.from_numpy(rgb / 255.0).permute(2, 0, 1)[None]
        img = (img - 0.5) / 0.5
        frames.append({"img": img, "true_shape": torch.tensor([[img.shape[2], img.shape[3]]])})
    return frames


def to_bfloat16(model, frames):
    """bfloat16 for the official model on the CPU with torch 1.13. CPU
    autocast cannot run it: autocast leaves layer_norm out on the CPU, and the
    first LayerNorm meets a bfloat16 activation with float32 weights ("expected
    scalar type BFloat16 but found Float"). So the weights are converted
    instead, as this package does, except the DPT heads, which the official
    code runs in float32 itself (it passes them tok.float()), and which hold
    conv_transpose2d, which has no bfloat16 CPU kernel. Each layer's input is
    cast to its weights' dtype by a forward pre-hook (the official code itself
    is not changed); the frames go in as bfloat16."""
    import torch
    model.to(torch.bfloat16)
    for name, m in model.named_modules():
        if "downstream_head" in name.split(".")[-1]:
            m.float()

    def follow_weights(mod, args):
        dtype = next(mod.parameters(recurse=False)).dtype
        return tuple(a.to(dtype) if torch.is_tensor(a) and a.is_floating_point() else a
                     for a in args)

    for m in model.modules():
        if next(m.parameters(recurse=False), None) is not None:
            m.register_forward_pre_hook(follow_weights)
    for f in frames:
        f["img"] = f["img"].to(torch.bfloat16)


def time_steps(opts):
    import torch
    Spann3R = import_official(opts.checkout)
    torch.set_num_threads(opts.threads)
    model = build_spann3r(Spann3R)
    model.load_state_dict(torch.load(opts.model, map_location="cpu")["model"])
    model.eval()
    frames = load_frames(opts.frames)
    if len(frames) < 3:
        sys.exit("need at least 3 frames")

    # One timestamp per step of the official loop: it starts every step with
    # encode_frames.
    starts = []
    encode = model.encode_frames

    def timed_encode(*args, **kwargs):
        starts.append(time.perf_counter())
        return encode(*args, **kwargs)

    model.encode_frames = timed_encode
    if opts.precision == "bfloat16":
        to_bfloat16(model, frames)
    with torch.no_grad():
        t0 = time.perf_counter()
        model(frames)
        end = time.perf_counter()
    del t0
    steps = [b - a for a, b in zip(starts, starts[1:] + [end])]
    with open(opts.out, "w") as f:
        json.dump({"steps_s": steps, "threads": torch.get_num_threads(),
                   "precision": opts.precision}, f)
    print("official %s: %d steps, %s s" % (opts.precision, len(steps),
                                           " ".join("%.2f" % s for s in steps)), flush=True)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    m = sub.add_parser("make")
    m.add_argument("checkout")
    m.add_argument("output")
    m.add_argument("--seed", type=int, default=0)
    t = sub.add_parser("time")
    t.add_argument("checkout")
    t.add_argument("model")
    t.add_argument("frames")
    t.add_argument("--threads", type=int, required=True)
    t.add_argument("--precision", choices=["float32", "bfloat16"], default="float32")
    t.add_argument("--out", required=True)
    opts = p.parse_args()
    make(opts) if opts.cmd == "make" else time_steps(opts)


if __name__ == "__main__":
    main()
