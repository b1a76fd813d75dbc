#!/usr/bin/python3
"""Pairs per second of the pair stage (config/train_pairs_fast.json), side by
side in one run on this machine:

  /usr/bin/python3 scripts/bench_pairs.py --build BUILD [--reference DIR]
      [--budget-s 90] [--warmup 20] [--ranks N] [--scenes N] [--cache FILE]
      [--work DIR]

Cases, each trained for --budget-s seconds of wall time, one after another:
  reference   the minimal pair regressor of DIR/tiny3r.py (with --reference:
              a folder holding tiny3r.py and pack.py) at one thread, with the
              settings of its README, on 16 + 2 scenes that long3r_synth
              renders and its pack.py packs; its rate is the pairs of its
              training loop over the budget (its one validation at step 1
              included)
  rendered    long3r_train as the pair run was trained before: one process of
              all cores' threads, frames rendered on a data thread
              (--prefetch 1), float32
  cached      one process of one thread, frames from the frame cache
  ranks       --ranks processes of one thread each (data-parallel over
              loopback), frames from the frame cache, amp as the
              configuration says (bfloat16 where the CPU has it natively)
Our rates are the global batch's pairs over the wall time of the steps after
the first --warmup (from train_log.csv's wall_s); validation and checkpoints
off. The frame cache is --cache when given and fitting, else one written for
--scenes scenes into the work folder (its writing is not timed). A figure
printer, not a test: run it on a quiet machine, nothing built beside it.
"""
import argparse
import csv
import glob
import json
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = os.path.join(ROOT, "config", "train_pairs_fast.json")


def cpu_name():
    for line in open("/proc/cpuinfo"):
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown CPU"


def native_bf16():
    flags = open("/proc/cpuinfo").read()
    return " avx512_bf16" in flags or " amx_bf16" in flags


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def case_config(work, name, amp, scenes):
    """The pair configuration without validation or periodic checkpoints."""
    cfg = json.load(open(CONFIG))
    cfg["model"] = os.path.join(ROOT, "config", cfg["model"])
    cfg["amp"] = amp
    cfg["validation"]["sequences"] = 0
    cfg["validation"]["blind_scenes"] = 0
    cfg["checkpoint_every"] = 0
    if scenes:
        cfg["data"]["synth"]["train_scenes"] = scenes
    cfg["comment"] = "bench_pairs.py case %s" % name
    path = os.path.join(work, name + ".json")
    json.dump(cfg, open(path, "w"), indent=1)
    return path


