#!/usr/bin/python3
"""Training throughput of long3r_train, side by side in one run: float32
against bfloat16 autocast (amp "bf16"), each with the batches prepared on the
training thread (--prefetch 0) and on a data thread (--prefetch 1):

  /usr/bin/python3 scripts/bench_train.py --train BUILD/long3r_train
      [--config config/train_ship_stage1.json] [--model-config NAME]
      [--steps 12] [--warmup 2] [--threads N] [--render-threads N]
      [--rounds 1] [--work DIR]

Each case trains the configuration's first stage from the same seed for
--steps steps (validation off) and reads the per-step times of its
train_log.csv, leaving out the first --warmup steps. Printed per case: the
median step time, the mean time the step waited for its batch, and frames
(batch_size x frames per sequence) per second at the median step. With
--rounds R the cases run R times, interleaved, and each column shows the
median over the rounds. A figure printer, not a test: a CPU without native
bfloat16 (AVX512-BF16 / AMX) refuses the bf16 cases, and the line says so.
"""
import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CASES = [("float32", "off", 0), ("float32", "off", 1), ("bfloat16", "bf16", 0),
         ("bfloat16", "bf16", 1)]


def bench_config(path, amp, steps):
    """The configuration with its first stage only, amp set, no validation and
    no checkpoint but the final one; and that stage."""
    with open(path) as f:
        cfg = json.load(f)
    stage = dict(cfg["stages"][0])
    stage["steps"] = max(int(stage["steps"]), steps)
    cfg["stages"] = [stage]
    cfg["amp"] = amp
    cfg.setdefault("validation", {})["sequences"] = 0
    cfg["checkpoint_every"] = 0
    cfg["comment"] = "bench_train.py case (amp %s) of %s" % (amp, path)
    return cfg, stage


def run_case(opts, work, frames, name, amp, prefetch, rnd):
    cfg, _ = bench_config(opts.config, amp, opts.steps)
    case_dir = os.path.join(work, "%s_prefetch%d_r%d" % (name, prefetch, rnd))
    os.makedirs(case_dir, exist_ok=True)
    cfg_path = os.path.join(case_dir, "config.json")
    with open(cfg_path, "w") as f:
        json.dump(cfg, f, indent=1)
    cmd = [opts.train, "--config", cfg_path, "--out", os.path.join(case_dir, "out"),
           "--max-steps", str(opts.steps), "--threads", str(opts.threads), "--prefetch",
           str(prefetch), "--seed", "7", "--quiet"]
    if opts.model_config:
        cmd += ["--model-config", opts.model_config]
    if opts.render_threads:
        cmd += ["--render-threads", str(opts.render_threads)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        lines = (proc.stderr or proc.stdout).strip().splitlines()
        return None, lines[-1] if lines else "exit %d" % proc.returncode
    with open(os.path.join(case_dir, "out", "train_log.csv")) as f:
        rows = list(csv.DictReader(f))[opts.warmup:]
    if not rows:
        return None, "no step after the warm-up"
    step_s = statistics.median(float(r["step_s"]) for r in rows)
    data_s = statistics.mean(float(r["data_s"]) for r in rows)
    return (step_s, data_s, frames / step_s), None


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--train", required=True, help="the long3r_train executable")
    p.add_argument("--config", default=os.path.join(ROOT, "config", "train_ship_stage1.json"))
    p.add_argument("--model-config", default="", help="overrides the configuration's model")
    p.add_argument("--steps", type=int, default=12)
    p.add_argument("--warmup", type=int, default=2, help="first steps left out of the figures")
    p.add_argument("--threads", type=int, default=os.cpu_count())
    p.add_argument("--render-threads", type=int, default=0,
                   help="threads rendering scenes (default: the trainer's, as --threads)")
    p.add_argument("--rounds", type=int, default=1)
    p.add_argument("--work", default="", help="folder for the runs (default: a temporary one)")
    opts = p.parse_args()
    if opts.steps <= opts.warmup:
        p.error("--steps must exceed --warmup")

    flags = open("/proc/cpuinfo").read()
    native = " avx512_bf16" in flags or " amx_bf16" in flags
    print("long3r_train throughput: %s%s, %d threads (%s rendering), %d steps (first %d left "
          "out), %d round(s); native bfloat16: %s" %
          (os.path.relpath(opts.config, ROOT) if opts.config.startswith(ROOT) else opts.config,
           " with " + opts.model_config if opts.model_config else "", opts.threads,
           opts.render_threads or opts.threads, opts.steps, opts.warmup, opts.rounds,
           "yes" if native else "no"))
    sys.stdout.flush()
    stage = bench_config(opts.config, "off", opts.steps)[1]
    frames = int(stage.get("batch_size", 1)) * int(stage["frames"])
    with tempfile.TemporaryDirectory(prefix="long3r_bench_train_") as tmp:
        work = opts.work or tmp
        results = {case: [] for case in CASES}
        refused = {}
        for rnd in range(opts.rounds):
            for case in CASES:
                if case in refused:
                    continue
                res, why = run_case(opts, work, frames, case[0], case[1], case[2], rnd)
                if res is None:
                    refused[case] = why
                else:
                    results[case].append(res)
    print("%-10s %-9s %12s %14s %10s" % ("precision", "prefetch", "step (s)", "data wait (s)",
                                         "frames/s"))
    base = None
    for case in CASES:
        name, _, prefetch = case
        if case in refused:
            print("%-10s %-9d refused: %s" % (name, prefetch, refused[case]))
            continue
        runs = results[case]
        step_s = statistics.median(r[0] for r in runs)
        data_s = statistics.median(r[1] for r in runs)
        fps = statistics.median(r[2] for r in runs)
        base = base or fps
        print("%-10s %-9d %12.3f %14.3f %10.2f   (%.2fx)" % (name, prefetch, step_s, data_s, fps,
                                                            fps / base))
    print("frames per step: %d (batch_size x frames of the first stage)" % frames)
    return 1 if len(refused) == len(CASES) else 0


if __name__ == "__main__":
    sys.exit(main())
