#!/usr/bin/python3
"""Data-parallel long3r_train under torchrun on this CPU (c10d, Gloo):

  * two ranks (torchrun --nproc_per_node 2 --no_python) train long3r_tiny for
    three steps, and after every step both hold bit-identical weights
    (--verify-replicas);
  * the weights and logged losses match one process trained on the same
    global batch, within float tolerance;
  * the two-rank run's step-2 checkpoint, resumed in one process, reproduces
    its step 3;
  * a SIGTERM to one rank ends both after the same step, with that step's
    checkpoint, and the job succeeds (a sitting stopped early loses nothing);
  * a rank killed mid-run ends the job, with that rank named, instead of a
    hang.
"""
import argparse
import csv
import json
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_test import check, free_port, fresh_dir, run  # noqa: E402

CONFIG = {
    "model": "long3r_tiny",
    "image_size": 64,
    # batch_size is the global batch: one sequence per rank with two ranks.
    "stages": [{"name": "s1", "steps": 400, "frames": 3, "batch_size": 2, "lr": 1e-3,
                "warmup_steps": 1}],
    "data": {"synth": {"train_scenes": 4, "val_scenes": 1, "trajectory_frames": 30},
             "max_stride": 3},
    "validation": {"sequences": 0},
    "checkpoint_every": 1,
    "keep_checkpoints": 5,
}


def torchrun(a, args):
    # --redirects/--tee 1: Debian 12's torchrun (torch 1.13 on Python 3.11)
    # cannot parse its own default "0" for them (docs/training.md).
    return [a.torchrun, "--nproc_per_node", "2", "--master_addr", "127.0.0.1",
            "--master_port", str(free_port()), "--redirects", "1", "--tee", "1",
            "--no_python", a.train] + args


def read_safetensors(path):
    with open(path, "rb") as f:
        n = struct.unpack("<Q", f.read(8))[0]
        header = json.loads(f.read(n))
        data = f.read()
    out = {}
    for name, info in header.items():
        if name == "__metadata__":
            continue
        check(info["dtype"] == "F32", "%s: dtype %s" % (name, info["dtype"]))
        b, e = info["data_offsets"]
        out[name] = np.frombuffer(data[b:e], dtype="<f4").reshape(info["shape"])
    return out


def log_rows(out):
    return list(csv.DictReader(open(os.path.join(out, "train_log.csv"))))


def compare_models(a, b, init, what):
    """Weights a and b (trained from init) agree within float tolerance: no
    element differs by more than 2e-5 (weights are of order 1), and the
    difference is under 1e-4 of the distance trained. Adam turns the float
    noise of gradients that are zero in exact arithmetic (a key's bias before
    a softmax) into updates of its own, so single elements of such tensors
    may differ by as much as they moved; they stay far below these bounds."""
    ta, tb, t0 = read_safetensors(a), read_safetensors(b), read_safetensors(init)
    check(sorted(ta) == sorted(tb) == sorted(t0), what + ": the same tensors")
    worst = max(float(np.abs(ta[k] - tb[k]).max()) for k in ta)
    diff = sum(float(np.sum((ta[k] - tb[k]).astype(np.float64) ** 2)) for k in ta) ** 0.5
    moved = sum(float(np.sum((tb[k] - t0[k]).astype(np.float64) ** 2)) for k in ta) ** 0.5
    print("%s: largest element difference %.3g, %.3g of the distance trained (%.4g)" %
          (what, worst, diff / moved, moved))
    check(moved > 0, what + ": the weights moved")
    check(worst <= 2e-5, "%s: an element differs by %.3g (bound 2e-5)" % (what, worst))
    check(diff <= 1e-4 * moved, "%s: weights differ by %.3g of the distance trained (bound 1e-4)"
          % (what, diff / moved))


def compare_losses(ra, rb, what, rtol):
    for x, y in zip(ra, rb):
        for k in ("loss", "conf_loss", "scale_loss", "regression"):
            u, v = float(x[k]), float(y[k])
            check(abs(u - v) <= rtol * max(1e-6, abs(v)),
                  "%s: step %s %s %.8g vs %.8g" % (what, x["step"], k, u, v))


def processes_of_rank(train, out, rank):
    """The pids of long3r_train processes writing to `out` as rank `rank`."""
    pids = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            cmd = open("/proc/%s/cmdline" % d, "rb").read().split(b"\0")
            env = open("/proc/%s/environ" % d, "rb").read().split(b"\0")
        except OSError:
            continue
        if cmd and cmd[0].decode(errors="replace") == train and out.encode() in cmd and \
                ("RANK=%d" % rank).encode() in env:
            pids.append(int(d))
    return pids


