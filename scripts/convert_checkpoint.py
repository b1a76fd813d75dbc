#!/usr/bin/python3
"""Converts PyTorch checkpoints of DUSt3R / Spann3R (and LONG3R) to the
safetensors files the C++ core loads, with the model configuration as JSON in
__metadata__["config"] (structure: docs/checkpoints.md). Also converts back
(--to-pth), and prints the tensor-name table of a safetensors file
(--names-table).

Needs only PyTorch (Debian's python3-torch works); the safetensors format is
written and read here directly.

  convert_checkpoint.py DUSt3R_ViTLarge_BaseDecoder_512_dpt.pth dust3r_512.safetensors
  convert_checkpoint.py --kind spann3r spann3r.pth spann3r.safetensors
  convert_checkpoint.py --to-pth model.safetensors model.pth
  convert_checkpoint.py --names-table model.safetensors

Official checkpoints are pickles. By default they are unpickled with an
allow-list (tensors, OrderedDict, argparse.Namespace, a few numpy types);
--trust-pickle lifts it for files you trust.
"""

import argparse
import ast
import collections
import io
import json
import math
import os
import pickle
import re
import struct
import sys
import zipfile

import torch

DTYPE_NAMES = {torch.float32: "F32", torch.float16: "F16", torch.bfloat16: "BF16",
               torch.int64: "I64"}
NAME_DTYPES = {v: k for k, v in DTYPE_NAMES.items()}
ITEM_SIZES = {"F32": 4, "F16": 2, "BF16": 2, "I64": 8}
# --dtype: the dtype of every floating tensor written.
STORAGE_DTYPES = {"f32": torch.float32, "bf16": torch.bfloat16, "f16": torch.float16}
MAX_HEADER = 100 << 20

# Official create_dpt_head widths (dust3r/heads/dpt_head.py) and DPTOutputAdapter
# defaults (croco/models/dpt_block.py).
OFFICIAL_DPT = {"feature_dim": 256, "last_dim": 128, "layer_dims": [96, 192, 384, 768]}
# Constructor defaults of AsymmetricCroCo3DStereo and CroCoNet.
DUST3R_DEFAULTS = {
    "output_mode": "pts3d", "head_type": "linear", "depth_mode": ("exp", -math.inf, math.inf),
    "conf_mode": ("exp", 1, math.inf), "freeze": "none", "img_size": 224, "patch_size": 16,
    "mask_ratio": 0.9, "norm_im2_in_dec": True, "pos_embed": "cosine",
}
# The DUSt3R model Spann3R is built on (DUSt3R_ViTLarge_BaseDecoder_512_dpt.pth);
# a Spann3R checkpoint does not record its arguments.
SPANN3R_DUST3R_MODEL = (
    "AsymmetricCroCo3DStereo(pos_embed='RoPE100', patch_embed_cls='ManyAR_PatchEmbed', "
    "img_size=(512, 512), head_type='dpt', output_mode='pts3d', depth_mode=('exp', -inf, inf), "
    "conf_mode=('exp', 1, inf), enc_embed_dim=1024, enc_depth=24, enc_num_heads=16, "
    "dec_embed_dim=768, dec_depth=12, dec_num_heads=12)")
# Spann3R constructor defaults (spann3r/model.py) and SpatialMemory defaults.
SPANN3R_DEFAULTS = {"use_feat": False, "mem_pos_enc": False, "memory_dropout": 0.15}
SPANN3R_VALUE_ENCODER_HEADS = 16  # hard-coded in Spann3R.set_memory_encoder


class ConvertError(Exception):
    pass


# ---------------------------------------------------------------------------
# safetensors


def tensor_bytes(t):
    t = t.detach().cpu().contiguous()
    if t.numel() == 0:
        return b""
    return t.reshape(-1).view(torch.uint8).numpy().tobytes()


