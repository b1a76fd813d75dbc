#!/usr/bin/python3
"""Round-trip test of scripts/convert_checkpoint.py on the golden weights:
builds official-style .pth files (DUSt3R {'model', 'args'}; Spann3R with
'dust3r.'-prefixed keys), converts them, and checks that every tensor comes
back bit-identical, that the stored config matches the golden one, that the
C++ loader (long3r_ckpt_info) reads every converted file, and that hostile
pickles and contradictory configs are refused.

usage: test_convert_roundtrip.py --script SCRIPT --info LONG3R_CKPT_INFO --golden GOLDEN_DIR
Exit 77 (skipped) when PyTorch is not importable.
"""
import argparse
import collections
import json
import os
import sys
import tempfile

try:
    import torch
except ImportError:
    print("PyTorch is not available to %s; skipping" % sys.executable)
    sys.exit(77)

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_test import Tally, load_script, run_process  # noqa: E402

# Every check runs; "ok  : <what>" or "FAIL: <what>", the failures summed up at the end.
CHECKS = Tally(ok="ok  : ", failed="FAIL: ")
check = CHECKS.check


def bits(t):
    t = t.contiguous()
    return t.dtype, tuple(t.shape), (t.reshape(-1).view(torch.uint8).numpy().tobytes()
                                     if t.numel() else b"")


def same_tensors(a, b, what):
    if not check(list(sorted(a)) == list(sorted(b)), "%s: same tensor names" % what):
        return False
    bad = [k for k in a if bits(a[k]) != bits(b[k])]
    return check(not bad, "%s: all %d tensors bit-identical %s" % (what, len(a), bad[:3]))


def without_notes(x):
    if isinstance(x, dict):
        return {k: without_notes(v) for k, v in x.items() if k != "note"}
    return x


def dust3r_model_string(d, patch_embed_cls="ManyAR_PatchEmbed"):
    """The official args.model form, written from a golden config."""
    def mode(m):
        return "(%s)" % ", ".join(repr(v) if not isinstance(v, str) or v not in ("inf", "-inf")
                                  else v for v in m)
    return ("AsymmetricCroCo3DStereo(pos_embed='%s', patch_embed_cls='%s', img_size=(%d, %d), "
            "head_type='%s', output_mode='%s', depth_mode=%s, conf_mode=%s, enc_embed_dim=%d, "
            "enc_depth=%d, enc_num_heads=%d, dec_embed_dim=%d, dec_depth=%d, dec_num_heads=%d, "
            "landscape_only=%s)" % (
                d["pos_embed"], patch_embed_cls, d["img_size"][0], d["img_size"][1],
                d["head_type"], d["output_mode"], mode(d["depth_mode"]), mode(d["conf_mode"]),
                d["enc_embed_dim"], d["enc_depth"], d["enc_num_heads"], d["dec_embed_dim"],
                d["dec_depth"], d["dec_num_heads"], d["landscape_only"]))


def share_dpt_aliases(sd, prefix):
    """As in an official state dict, scratch.layer_rn.{N-1} and scratch.layerN_rn
    are one tensor."""
    for h in (1, 2):
        for n in range(1, 5):
            base = "%sdownstream_head%d.dpt.scratch." % (prefix, h)
            sd[base + "layer_rn.%d.weight" % (n - 1)] = sd[base + "layer%d_rn.weight" % n]