def ours(opts, work, name, config, ranks, threads, cache, extra):
    out = os.path.join(work, name)
    shutil.rmtree(out, ignore_errors=True)
    cmd = [os.path.join(opts.build, "long3r_train"), "--config", config, "--out", out,
           "--seed", "0", "--threads", str(threads), "--time-budget-s", str(opts.budget_s),
           "--quiet"] + extra
    if cache:
        cmd += ["--frame-cache", cache]
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), OPENBLAS_NUM_THREADS="1")
    procs = []
    port = free_port()
    for r in range(ranks):
        e = dict(env)
        if ranks > 1:
            e.update(RANK=str(r), WORLD_SIZE=str(ranks), LOCAL_RANK=str(r),
                     MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
        procs.append(subprocess.Popen(cmd, env=e, stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True))
    logs = [p.communicate()[0] for p in procs]
    if any(p.returncode != 0 for p in procs):
        lines = "\n".join(logs).strip().splitlines()
        return None, lines[-1] if lines else "exit status"
    rows = list(csv.DictReader(open(os.path.join(out, "train_log.csv"))))
    if len(rows) <= opts.warmup + 1:
        return None, "%d steps, no more than the warm-up" % len(rows)
    batch = json.load(open(config))["stages"][0]["batch_size"]
    first, last = rows[opts.warmup], rows[-1]
    seconds = float(last["wall_s"]) - float(first["wall_s"])
    steps = int(last["step"]) - int(first["step"])
    return (steps * batch / seconds, len(rows)), None


def reference(opts, work):
    src = opts.reference
    data = os.path.join(work, "reference_data")
    os.makedirs(data, exist_ok=True)
    synth = os.path.join(opts.build, "long3r_synth")
    trajectories = ["walk", "orbit", "pan"]
    seeds = list(range(1000, 1016)) + [2000000, 2000001]
    for i, s in enumerate(seeds):
        d = os.path.join(data, "data64", "s%d" % s)
        if os.path.exists(os.path.join(d, "groundtruth.txt")):
            continue
        subprocess.run([synth, "--out", d, "--seed", str(s), "--frames", "100", "--width", "64",
                        "--height", "64", "--hfov", str(60 + (7 * s) % 21), "--threads", "1",
                        "--quiet", "--trajectory", trajectories[i % 3]],
                       check=True, capture_output=True)
    if not os.path.exists(os.path.join(data, "val64.npz")):
        subprocess.run(["/usr/bin/python3", os.path.join(src, "pack.py")], cwd=data, check=True,
                       capture_output=True)
    cmd = ["/usr/bin/python3", os.path.join(src, "tiny3r.py"), "--enc", "64", "--enc_depth", "3",
           "--dec", "64", "--dec_depth", "2", "--patch", "8", "--batch", "16", "--lr", "3e-4",
           "--pose_aux", "1", "--seed", "0", "--threads", "1", "--budget", str(opts.budget_s),
           "--steps", "100000000", "--val_every", "100000000"]
    env = dict(os.environ, TINY3R_DATA=data, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    m = re.search(r"final step (\d+)", proc.stdout)
    if proc.returncode != 0 or not m:
        lines = (proc.stderr or proc.stdout).strip().splitlines()
        return None, lines[-1] if lines else "exit %d" % proc.returncode
    steps = int(m.group(1))
    return (steps * 16 / opts.budget_s, steps), None


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--build", required=True,
                   help="folder with long3r_train, long3r_frame_cache (and long3r_synth for "
                        "the reference)")
    p.add_argument("--reference", default="",
                   help="folder of the minimal reference (tiny3r.py, pack.py); none: left out")
    p.add_argument("--budget-s", type=float, default=90.0, help="wall time of each case")
    p.add_argument("--warmup", type=int, default=20, help="first steps left out of our rates")
    p.add_argument("--ranks", type=int, default=os.cpu_count())
    p.add_argument("--scenes", type=int, default=64,
                   help="training scenes of the benchmark's own frame cache")
    p.add_argument("--cache", default=os.path.join(ROOT, "build", "cache"),
                   help="a frame cache of the configuration to use if it fits, or the folder "
                        "of scripts/train_pairs_curve.sh's caches")
    p.add_argument("--cases", default="reference,rendered,cached,ranks")
    p.add_argument("--work", default="", help="folder for the runs (default: a temporary one)")
    opts = p.parse_args()
    cases = opts.cases.split(",")
    if opts.reference:
        for f in ("tiny3r.py", "pack.py"):
            if not os.path.exists(os.path.join(opts.reference, f)):
                p.error("--reference %s holds no %s" % (opts.reference, f))
    elif "reference" in cases:
        cases.remove("reference")
    threads = os.cpu_count()
    print("pair stage throughput, %s: %s, %d cores, native bfloat16: %s; %.0f s a case, "
          "first %d steps of ours left out" % (os.path.relpath(CONFIG, ROOT), cpu_name(), threads,
                                               "yes" if native_bf16() else "no", opts.budget_s,
                                               opts.warmup))
    sys.stdout.flush()
    with tempfile.TemporaryDirectory(prefix="long3r_bench_pairs_") as tmp:
        work = opts.work or tmp
        os.makedirs(work, exist_ok=True)
        tool = os.path.join(opts.build, "long3r_frame_cache")
        check = case_config(work, "check", "off", 0)
        cache, scenes = opts.cache, 0
        if os.path.isdir(cache):
            cache = subprocess.run([tool, "--config", check, "--out", cache, "--print-name"],
                                   check=True, capture_output=True, text=True).stdout.strip()
        fits = os.path.exists(cache) and subprocess.run(
            [tool, "--config", check, "--out", cache, "--check"],
            capture_output=True).returncode == 0
        if not fits:
            scenes = opts.scenes
            cache = os.path.join(work, "frames.cache")
            subprocess.run([tool, "--config", case_config(work, "cache", "off", scenes), "--out",
                            cache, "--quiet"], check=True, capture_output=True)
        amp = json.load(open(CONFIG))["amp"]
        plan = {
            "reference": ("tiny3r.py, 1 thread", lambda: reference(opts, work)),
            "rendered": ("1 process x %d threads, rendered, float32" % threads,
                         lambda: ours(opts, work, "rendered", case_config(work, "rendered", "off",
                                                                          scenes),
                                      1, threads, "", ["--prefetch", "1", "--render-threads",
                                                       "1"])),
            "cached": ("1 process x 1 thread, cached, float32",
                       lambda: ours(opts, work, "cached", case_config(work, "cached", "off",
                                                                      scenes),
                                    1, 1, cache, ["--prefetch", "0"])),
            "ranks": ("%d processes x 1 thread, cached, amp %s" % (opts.ranks, amp),
                      lambda: ours(opts, work, "ranks", case_config(work, "ranks", amp, scenes),
                                   opts.ranks, 1, cache, ["--prefetch", "0"])),
        }
        results = {}
        for name in cases:
            if name not in plan:
                p.error("unknown case %s" % name)
            t0 = time.time()
            res, why = plan[name][1]()
            results[name] = (res, why, time.time() - t0)
    print("%-10s %-44s %10s %8s" % ("case", "how", "pairs/s", "steps"))
    base = results.get("reference", (None,))[0]
    for name in cases:
        res, why, _ = results[name]
        if res is None:
            print("%-10s %-44s refused: %s" % (name, plan[name][0], why))
            continue
        ratio = "   (%.2fx the reference)" % (res[0] / base[0]) if base else ""
        print("%-10s %-44s %10.1f %8d%s" % (name, plan[name][0], res[0], res[1], ratio))
    print("frame cache: %s" % ("the run's (%s)" % cache if not scenes else
                               "written for %d scenes" % scenes))
    return 1 if all(results[n][0] is None for n in cases) else 0


if __name__ == "__main__":
    sys.exit(main())
