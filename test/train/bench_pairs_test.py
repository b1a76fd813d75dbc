#!/usr/bin/python3
"""scripts/bench_pairs.py without the reference (which a user's clone does not
have), on a frame cache of its own: a row per case in order, each with a rate
that its steps and the budget allow, and the header naming the CPU. A
printer's table, checked; no rate is asserted."""
import os
import re
import subprocess
import sys


def main():
    root, build, work = sys.argv[1], sys.argv[2], sys.argv[3]
    budget = 6.0
    out = subprocess.run(["/usr/bin/python3", os.path.join(root, "scripts", "bench_pairs.py"),
                          "--build", build, "--cases", "cached,ranks", "--budget-s", str(budget),
                          "--warmup", "2", "--scenes", "3", "--ranks", "2",
                          "--cache", os.path.join(work, "absent.frames"), "--work", work],
                         check=True, capture_output=True, text=True).stdout
    lines = out.splitlines()
    assert lines[0].startswith("pair stage throughput, config/train_pairs_fast.json: "), out
    assert "cores, native bfloat16: " in lines[0], out
    head = next(i for i, l in enumerate(lines) if l.startswith("case"))
    rows = lines[head + 1:head + 3]
    for name, row in zip(["cached", "ranks"], rows):
        assert row.startswith(name), (row, out)
        m = re.search(r"\s([\d.]+)\s+(\d+)$", row)
        assert m, (row, out)
        rate, steps = float(m.group(1)), int(m.group(2))
        assert steps > 3 and rate > 0, (row, out)
    assert "2 processes x 1 thread, cached" in rows[1], rows[1]
    assert lines[-1] == "frame cache: written for 3 scenes", out
    print(out)


if __name__ == "__main__":
    main()