class Hostile:
    """Unpickling this calls os.getpid: the allow-list must refuse it."""

    def __reduce__(self):
        return (os.getpid, ())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--script", required=True)
    ap.add_argument("--info", required=True)
    ap.add_argument("--golden", required=True)
    ap.add_argument("--linear-golden", help="folder of the linear-head golden case "
                    "(test/data/golden/dust3r_linear_sq64)")
    opts = ap.parse_args()
    conv = load_script(opts.script, "convert_checkpoint")
    py = sys.executable

    def convert(*args, expect_rc=0):
        return run_process([py, opts.script] + list(args), expect_rc=expect_rc)

    def cpp_reads(path, count):
        p = run_process([opts.info, "--no-tensors", path], expect_rc=0)
        return check(p.returncode == 0 and ("%d tensors" % count) in p.stdout,
                     "C++ loader reads %s (%d tensors)" % (os.path.basename(path), count))

    with tempfile.TemporaryDirectory() as tmp:
        def tmpf(name):
            return os.path.join(tmp, name)

        # ---- DUSt3R: {'model', 'args'} ----------------------------------------
        gd_path = os.path.join(opts.golden, "dust3r_pair_sq224", "weights.safetensors")
        gd, gd_meta = conv.read_safetensors(gd_path)
        gd_cfg = json.loads(gd_meta["config"])
        sd = collections.OrderedDict(gd)
        share_dpt_aliases(sd, "")
        args = argparse.Namespace(model=dust3r_model_string(gd_cfg["dust3r"]), epoch=3)
        torch.save({"model": sd, "args": args, "epoch": 3}, tmpf("dust3r.pth"))
        p = convert(tmpf("dust3r.pth"), tmpf("dust3r.safetensors"))
        check(p.returncode == 0, "DUSt3R .pth converts")
        if p.returncode == 0:
            out, meta = conv.read_safetensors(tmpf("dust3r.safetensors"))
            same_tensors(gd, out, "DUSt3R")
            cfg = json.loads(meta["config"])
            check(cfg["model"] == gd_cfg["model"], "DUSt3R model name")
            check(without_notes(cfg["dust3r"]) == without_notes(gd_cfg["dust3r"]),
                  "DUSt3R config matches the golden one (DPT widths read from shapes)")
            check("note" in cfg["dust3r"]["dpt_head"], "non-official DPT widths carry a note")
            cpp_reads(tmpf("dust3r.safetensors"), 661)

        # Without args: everything but the head counts, image size and modes is
        # inferred; the head count is guessed as width/64 (= 1 here).
        torch.save({"model": sd}, tmpf("dust3r_noargs.pth"))
        p = convert(tmpf("dust3r_noargs.pth"), tmpf("dust3r_noargs.safetensors"))
        if check(p.returncode == 0 and "enc_num_heads" in p.stderr,
                 "DUSt3R without args converts with a warning about guessed values"):
            cfg = json.loads(conv.read_safetensors(tmpf("dust3r_noargs.safetensors"))[1]["config"])
            d, g = cfg["dust3r"], gd_cfg["dust3r"]
            for k in ("enc_embed_dim", "enc_depth", "dec_embed_dim", "dec_depth", "patch_size",
                      "mlp_ratio", "pos_embed", "depth_mode", "conf_mode"):
                check(d[k] == g[k], "inferred dust3r.%s = %r" % (k, d[k]))
            check(without_notes(d["dpt_head"]) == without_notes(g["dpt_head"]),
                  "inferred DPT head matches")
            check(d["landscape_only"] is False, "DUSt3R defaults to landscape_only=False")

        # float16 and bfloat16 storage.
        for flag, dtype in (("f16", torch.float16), ("bf16", torch.bfloat16)):
            path = tmpf("dust3r_%s.safetensors" % flag)
            p = convert("--dtype", flag, tmpf("dust3r.pth"), path)
            if check(p.returncode == 0, "DUSt3R converts to %s" % flag):
                out, _ = conv.read_safetensors(path)
                same_tensors(collections.OrderedDict((k, v.to(dtype)) for k, v in gd.items()),
                             out, "DUSt3R %s" % flag)
                cpp_reads(path, 661)

        # ---- DUSt3R with the linear head (the official 224 linear layout) ------
        if opts.linear_golden:
            gl, gl_meta = conv.read_safetensors(os.path.join(opts.linear_golden,
                                                             "weights.safetensors"))
            gl_cfg = json.loads(gl_meta["config"])
            args = argparse.Namespace(model=dust3r_model_string(gl_cfg["dust3r"]), epoch=1)
            torch.save({"model": collections.OrderedDict(gl), "args": args, "epoch": 1},
                       tmpf("linear.pth"))
            p = convert(tmpf("linear.pth"), tmpf("linear.safetensors"))
            if check(p.returncode == 0, "DUSt3R linear-head .pth converts"):
                out, meta = conv.read_safetensors(tmpf("linear.safetensors"))
                same_tensors(gl, out, "DUSt3R linear head")
                cfg = json.loads(meta["config"])
                check(cfg["dust3r"]["head_type"] == "linear" and "dpt_head" not in cfg["dust3r"],
                      "linear head: no DPT section")
                check(without_notes(cfg["dust3r"]) == without_notes(gl_cfg["dust3r"]),
                      "linear-head config matches the golden one (patch size from the shapes)")
                cpp_reads(tmpf("linear.safetensors"), len(gl))

        # ---- Spann3R: 'dust3r.'-prefixed keys ----------------------------------
        gs_path = os.path.join(opts.golden, "spann3r_seq_sq224", "weights.safetensors")
        gs, gs_meta = conv.read_safetensors(gs_path)
        gs_cfg = json.loads(gs_meta["config"])
        sd = collections.OrderedDict(gs)
        share_dpt_aliases(sd, "dust3r.")
        args = argparse.Namespace(model="Spann3R(dus3r_name='./checkpoints/"
                                  "DUSt3R_ViTLarge_BaseDecoder_512_dpt.pth', use_feat=False, "
                                  "mem_pos_enc=False)")
        torch.save({"model": sd, "args": args, "epoch": 1}, tmpf("spann3r.pth"))
        with open(tmpf("spann3r_config.json"), "w") as f:
            json.dump(gs_cfg, f)
        p = convert("--config-json", tmpf("spann3r_config.json"), tmpf("spann3r.pth"),
                    tmpf("spann3r.safetensors"))
        if check(p.returncode == 0, "Spann3R .pth converts with --config-json"):
            out, meta = conv.read_safetensors(tmpf("spann3r.safetensors"))
            same_tensors(gs, out, "Spann3R")
            check(meta["config"] == gs_meta["config"], "Spann3R config string identical")
            cpp_reads(tmpf("spann3r.safetensors"), 705)

        p = convert(tmpf("spann3r.pth"), tmpf("spann3r_inferred.safetensors"))
        if check(p.returncode == 0, "Spann3R .pth converts without a config"):
            cfg = json.loads(
                conv.read_safetensors(tmpf("spann3r_inferred.safetensors"))[1]["config"])
            check(cfg["model"] == "Spann3R", "Spann3R detected")
            d, g = cfg["dust3r"], gs_cfg["dust3r"]
            for k in ("enc_embed_dim", "enc_depth", "dec_embed_dim", "dec_depth", "landscape_only",
                      "patch_embed_cls", "depth_mode", "conf_mode"):
                check(d[k] == g[k], "inferred Spann3R dust3r.%s = %r" % (k, d[k]))
            s, gsp = cfg["spann3r"], gs_cfg["spann3r"]
            for k in ("attn_head", "norm_qkv", "pos_patch_embed", "use_feat", "mem_pos_enc",
                      "memory_dropout"):
                check(s[k] == gsp[k], "inferred spann3r.%s = %r" % (k, s[k]))
            ve = s["value_encoder"]
            check((ve["depth"], ve["embed_dim"], ve["out_dim"], ve["mlp_ratio"]) == (2, 32, 32, 4),
                  "inferred value encoder sizes")
            check(ve["num_heads"] == 16, "value encoder heads: the official hard-coded 16")
            check(cfg["spatial_memory"]["long_mem_size"] == 4000, "official memory defaults")

        # A configuration that contradicts the weights is refused.
        bad = json.loads(json.dumps(gs_cfg))
        bad["dust3r"]["enc_embed_dim"] = 64
        bad["spann3r"]["value_encoder"]["depth"] = 6
        with open(tmpf("bad_config.json"), "w") as f:
            json.dump(bad, f)
        p = convert("--config-json", tmpf("bad_config.json"), tmpf("spann3r.pth"),
                    tmpf("bad.safetensors"), expect_rc=1)
        check(p.returncode == 1 and "dust3r.enc_embed_dim" in p.stderr
              and "spann3r.value_encoder.depth" in p.stderr
              and not os.path.exists(tmpf("bad.safetensors")),
              "contradictory --config-json refused, naming both fields")

        # ---- --to-pth and back ---------------------------------------------------
        for name, path, golden, count in (("DUSt3R", gd_path, gd, 661),
                                          ("Spann3R", gs_path, gs, 705)):
            pth = tmpf(name + "_back.pth")
            st = tmpf(name + "_back.safetensors")
            p1 = convert("--to-pth", path, pth)
            p2 = convert(pth, st) if p1.returncode == 0 else p1
            if check(p2.returncode == 0, "%s safetensors -> .pth -> safetensors" % name):
                back = conv.load_pth(pth)
                check(set(back) == {"model", "config", "args"}, "%s .pth has model/config/args"
                      % name)
                conv.parse_model_string(back["args"].model)
                out, meta = conv.read_safetensors(st)
                same_tensors(golden, out, name + " via .pth")
                check(json.loads(meta["config"]) == json.loads(
                    conv.read_safetensors(path)[1]["config"]), "%s config survives" % name)
                cpp_reads(st, count)

        # ---- hostile and broken inputs -----------------------------------------
        torch.save({"model": {"w": torch.ones(1)}, "args": Hostile()}, tmpf("hostile.pth"))
        p = convert(tmpf("hostile.pth"), tmpf("hostile.safetensors"), expect_rc=1)
        check(p.returncode == 1 and "refusing to unpickle posix.getpid" in p.stderr,
              "pickle with a non-allow-listed global refused")
        torch.save({"model": {"w": torch.ones(2, dtype=torch.int32)}}, tmpf("int32.pth"))
        p = convert("--kind", "long3r", "--config-json", tmpf("spann3r_config.json"),
                    tmpf("int32.pth"), tmpf("int32.safetensors"), expect_rc=1)
        check(p.returncode == 1 and "torch.int32" in p.stderr, "unsupported dtype refused")
        with open(tmpf("corrupt.safetensors"), "wb") as f:
            with open(gd_path, "rb") as g:
                f.write(g.read()[:5000])
        p = run_process([opts.info, tmpf("corrupt.safetensors")], expect_rc=1)
        check(p.returncode == 1 and "truncated" in p.stderr, "C++ loader rejects a truncated file")

    if CHECKS.failures:
        print("%d check(s) failed:\n  %s" % (len(CHECKS.failures), "\n  ".join(CHECKS.failures)))
        return 1
    print("all checks passed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