def write_safetensors(path, tensors, metadata=None):
    """Same layout as long3r::save_safetensors: __metadata__ first, then the
    names sorted; data ordered by item size (largest first) then name, so every
    tensor is aligned without gaps; header padded with spaces to 8 bytes."""
    items = []
    for name in sorted(tensors):
        t = tensors[name]
        if t.dtype not in DTYPE_NAMES:
            raise ConvertError("tensor %r has dtype %s; only float32, float16, bfloat16 and int64 "
                               "are supported" % (name, t.dtype))
        items.append((name, DTYPE_NAMES[t.dtype], t))
    order = sorted(items, key=lambda it: -ITEM_SIZES[it[1]])  # stable: names stay sorted
    offsets = {}
    pos = 0
    for name, dt, t in order:
        n = t.numel() * ITEM_SIZES[dt]
        offsets[name] = (pos, pos + n)
        pos += n
    header = collections.OrderedDict()
    if metadata:
        header["__metadata__"] = collections.OrderedDict(sorted(metadata.items()))
    for name, dt, t in items:
        header[name] = collections.OrderedDict(
            [("dtype", dt), ("shape", list(t.shape)), ("data_offsets", list(offsets[name]))])
    text = json.dumps(header, ensure_ascii=False).encode("utf-8")
    text += b" " * ((8 - len(text) % 8) % 8)
    tmp = "%s.tmp.%d" % (path, os.getpid())
    try:
        with open(tmp, "wb") as f:
            f.write(struct.pack("<Q", len(text)))
            f.write(text)
            for _, _, t in order:
                f.write(tensor_bytes(t))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def read_safetensors(path):
    """Returns (OrderedDict name -> tensor in header order, metadata dict)."""
    with open(path, "rb") as f:
        data = f.read()
    if len(data) < 8:
        raise ConvertError("%s: too short for a safetensors file" % path)
    (n,) = struct.unpack("<Q", data[:8])
    if n > MAX_HEADER or n > len(data) - 8:
        raise ConvertError("%s: bad header length %d" % (path, n))
    try:
        header = json.loads(data[8:8 + n].decode("utf-8"),
                            object_pairs_hook=collections.OrderedDict)
    except ValueError as e:
        raise ConvertError("%s: header is not valid JSON: %s" % (path, e))
    if not isinstance(header, dict):
        raise ConvertError("%s: header is not a JSON object" % path)
    base = 8 + n
    metadata = header.pop("__metadata__", {}) or {}
    tensors = collections.OrderedDict()
    for name, e in header.items():
        if not isinstance(e, dict):
            raise ConvertError("%s: entry %r is not an object" % (path, name))
        dt = e.get("dtype")
        if dt not in NAME_DTYPES:
            raise ConvertError("%s: unsupported dtype %r for tensor %r" % (path, dt, name))
        shape = e["shape"]
        begin, end = e["data_offsets"]
        numel = 1
        for d in shape:
            if not isinstance(d, int) or d < 0:
                raise ConvertError("%s: bad shape %r for tensor %r" % (path, shape, name))
            numel *= d
        if not (0 <= begin <= end <= len(data) - base) or end - begin != numel * ITEM_SIZES[dt]:
            raise ConvertError("%s: bad data_offsets for tensor %r" % (path, name))
        if numel == 0:
            t = torch.empty(shape, dtype=NAME_DTYPES[dt])
        else:
            buf = bytearray(data[base + begin:base + end])
            t = torch.frombuffer(buf, dtype=NAME_DTYPES[dt]).reshape(shape)
        tensors[name] = t
    return tensors, metadata


# ---------------------------------------------------------------------------
# Loading .pth files


_ALLOWED_GLOBALS = {
    ("collections", "OrderedDict"),
    ("argparse", "Namespace"),
    ("torch._utils", "_rebuild_tensor_v2"),
    ("torch._utils", "_rebuild_tensor"),
    ("torch._utils", "_rebuild_parameter"),
    ("torch._utils", "_rebuild_parameter_with_state"),
    ("torch", "Size"),
    ("torch", "device"),
    ("numpy.core.multiarray", "scalar"),
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
    ("builtins", "set"),
    ("builtins", "frozenset"),
    ("builtins", "slice"),
    ("builtins", "complex"),
    ("pathlib", "PosixPath"),
    ("pathlib", "PurePosixPath"),
}