def signal_rank_1_at_step_2(a, cfg, out_dir, sig):
    """Runs two ranks under torchrun into out_dir and sends `sig` to rank 1
    once rank 0 logs step 2. Returns the job's exit code, its output (lines)
    and when the signal went (None if the run never reached step 2)."""
    cmd = torchrun(a, ["--config", cfg, "--threads", "1", "--seed", "3", "--out", out_dir])
    job = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    out = []
    t_signal = None
    t0 = time.time()
    for line in job.stdout:
        out.append(line)
        if t_signal is None and re.search(r"step +2/", line):
            pids = processes_of_rank(a.train, out_dir, 1)
            check(len(pids) == 1, "one rank-1 process: %s" % pids)
            os.kill(pids[0], sig)
            t_signal = time.time()
        if time.time() - t0 > 300:
            job.kill()
            check(False, "the job did not end after signal %d to rank 1: %s" % (sig, "".join(out)))
    return job.wait(), out, t_signal


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--train", required=True)
    ap.add_argument("--torchrun", required=True)
    ap.add_argument("--workdir", required=True)
    a = ap.parse_args()
    a.train = os.path.realpath(a.train)
    fresh_dir(a.workdir)
    cfg = os.path.join(a.workdir, "train.json")
    with open(cfg, "w") as f:
        json.dump(CONFIG, f)
    common = ["--config", cfg, "--threads", "1", "--seed", "3", "--max-steps", "3"]

    # Two ranks, three steps, replicas checked after each.
    two = os.path.join(a.workdir, "two_ranks")
    rc, log = run(torchrun(a, common + ["--out", two, "--verify-replicas"]),
                  timeout=600, merge_output=True)
    check(rc == 0, "two-rank run: " + log)
    check("data parallel: 2 ranks (torchrun, gloo)" in log, "the run names its group: " + log)
    same = re.findall(r"step (\d+): weights bit-identical on 2 ranks", log)
    check(same == ["1", "2", "3"], "bit-identical weights after every step: %s\n%s" % (same, log))
    rows_two = log_rows(two)
    check([r["step"] for r in rows_two] == ["1", "2", "3"], "rank 0 logs every step")
    check(re.search(r"\[default1\]:step", log) is None, "only rank 0 speaks for the job: " + log)

    # One process, the same global batch of two; and the weights before step 1.
    one = os.path.join(a.workdir, "one_process")
    rc, log = run([a.train] + common + ["--out", one, "--quiet"],
                  timeout=600, merge_output=True)
    check(rc == 0, "single-process run: " + log)
    init = os.path.join(a.workdir, "initial")
    rc, log = run([a.train] + common[:-1] + ["0", "--out", init, "--quiet"],
                  timeout=600, merge_output=True)
    check(rc == 0, "initial weights: " + log)
    initial = os.path.join(init, "model.safetensors")
    compare_models(os.path.join(two, "model.safetensors"), os.path.join(one, "model.safetensors"),
                   initial, "2 ranks vs 1 process")
    compare_losses(rows_two, log_rows(one), "2 ranks vs 1 process", 1e-5)

    # The two-rank checkpoint of step 2, resumed in one process (the run's
    # log goes with it: a checkpoint keeps only its row count).
    resumed = os.path.join(a.workdir, "resumed")
    os.makedirs(os.path.join(resumed, "checkpoint"))
    shutil.copy(os.path.join(two, "checkpoint", "step_00000002.pt"),
                os.path.join(resumed, "checkpoint"))
    shutil.copy(os.path.join(two, "train_log.csv"), resumed)
    with open(os.path.join(resumed, "checkpoint", "latest"), "w") as f:
        f.write("step_00000002.pt\n")
    rc, log = run([a.train] + common + ["--out", resumed, "--resume"],
                  timeout=600, merge_output=True)
    check(rc == 0 and "resumed at step 2" in log, "resume in one process: " + log)
    compare_models(os.path.join(resumed, "model.safetensors"),
                   os.path.join(two, "model.safetensors"), initial, "step 3 resumed vs 2 ranks")
    compare_losses(log_rows(resumed)[2:], rows_two[2:], "step 3 resumed vs 2 ranks", 1e-5)

    # A SIGTERM to rank 1 alone: both ranks stop after the same step, rank 0
    # writes that step's checkpoint and outputs, and the job succeeds.
    stopped = os.path.join(a.workdir, "stopped")
    rc, out, t_signal = signal_rank_1_at_step_2(a, cfg, stopped, signal.SIGTERM)
    text = "".join(out)
    check(t_signal is not None, "the run reached step 2: " + text)
    check(rc == 0, "a job whose rank was asked to stop succeeds: " + text)
    ended = re.search(r"stop requested: ending after step (\d+)", text)
    check(ended is not None and "stopped by stop_request" in text,
          "rank 0 says it stopped on request: " + text)
    last = int(ended.group(1))
    check(2 <= last < 400, "stopped soon after the signal, at step %d" % last)
    with open(os.path.join(stopped, "checkpoint", "latest")) as f:
        check(f.read().strip() == "step_%08d.pt" % last,
              "the checkpoint of step %d is the latest" % last)
    check([int(r["step"]) for r in log_rows(stopped)] == list(range(1, last + 1)),
          "the log holds every step up to the stop")
    print("SIGTERM to rank 1: both ranks stopped after step %d" % last)

    # A rank killed mid-run: the job ends, naming it.
    killed = os.path.join(a.workdir, "killed")
    rc, out, t_kill = signal_rank_1_at_step_2(a, cfg, killed, signal.SIGKILL)
    text = "".join(out)
    check(t_kill is not None, "the run reached step 2: " + text)
    check(rc != 0, "a job with a killed rank fails")
    print("the job ended %.1f s after rank 1 was killed; its last lines:" % (time.time() - t_kill))
    print("".join(out[-30:]))
    check(time.time() - t_kill < 120, "the job ended promptly")
    check(re.search(r"rank\s*:\s*1 \(local_rank: 1\)", text) is not None and
          re.search(r"exitcode\s*:\s*-9", text) is not None,
          "torchrun names the killed rank: " + text)
    print("PASS")


if __name__ == "__main__":
    main()
