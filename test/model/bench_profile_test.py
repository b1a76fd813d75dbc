#!/usr/bin/python3
"""long3r_bench --profile-frames: the profile is printed for the steps asked,
its class rows add up to the total it states, the matrix products carry
torch's FLOP count, and the operator rows are the largest first."""
import re
import subprocess
import sys


def main():
    bench = sys.argv[1]
    out = subprocess.run([bench, "--config", "long3r_tiny", "--frames", "4", "--size", "64",
                          "--threads", "1", "--profile-frames", "2"],
                         check=True, capture_output=True, text=True).stdout
    m = re.search(r"profile of (\d+) step\(s\): ([0-9.]+) ms per step in operators", out)
    assert m, "no profile header in:\n" + out
    assert int(m.group(1)) == 2, m.group(0)
    total = float(m.group(2))
    assert total > 0, m.group(0)
    lines = out.splitlines()
    start = next(i for i, l in enumerate(lines) if l.startswith("operator class"))
    classes = {}
    for l in lines[start + 1:]:
        if l.startswith("operator (top 20"):
            break
        parts = re.split(r"\s{2,}", l.strip())
        classes[parts[0]] = [float(p.rstrip("%")) for p in parts[1:]]
    assert "matrix products (linear, matmul)" in classes, classes
    summed = sum(v[0] for v in classes.values())
    # Rows are printed to 0.1 ms; the header's total is their sum.
    assert abs(summed - total) <= 0.05 * len(classes) + 1e-6, (summed, total)
    assert abs(sum(v[1] for v in classes.values()) - 100.0) < 0.1 * len(classes), classes
    # GFLOP/s (the GFLOP column rounds to 0.0 at this size).
    rate = classes["matrix products (linear, matmul)"][3]
    assert rate > 0, classes
    ops = []
    for l in lines[lines.index(next(l for l in lines if l.startswith("operator (top 20"))) + 1:]:
        if not l.startswith("aten::"):
            break
        ops.append(float(l.split()[1]))
    assert ops and ops == sorted(ops, reverse=True), ops
    print("profile: %.1f ms per step, %d classes, products at %.0f GFLOP/s" %
          (total, len(classes), rate))


if __name__ == "__main__":
    main()