class _RestrictedUnpickler(pickle.Unpickler):
    """Reads the data.pkl of a torch zip checkpoint, building only
    allow-listed globals; tensor storages come from the archive's data/
    records."""

    def __init__(self, f, zf, prefix):
        super().__init__(f, encoding="utf-8")
        self._zf = zf
        self._prefix = prefix
        self._storages = {}  # key -> storage, so shared tensors stay shared

    def find_class(self, module, name):
        if module == "torch" and name.endswith("Storage") and \
                isinstance(getattr(torch, name, None), type):
            return getattr(torch, name)
        if (module, name) in _ALLOWED_GLOBALS:
            return super().find_class(module, name)
        if module == "torch" and isinstance(getattr(torch, name, None), torch.dtype):
            return getattr(torch, name)
        raise pickle.UnpicklingError(
            "refusing to unpickle %s.%s (not on the allow-list); rerun with --trust-pickle if you "
            "trust this file" % (module, name))

    def persistent_load(self, saved_id):
        if not isinstance(saved_id, tuple) or len(saved_id) < 3 or saved_id[0] != "storage":
            raise pickle.UnpicklingError("unexpected persistent id %r" % (saved_id,))
        storage_type, key = saved_id[1], str(saved_id[2])
        if key not in self._storages:
            dtype = storage_type.dtype
            try:
                raw = self._zf.read("%s/data/%s" % (self._prefix, key))
            except KeyError:
                raise pickle.UnpicklingError("storage record %r is missing" % key)
            itemsize = torch.tensor([], dtype=dtype).element_size()
            if len(raw) % itemsize:
                raise pickle.UnpicklingError("storage record %r has a partial element" % key)
            t = (torch.frombuffer(bytearray(raw), dtype=dtype) if raw
                 else torch.empty(0, dtype=dtype))
            self._storages[key] = t.storage()
        return self._storages[key]


def load_pth(path, trust_pickle=False):
    """Loads a torch.save file (zip format) onto the CPU. Without
    trust_pickle the pickle may only reference allow-listed globals (this does
    not rely on torch.load's pickle_module, which torch 1.13 ignores)."""
    if trust_pickle:
        return torch.load(path, map_location="cpu")
    if not zipfile.is_zipfile(path):
        raise ConvertError("%s is not a zip-format torch checkpoint (saved by torch < 1.6?); "
                           "rerun with --trust-pickle if you trust it" % path)
    with zipfile.ZipFile(path) as zf:
        pkls = [n for n in zf.namelist() if n.count("/") == 1 and n.endswith("/data.pkl")]
        if len(pkls) != 1:
            raise ConvertError("%s: expected one <archive>/data.pkl, found %s" % (path, pkls))
        prefix = pkls[0].split("/")[0]
        if "%s/byteorder" % prefix in zf.namelist() and \
                zf.read("%s/byteorder" % prefix).strip() != b"little":
            raise ConvertError("%s: big-endian checkpoints are not supported" % path)
        return _RestrictedUnpickler(io.BytesIO(zf.read(pkls[0])), zf, prefix).load()


# ---------------------------------------------------------------------------
# Model strings such as "AsymmetricCroCo3DStereo(pos_embed='RoPE100', ...)"


def _literal(node, text):
    """Evaluates a literal expression (numbers, strings, tuples, lists, dicts,
    True/False/None, inf, nan, unary minus) without executing anything."""
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, ast.Name):
        names = {"inf": math.inf, "nan": math.nan, "True": True, "False": False, "None": None}
        if node.id in names:
            return names[node.id]
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        v = _literal(node.operand, text)
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            return -v if isinstance(node.op, ast.USub) else v
    if isinstance(node, ast.Tuple):
        return tuple(_literal(e, text) for e in node.elts)
    if isinstance(node, ast.List):
        return [_literal(e, text) for e in node.elts]
    if isinstance(node, ast.Dict):
        return {_literal(k, text): _literal(v, text) for k, v in zip(node.keys, node.values)}
    raise ConvertError("cannot interpret %r in the model string %r; give the configuration with "
                       "--config-json" % (ast.get_source_segment(text, node) or ast.dump(node), text))


def parse_model_string(text):
    """'Cls(a=1, b=(2, 3))' -> ('Cls', {'a': 1, 'b': (2, 3)})."""
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as e:
        raise ConvertError("model string %r is not a call expression: %s" % (text, e))
    call = tree.body
    if not isinstance(call, ast.Call) or not isinstance(call.func, (ast.Name, ast.Attribute)):
        raise ConvertError("model string %r is not of the form Class(arg=value, ...)" % text)
    if call.args:
        raise ConvertError("model string %r has positional arguments" % text)
    name = call.func.id if isinstance(call.func, ast.Name) else call.func.attr
    return name, {kw.arg: _literal(kw.value, text) for kw in call.keywords}


def _py_literal(v):
    if isinstance(v, float) and math.isinf(v):
        return "inf" if v > 0 else "-inf"
    if isinstance(v, (list, tuple)):
        inner = ", ".join(_py_literal(x) for x in v)
        return "(%s%s)" % (inner, "," if len(v) == 1 else "") if isinstance(v, tuple) else \
            "[%s]" % inner
    return repr(v)


