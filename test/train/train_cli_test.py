#!/usr/bin/python3
"""End-to-end test of long3r_train: a few steps of every curriculum stage of
long3r_tiny on generated 64 x 64 scenes, an interrupted run resumed, the
outputs checked, and the trained model run through long3r_reconstruct."""
import argparse
import csv
import json
import math
import os
import re
import sys
import zipfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_test import check, fresh_dir, run  # noqa: E402


CONFIG = {
    "model": "long3r_tiny",
    "image_size": 64,
    "stages": [
        {"name": "s1", "steps": 3, "frames": 3, "batch_size": 2, "lr": 1e-3, "warmup_steps": 1},
        {"name": "s2a", "steps": 2, "frames": 4, "lr": 1e-4, "freeze_encoder": True},
        {"name": "s2b", "steps": 1, "frames": 6, "lr": 1e-4, "freeze_encoder": True},
    ],
    "data": {"synth": {"train_scenes": 4, "val_scenes": 1, "trajectory_frames": 30},
             "max_stride": 3},
    "validation": {"every": 3, "sequences": 1, "frames": 5, "stride": 2,
                   "blind_scenes": 1, "blind_starts": 2, "blind_strides": [2, 4]},
    "checkpoint_every": 2,
}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--train", required=True)
    ap.add_argument("--synth", required=True)
    ap.add_argument("--reconstruct", required=True)
    ap.add_argument("--model-eval", required=True)
    ap.add_argument("--ckpt-info", required=True)
    ap.add_argument("--workdir", required=True)
    a = ap.parse_args()
    fresh_dir(a.workdir)
    cfg = os.path.join(a.workdir, "train.json")
    with open(cfg, "w") as f:
        json.dump(CONFIG, f)
    out = os.path.join(a.workdir, "run")
    base = [a.train, "--config", cfg, "--out", out, "--threads", "2", "--seed", "3", "--quiet"]

    # Interrupted after 3 steps (checkpoint at 2), then resumed to the end.
    rc, log = run(base + ["--max-steps", "3"])
    check(rc == 0, "first run: " + log)
    check(open(os.path.join(out, "checkpoint", "latest")).read().strip() == "step_00000003.pt",
          "latest checkpoint after the first run")
    rc, log = run(base + ["--resume"])
    check(rc == 0, "resumed run: " + log)
    for name in ["model.safetensors", "train_log.csv", "loss_curve.png", "train_config.json"]:
        check(os.path.getsize(os.path.join(out, name)) > 0, name)
    check(open(os.path.join(out, "loss_curve.png"), "rb").read(4) == b"\x89PNG", "PNG header")
    rows = list(csv.DictReader(open(os.path.join(out, "train_log.csv"))))
    check([int(r["step"]) for r in rows] == list(range(1, 7)), "one CSV row per step: %s" %
          [r["step"] for r in rows])
    check([int(r["stage"]) for r in rows] == [1, 1, 1, 2, 2, 3], "stages in the log")
    for r in rows:
        check(float(r["loss"]) == float(r["loss"]) and float(r["lr"]) > 0, "row values: %s" % r)
    val = [r for r in rows if r["val_loss"] != "nan"]
    check([int(r["step"]) for r in val] == [3, 6], "validation rows: %s" % [r["step"] for r in val])
    for r in val:
        check(float(r["val_acc_mean_m"]) > 0 and float(r["val_comp_mean_m"]) > 0,
              "validation metrics: %s" % r)
        ratio, true, blind = (float(r[k]) for k in ["val_blind_ratio", "val_reg_true",
                                                    "val_reg_blind"])
        check(ratio > 0 and abs(ratio - true / blind) < 1e-6 * ratio,
              "blind control in validation: %s" % r)
        check(float(r["val_rot_true_deg"]) > 0, "relative rotation readout: %s" % r)
    # The blind control at every stride, a row per validation and stride; the
    # log's columns are its first stride's.
    blind_rows = list(csv.DictReader(open(os.path.join(out, "blind_control.csv"))))
    check([(int(b["step"]), int(b["stride"]), int(b["frames"])) for b in blind_rows] ==
          [(3, 2, 2), (3, 4, 2), (6, 2, 2), (6, 4, 2)], "blind_control.csv rows: %s" % blind_rows)
    for r in val:
        first = next(b for b in blind_rows if b["step"] == r["step"] and b["stride"] == "2")
        check(abs(float(first["blind_ratio"]) - float(r["val_blind_ratio"])) <=
              1e-6 * float(r["val_blind_ratio"]), "log = first stride: %s / %s" % (first, r))
        shape = float(r["val_shape_err"])
        check(0 < shape < float(r["val_reg_true"]) * 1.05, "shape error readout: %s" % r)
        check(math.isfinite(float(r["val_depth_slope"])), "depth response readout: %s" % r)
    check(all(r["val_completion_true"] == "nan" for r in rows),
          "no completion control without a completion stage")
    vj = json.load(open(os.path.join(out, "validation.json")))
    check(vj["blind_frames"] == 2 and vj["blind_ratio"] > 0, "validation.json: %s" % vj)
    ckpts = sorted(d for d in os.listdir(os.path.join(out, "checkpoint")) if d.startswith("step_"))
    check(ckpts == ["step_00000004.pt", "step_00000006.pt"], "kept checkpoints: %s" % ckpts)
    # One bundle per checkpoint (a libtorch zip archive) with every part of the state.
    bundle = os.path.join(out, "checkpoint", "step_00000006.pt")
    with zipfile.ZipFile(bundle) as z:
        pickled = b"".join(z.read(n) for n in z.namelist() if n.endswith(".pkl"))
    for part in [b"weights", b"optimizer", b"step", b"sampler_rng", b"torch_cpu_rng", b"wall_s",
                 b"model_config", b"train_config", b"train_log_rows"]:
        check(part in pickled, "checkpoint part %s" % part)

    model = os.path.join(out, "model.safetensors")
    rc, log = run([a.ckpt_info, "--no-tensors", model])
    check(rc == 0 and "LONG3R" in log, "ckpt_info: " + log)
    # The file records the size it was trained at, and the pipeline runs it
    # there (no --img-size below).
    check(re.search(r'"input_width": ?64\b', log) and re.search(r'"input_height": ?64\b', log),
          "the trained file records its input size: " + log)
    seq = os.path.join(a.workdir, "seq")
    rc, log = run([a.synth, "--out", seq, "--frames", "5", "--width", "64", "--height", "64",
                   "--seed", "77", "--quiet"])
    check(rc == 0, "long3r_synth: " + log)
    rc, log = run([a.reconstruct, "--model", model, "--out", os.path.join(a.workdir, "rec"),
                   "--threads", "2", "--conf-threshold", "1", seq])
    check(rc == 0 and "summary: 5 frames used" in log, "reconstruct with the trained model: " + log)
    check("model input 64x64" in log, "reconstruct runs the model at its trained size: " + log)

    # The blind control of the trained model, per length and stride.
    bj = os.path.join(a.workdir, "blind.json")
    rc, log = run([a.model_eval, "--model", model, "--blind-control", "--img-size", "64",
                   "--sequences", "1", "--blind-starts", "2", "--blind-stride", "2",
                   "--blind-stride", "6", "--blind-frames", "2", "--blind-frames", "3",
                   "--threads", "2", "--json", bj])
    check(rc == 0 and "blind_ratio" in log, "model_eval --blind-control: " + log)
    rows_b = json.load(open(bj))["blind_control"]
    check([(r["frames"], r["stride"], r["scored"]) for r in rows_b] ==
          [(2, 2, 2), (2, 6, 2), (3, 2, 4), (3, 6, 4)], "blind control rows: %s" % rows_b)
    for r in rows_b:
        check(r["blind_ratio"] > 0 and r["motion_tokens"] > 0, "blind control row: %s" % r)
    check(rows_b[1]["motion_px"] > rows_b[0]["motion_px"], "motion grows with the stride")
    rc, log = run([a.model_eval, "--baseline", "constant-depth", "--blind-control"])
    check(rc == 1 and "needs --model" in log, "blind control of a baseline: " + log)

    # Bad usage is refused.
    rc, log = run([a.train, "--config", cfg, "--out", os.path.join(a.workdir, "x"), "--resume"])
    check(rc == 1 and "no checkpoint" in log, "resume without checkpoint: " + log)
    rc, log = run([a.train, "--config", cfg, "--out", out, "--model-config", "long3r_small",
                   "--resume"])
    check(rc == 1 and "different model configuration" in log, "resume with another model: " + log)
    print("OK")


if __name__ == "__main__":
    main()
