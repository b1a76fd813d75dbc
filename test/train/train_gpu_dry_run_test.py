#!/usr/bin/python3
"""scripts/train_gpu.sh --cpu-dry-run end to end: the libtorch-only build of
long3r_train (OpenCV, PCL and the system Eigen kept out; nlohmann-json and
Eigen from a --pack-deps folder, as a GPU machine gets them), two steps of
config/train_gpu.json with long3r_tiny and a data thread, and the folder it
writes. Without a CUDA GPU the real run must refuse, saying why."""
import argparse
import json
import os
import shutil
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_test import check, run  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--root", required=True)
    ap.add_argument("--workdir", required=True)
    a = ap.parse_args()
    script = os.path.join(a.root, "scripts", "train_gpu.sh")
    deps = os.path.join(a.workdir, "deps")
    build = os.path.join(a.workdir, "build")  # kept between runs: the build is incremental
    out = os.path.join(a.workdir, "out")
    shutil.rmtree(out, ignore_errors=True)
    shutil.rmtree(deps, ignore_errors=True)
    env = dict(os.environ, PYTHON="/usr/bin/python3", PATH="/usr/bin:/bin:" + os.environ["PATH"])
    env.pop("LONG3R_EIGEN_DIR", None)
    env.pop("LONG3R_NLOHMANN_JSON_DIR", None)

    rc, log = run(["bash", script, "--pack-deps", "--deps-dir", deps], env=env, merge_output=True)
    check(rc == 0, "--pack-deps failed:\n" + log)
    check(os.path.isfile(os.path.join(deps, "eigen3", "Eigen", "Core")), "no Eigen packed")
    check(os.path.isfile(os.path.join(deps, "nlohmann", "json.hpp")), "no nlohmann-json packed")

    rc, log = run(["bash", script, "--cpu-dry-run", "--deps-dir", deps, "--build-dir", build,
                   "--out", out, "--jobs", "2"], env=env, merge_output=True)
    print(log)
    check(rc == 0, "the dry run failed (rc %d)" % rc)
    cache = open(os.path.join(build, "CMakeCache.txt")).read()
    check("LONG3R_EIGEN_DIR:PATH=" + os.path.join(deps, "eigen3") in cache,
          "the build did not take Eigen from the packed folder")
    check("OpenCV_DIR:PATH=/" not in cache and "PCL_DIR:PATH=/" not in cache,
          "the build found OpenCV or PCL")
    for f in ("model.safetensors", "train_log.csv", "validation.json", "train_config.json",
              "train.log", "report.txt", os.path.join("checkpoint", "latest")):
        check(os.path.isfile(os.path.join(out, f)), "missing " + f)
    check(not os.path.exists(os.path.join(out, "loss_curve.png")),
          "a picture was drawn without OpenCV")
    report = open(os.path.join(out, "report.txt")).read()
    check("MODE: --cpu-dry-run" in report and "--prefetch 2" in report,
          "the report does not say what ran:\n" + report)
    needs = [l for l in report.splitlines() if l.startswith("long3r_train needs: ")]
    check(len(needs) == 1 and "libtorch" in needs[0]
          and not any(x in needs[0] for x in ("opencv", "pcl", "ros")),
          "what the binary links: %s" % needs)
    v = json.load(open(os.path.join(out, "validation.json")))
    check(v["step"] == 2 and v["stop_reason"] == "max_steps", "validation.json: %s" % v)
    check(v["model"] == "long3r_tiny" and v["device"] == "cpu", "validation.json: %s" % v)
    check(v["steps_planned"] == 1900, "not the GPU recipe's schedule: %s" % v)
    check(v["sequences"] == 4 and v["frames"] == 64, "validation.json: %s" % v)
    check(0 < v["registered"] < v["regression"], "loss split: %s" % v)
    check(v["pointmap_err_m"] > 0, "pointmap error: %s" % v)
    check(v["acc_mean_m"] is None and v["ate_rmse_m"] is None,
          "OpenCV-side figures from a build without OpenCV: %s" % v)

    # The real run on this machine (no CUDA): refused with the reason, exit 3.
    rc, log = run(["bash", script, "--deps-dir", deps, "--build-dir", build,
                   "--out", os.path.join(a.workdir, "no_gpu")], env=env, merge_output=True)
    check(rc == 3 and "NO CUDA GPU" in log, "without a GPU: rc %d\n%s" % (rc, log))
    print("PASS")


if __name__ == "__main__":
    main()