def _mode_to_json(mode):
    """('exp', -inf, inf) -> ["exp", "-inf", "inf"] (JSON has no infinities)."""
    out = []
    for v in mode:
        if isinstance(v, float) and math.isinf(v):
            out.append("inf" if v > 0 else "-inf")
        elif isinstance(v, float) and v.is_integer():
            out.append(int(v))
        else:
            out.append(v)
    return out


def _mode_from_json(mode):
    return tuple(math.inf if v == "inf" else -math.inf if v == "-inf" else v for v in mode)


# ---------------------------------------------------------------------------
# Configuration from arguments and tensor shapes


def _count_blocks(sd, prefix):
    idx = set()
    pat = re.compile(re.escape(prefix) + r"(\d+)\.")
    for k in sd:
        m = pat.match(k)
        if m:
            idx.add(int(m.group(1)))
    if idx and idx != set(range(len(idx))):
        raise ConvertError("blocks under %r are not numbered 0..N-1: %s" % (prefix, sorted(idx)))
    return len(idx)


def _shape(sd, key):
    if key not in sd:
        raise ConvertError("expected tensor %r is missing from the checkpoint" % key)
    return list(sd[key].shape)


def _int_if_integral(x):
    return int(x) if float(x).is_integer() else x


def _guess_heads(dim, what, warnings):
    # ViT convention: 64-dimensional heads (true for every official DUSt3R model).
    heads = dim // 64 if dim % 64 == 0 and dim >= 64 else 1
    warnings.append("%s not recorded in the checkpoint; assumed %d (64-dim heads), override with "
                    "--config-json if wrong" % (what, heads))
    return heads


def infer_dust3r(sd, p, kwargs, landscape_only, warnings):
    """The "dust3r" section from the model arguments (kwargs, may be empty) and
    the tensor shapes of the state dict sd under prefix p."""
    kw = dict(DUST3R_DEFAULTS)
    kw.update(kwargs)
    pe = _shape(sd, p + "patch_embed.proj.weight")
    enc_dim, patch = pe[0], pe[2]
    if pe[2] != pe[3]:
        raise ConvertError("non-square patches %s are not supported" % pe)
    dec_dim = _shape(sd, p + "decoder_embed.weight")[0]
    enc_depth = _count_blocks(sd, p + "enc_blocks.")
    dec_depth = _count_blocks(sd, p + "dec_blocks.")
    mlp_ratio = _int_if_integral(_shape(sd, p + "enc_blocks.0.mlp.fc1.weight")[0] / enc_dim)
    for key, have in (("enc_embed_dim", enc_dim), ("dec_embed_dim", dec_dim),
                      ("enc_depth", enc_depth), ("dec_depth", dec_depth), ("patch_size", patch)):
        if key in kwargs and kwargs[key] != have:
            raise ConvertError("model arguments say %s=%r but the weights have %r"
                               % (key, kwargs[key], have))
    head_type = "dpt" if any(k.startswith(p + "downstream_head1.dpt.") for k in sd) else "linear"
    if "head_type" in kwargs and kwargs["head_type"] != head_type:
        raise ConvertError("model arguments say head_type=%r but the weights hold a %r head"
                           % (kwargs["head_type"], head_type))
    pos_embed = kw["pos_embed"]
    if "pos_embed" not in kwargs:
        pos_embed = "cosine" if (p + "enc_pos_embed") in sd else "RoPE100"
        if pos_embed == "RoPE100":
            warnings.append("pos_embed not recorded; no cosine embedding in the weights, so "
                            "assumed RoPE100 (every official DUSt3R model)")
    img = kw["img_size"]
    img = [img, img] if isinstance(img, int) else list(img)
    enc_heads = kw["enc_num_heads"] if "enc_num_heads" in kw else \
        _guess_heads(enc_dim, "enc_num_heads", warnings)
    dec_heads = kw["dec_num_heads"] if "dec_num_heads" in kw else \
        _guess_heads(dec_dim, "dec_num_heads", warnings)
    for dim, heads, what in ((enc_dim, enc_heads, "enc"), (dec_dim, dec_heads, "dec")):
        if dim % heads:
            raise ConvertError("%s_embed_dim %d is not divisible by %s_num_heads %d"
                               % (what, dim, what, heads))
    cfg = {
        "output_mode": kw["output_mode"], "head_type": head_type,
        "depth_mode": _mode_to_json(kw["depth_mode"]), "conf_mode": _mode_to_json(kw["conf_mode"]),
        "freeze": kw["freeze"], "landscape_only": landscape_only,
        # The official loader builds every model with PatchEmbedDust3R (same weights).
        "patch_embed_cls": "PatchEmbedDust3R",
        "img_size": img, "patch_size": patch,
        "enc_embed_dim": enc_dim, "enc_depth": enc_depth, "enc_num_heads": enc_heads,
        "dec_embed_dim": dec_dim, "dec_depth": dec_depth, "dec_num_heads": dec_heads,
        "mlp_ratio": mlp_ratio, "norm_layer": "LayerNorm(eps=1e-6)",
        "norm_im2_in_dec": kw["norm_im2_in_dec"], "pos_embed": pos_embed,
        "mask_ratio": kw["mask_ratio"],
    }
    if head_type == "dpt":
        h = p + "downstream_head1.dpt."
        feature_dim = _shape(sd, h + "scratch.layer1_rn.weight")[0]
        last_dim = _shape(sd, h + "head.2.weight")[0]
        num_channels = _shape(sd, h + "head.4.weight")[0]
        layer_dims = [_shape(sd, h + "act_postprocess.%d.0.weight" % i)[0] for i in range(4)]
        dim_tokens = [_shape(sd, h + "act_postprocess.%d.0.weight" % i)[1] for i in range(4)]
        if dim_tokens != [enc_dim, dec_dim, dec_dim, dec_dim]:
            raise ConvertError("DPT input widths %s do not match enc/dec widths %d/%d"
                               % (dim_tokens, enc_dim, dec_dim))
        if dec_depth <= 9:
            raise ConvertError("the DPT head needs dec_depth > 9, the weights have %d" % dec_depth)
        dpt = {
            "feature_dim": feature_dim, "last_dim": last_dim, "layer_dims": layer_dims,
            "hooks": [0, dec_depth * 2 // 4, dec_depth * 3 // 4, dec_depth],
            "dim_tokens": dim_tokens, "num_channels": num_channels, "head_type": "regression",
            "output_width_ratio": 1, "stride_level": 1, "patch_size": 16,
            "use_bn": any(".bn1." in k for k in sd if k.startswith(h)),
        }
        if {k: dpt[k] for k in OFFICIAL_DPT} != OFFICIAL_DPT:
            dpt["note"] = ("official create_dpt_head hardcodes feature_dim=256, last_dim=128, "
                           "layer_dims=[96,192,384,768]; these widths were read from the "
                           "checkpoint's tensor shapes")
        cfg["dpt_head"] = dpt
    return cfg


def infer_spann3r(sd, kwargs, dust3r_cfg, warnings):
    """The "spann3r" and "spatial_memory" sections."""
    kw = dict(SPANN3R_DEFAULTS)
    kw.update(kwargs)
    use_feat = "pos_patch_embed.proj.weight" not in sd
    if "use_feat" in kwargs and kwargs["use_feat"] != use_feat:
        raise ConvertError("model arguments say use_feat=%r but the weights %s pos_patch_embed"
                           % (kwargs["use_feat"], "lack" if use_feat else "have"))
    depth = _count_blocks(sd, "value_encoder.")
    embed = _shape(sd, "value_encoder.0.norm1.weight")[0]
    mlp = _int_if_integral(_shape(sd, "value_encoder.0.mlp.fc1.weight")[0] / embed)
    out_dim = _shape(sd, "value_out.weight")[0]
    a1 = _shape(sd, "attn_head_1.0.weight")
    a2 = _shape(sd, "attn_head_1.2.weight")
    mem_dim = _shape(sd, "norm_q.weight")[0]
    heads = SPANN3R_VALUE_ENCODER_HEADS
    if embed % heads:
        heads = _guess_heads(embed, "value encoder num_heads", warnings)
    spann3r = {
        "use_feat": use_feat, "mem_pos_enc": kw["mem_pos_enc"],
        "memory_dropout": kw["memory_dropout"],
        "value_encoder": {
            "depth": depth, "embed_dim": embed, "num_heads": heads, "mlp_ratio": mlp,
            "qkv_bias": "value_encoder.0.attn.qkv.bias" in sd,
            "norm_layer": "LayerNorm(eps=1e-6)",
            "rope": dust3r_cfg["pos_embed"] if kw["mem_pos_enc"] else None, "out_dim": out_dim},
        "norm_qkv": "LayerNorm(%d) eps=1e-5 (norm_q, norm_k, norm_v)" % mem_dim,
        "attn_head": "Sequential(Linear(%d,%d), GELU(exact), Linear(%d,%d))"
                     % (a1[1], a1[0], a2[1], a2[0]),
    }
    if not use_feat:
        spann3r["pos_patch_embed"] = ("PatchEmbedDust3R(patch %d, 3 -> enc_dim) applied to pts3d "
                                      "(NCHW)" % dust3r_cfg["patch_size"])
    memory = {"long_mem_size": 4000, "top_k": 4000, "work_mem_size": 5, "attn_thresh": 0.0005,
              "sim_thresh": 0.95, "mem_dropout": None, "num_patches": None,
              "note": "official eval-mode SpatialMemory defaults; num_patches is set by the "
                      "first frame"}
    return spann3r, memory


_MISSING = object()


def _get(cfg, path):
    for k in path.split("."):
        if not isinstance(cfg, dict) or k not in cfg:
            return _MISSING
        cfg = cfg[k]
    return cfg


# Fields of a configuration that the tensor shapes determine.
SHAPE_FIELDS = ["enc_embed_dim", "enc_depth", "dec_embed_dim", "dec_depth", "patch_size",
                "mlp_ratio", "head_type", "dpt_head.feature_dim", "dpt_head.last_dim",
                "dpt_head.layer_dims", "dpt_head.dim_tokens", "dpt_head.num_channels"]
SPANN3R_SHAPE_FIELDS = ["value_encoder.depth", "value_encoder.embed_dim",
                        "value_encoder.mlp_ratio", "value_encoder.out_dim", "use_feat"]


def check_config_against_weights(config, inferred):
    """Every shape-determined field of a given config must agree with the weights."""
    problems = []
    if inferred and config.get("model") != inferred.get("model"):
        problems.append("model is %r but the weights are of a %r" % (config.get("model"),
                                                                     inferred.get("model")))
    pairs = [("dust3r." + f, f, "dust3r") for f in SHAPE_FIELDS]
    pairs += [("spann3r." + f, f, "spann3r") for f in SPANN3R_SHAPE_FIELDS]
    for full, field, section in pairs:
        want = _get(inferred.get(section, {}), field)
        have = _get(config.get(section, {}), field)
        if want is _MISSING:
            continue
        if have is _MISSING:
            problems.append("%s is missing (the weights say %r)" % (full, want))
        elif have != want:
            problems.append("%s is %r but the weights say %r" % (full, have, want))
    if problems:
        raise ConvertError("the given configuration does not match the weights:\n  "
                           + "\n  ".join(problems))


def model_string(config):
    """An official-style model string for a config (for --to-pth)."""
    model = config.get("model", "")
    if model == "AsymmetricCroCo3DStereo":
        d = config["dust3r"]
        args = [("pos_embed", d["pos_embed"]), ("img_size", tuple(d["img_size"])),
                ("head_type", d["head_type"]), ("output_mode", d["output_mode"]),
                ("depth_mode", _mode_from_json(d["depth_mode"])),
                ("conf_mode", _mode_from_json(d["conf_mode"])),
                ("enc_embed_dim", d["enc_embed_dim"]), ("enc_depth", d["enc_depth"]),
                ("enc_num_heads", d["enc_num_heads"]), ("dec_embed_dim", d["dec_embed_dim"]),
                ("dec_depth", d["dec_depth"]), ("dec_num_heads", d["dec_num_heads"]),
                ("landscape_only", d["landscape_only"])]
    elif model == "Spann3R":
        s = config["spann3r"]
        args = [("dus3r_name", ""), ("use_feat", s["use_feat"]), ("mem_pos_enc", s["mem_pos_enc"]),
                ("memory_dropout", s["memory_dropout"])]
    else:
        return None
    return "%s(%s)" % (model, ", ".join("%s=%s" % (k, _py_literal(v)) for k, v in args))


# ---------------------------------------------------------------------------
# Commands


def _args_model_string(ckpt):
    args = ckpt.get("args")
    if args is None:
        return None
    if isinstance(args, dict):
        return args.get("model")
    return getattr(args, "model", None)


def _config_from_ckpt(ckpt):
    cfg = ckpt.get("config")
    if isinstance(cfg, str):
        cfg = json.loads(cfg)
    return cfg


def detect_kind(ckpt, sd):
    cfg = _config_from_ckpt(ckpt)
    if isinstance(cfg, dict) and str(cfg.get("model", "")).lower().startswith("long3r"):
        return "long3r"
    if any(k.startswith("dust3r.") for k in sd):
        return "spann3r"
    ms = _args_model_string(ckpt) or ""
    if ms.startswith("Spann3R"):
        return "spann3r"
    if ms.startswith("AsymmetricCroCo3DStereo") or any(k.startswith("dec_blocks") for k in sd):
        return "dust3r"
    raise ConvertError("cannot tell which model this checkpoint holds; use --kind")


def to_safetensors(opts):
    ckpt = load_pth(opts.input, opts.trust_pickle)
    if not isinstance(ckpt, dict):
        raise ConvertError("%s does not hold a dict" % opts.input)
    sd = ckpt.get("model", ckpt.get("state_dict"))
    if sd is None:
        # A bare state dict.
        sd = ckpt if all(isinstance(v, torch.Tensor) for v in ckpt.values()) else None
    if not isinstance(sd, dict) or not sd:
        raise ConvertError("%s has no 'model' state dict" % opts.input)
    if all(k.startswith("module.") for k in sd):  # saved from DistributedDataParallel
        sd = collections.OrderedDict((k[len("module."):], v) for k, v in sd.items())
    for k, v in sd.items():
        if not isinstance(v, torch.Tensor):
            raise ConvertError("state dict entry %r is not a tensor" % k)
    kind = detect_kind(ckpt, sd) if opts.kind == "auto" else opts.kind
    warnings = []  # about guessed configuration values
    notes = []  # about changes to the weights

    given = None
    if opts.config_json:
        with open(opts.config_json) as f:
            given = json.load(f)
    elif _config_from_ckpt(ckpt) is not None:
        given = _config_from_ckpt(ckpt)

    if kind == "dust3r":
        if any(k.startswith("dust3r.") for k in sd):
            raise ConvertError("the keys are 'dust3r.'-prefixed: this is a Spann3R checkpoint")
        if not any(k.startswith("dec_blocks2.") for k in sd):
            # As the official load_state_dict: the second decoder starts as a copy.
            notes.append("no dec_blocks2 in the weights; copied from dec_blocks as the "
                         "official loader does")
            for k in list(sd):
                if k.startswith("dec_blocks."):
                    sd["dec_blocks2." + k[len("dec_blocks."):]] = sd[k].clone()
        ms = _args_model_string(ckpt)
        kwargs = {}
        if ms:
            name, kwargs = parse_model_string(ms)
            if name != "AsymmetricCroCo3DStereo":
                raise ConvertError("args.model builds %s, not AsymmetricCroCo3DStereo" % name)
        else:
            warnings.append("no args.model in the checkpoint; configuration inferred from the "
                            "tensor shapes and the official defaults")
        # DUSt3R's own loader runs with landscape_only=False unless told otherwise.
        inferred = {"model": "AsymmetricCroCo3DStereo",
                    "dust3r": infer_dust3r(sd, "", kwargs, kwargs.get("landscape_only", False),
                                           warnings)}
    elif kind == "spann3r":
        if not any(k.startswith("dust3r.") for k in sd):
            raise ConvertError("no 'dust3r.'-prefixed keys: not a Spann3R checkpoint")
        ms = _args_model_string(ckpt)
        kwargs = {}
        if ms:
            name, kwargs = parse_model_string(ms)
            if name != "Spann3R":
                raise ConvertError("args.model builds %s, not Spann3R" % name)
            kwargs.pop("dus3r_name", None)
        if opts.dust3r_model:
            _, dkw = parse_model_string(opts.dust3r_model)
        else:
            # The defaults describe the ViT-L model; its sizes (and so its head
            # counts) only apply if the weights have them.
            _, dkw = parse_model_string(SPANN3R_DUST3R_MODEL)
            sizes = ("enc_embed_dim", "enc_depth", "dec_embed_dim", "dec_depth")
            pe = _shape(sd, "dust3r.patch_embed.proj.weight")
            have = (pe[0], _count_blocks(sd, "dust3r.enc_blocks."),
                    _shape(sd, "dust3r.decoder_embed.weight")[0],
                    _count_blocks(sd, "dust3r.dec_blocks."))
            if tuple(dkw[k] for k in sizes) != have:
                for k in sizes + ("enc_num_heads", "dec_num_heads"):
                    dkw.pop(k)
        # Spann3R builds its DUSt3R with landscape_only=True.
        dcfg = infer_dust3r(sd, "dust3r.", dkw, True, warnings)
        spann3r, memory = infer_spann3r(sd, kwargs, dcfg, warnings)
        inferred = {"model": "Spann3R", "dust3r": dcfg, "spann3r": spann3r,
                    "spatial_memory": memory}
    elif kind == "long3r":
        if given is None:
            raise ConvertError("a LONG3R checkpoint needs its configuration: a 'config' entry in "
                               "the .pth or --config-json")
        inferred = {}
    else:
        raise ConvertError("unknown kind %r" % kind)

    if given is not None:
        check_config_against_weights(given, inferred)
        config = given
    else:
        config = inferred
    for w in notes + (warnings if given is None else []):
        print("warning: " + w, file=sys.stderr)

    # Every floating tensor in one dtype; the C++ loader loads them as stored
    # (a bfloat16 file gives a bfloat16 model) and converts once, to the
    # precision asked for.
    stored = STORAGE_DTYPES[opts.dtype]
    tensors = collections.OrderedDict()
    for k, v in sd.items():
        v = v.detach()
        if v.is_floating_point():
            v = v.to(stored)
        if v.dtype not in DTYPE_NAMES:
            raise ConvertError("tensor %r has dtype %s, which the format here does not carry"
                               % (k, v.dtype))
        tensors[k] = v
    write_safetensors(opts.output, tensors, {"config": json.dumps(config, sort_keys=True)})
    print("wrote %s: %s, %d tensors" % (opts.output, config.get("model", kind), len(tensors)),
          file=sys.stderr)


def to_pth(opts):
    tensors, metadata = read_safetensors(opts.input)
    ckpt = {"model": collections.OrderedDict(tensors)}
    if "config" in metadata:
        config = json.loads(metadata["config"])
        ckpt["config"] = config
        ms = model_string(config)
        if ms:
            ckpt["args"] = argparse.Namespace(model=ms)
    torch.save(ckpt, opts.output)
    print("wrote %s: %d tensors" % (opts.output, len(tensors)), file=sys.stderr)


# Name parts collapsed in --names-table: indices of repeated blocks and the
# numbered copies of DPT heads, fusion blocks and key heads.
_COLLAPSE = [
    (re.compile(r"\b(enc_blocks|dec_blocks2?|value_encoder|layer_rn|act_postprocess)\.\d+\."),
     r"\1.{i}."),
    (re.compile(r"\bdownstream_head[12]\."), "downstream_head{h}."),
    (re.compile(r"\brefinenet[1-4]\."), "refinenet{n}."),
    (re.compile(r"\blayer[1-4]_rn\."), "layer{n}_rn."),
    (re.compile(r"\battn_head_[12]\."), "attn_head_{j}."),
]


def names_table(opts):
    """Markdown table of tensor names with block indices collapsed."""
    tensors, _ = read_safetensors(opts.input)
    rows = collections.OrderedDict()
    for name, t in tensors.items():
        pattern = name
        for rx, repl in _COLLAPSE:
            pattern = rx.sub(repl, pattern)
        row = rows.setdefault(pattern, [0, []])
        row[0] += 1
        if list(t.shape) not in row[1]:
            row[1].append(list(t.shape))
    print("| name | count | shape |")
    print("| --- | --- | --- |")
    for pattern, (count, shapes) in rows.items():
        print("| `%s` | %d | %s |" % (pattern, count, " or ".join(str(s) for s in shapes)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("input")
    ap.add_argument("output", nargs="?")
    ap.add_argument("--kind", choices=["auto", "dust3r", "spann3r", "long3r"], default="auto")
    ap.add_argument("--dtype", choices=sorted(STORAGE_DTYPES), default="f32",
                    help="store floating tensors as float32 (default), bfloat16 or float16")
    ap.add_argument("--config-json", help="configuration to store instead of the inferred one "
                    "(checked against the tensor shapes)")
    ap.add_argument("--dust3r-model", help="model string of the DUSt3R inside a Spann3R "
                    "checkpoint (default: the 512 DPT model Spann3R is built on)")
    ap.add_argument("--trust-pickle", action="store_true",
                    help="unpickle without the allow-list (only for files you trust)")
    ap.add_argument("--to-pth", action="store_true",
                    help="convert a safetensors file back to a .pth {'model', 'config', 'args'}")
    ap.add_argument("--names-table", action="store_true",
                    help="print the tensor names of a safetensors file as a markdown table")
    opts = ap.parse_args(argv)
    try:
        if opts.names_table:
            names_table(opts)
            return 0
        if not opts.output:
            ap.error("an output path is needed")
        if opts.to_pth:
            to_pth(opts)
        else:
            to_safetensors(opts)
    except (ConvertError, pickle.UnpicklingError, OSError, KeyError, ValueError) as e:
        print("error: %s" % e, file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
