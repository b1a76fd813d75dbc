#!/usr/bin/python3
"""scripts/bench_train.py on the tiny model: a row per case, in order, each
with its figures (or, for bfloat16 on a CPU without it, the trainer's reason),
frames per second that follow from the step time, and the waits inside the
steps. A printer's arithmetic, checked; no time is asserted."""
import re
import subprocess
import sys


def main():
    root, train = sys.argv[1], sys.argv[2]
    out = subprocess.run(["/usr/bin/python3", root + "/scripts/bench_train.py", "--train", train,
                          "--model-config", "long3r_tiny", "--steps", "4", "--warmup", "1",
                          "--threads", "1"],
                         check=True, capture_output=True, text=True).stdout
    lines = out.splitlines()
    assert lines[0].startswith("long3r_train throughput: config/train_ship_stage1.json with "
                               "long3r_tiny, 1 threads (1 rendering), 4 steps"), out
    native = lines[0].endswith("native bfloat16: yes")
    m = re.search(r"frames per step: (\d+)", out)
    assert m and int(m.group(1)) == 10, out  # the stage's batch 2 x 5 frames
    frames = int(m.group(1))
    head = next(i for i, l in enumerate(lines) if l.startswith("precision"))
    rows = lines[head + 1:head + 5]
    expected = [("float32", "0"), ("float32", "1"), ("bfloat16", "0"), ("bfloat16", "1")]
    for (name, prefetch), row in zip(expected, rows):
        parts = row.split()
        assert parts[:2] == [name, prefetch], (row, out)
        if name == "bfloat16" and not native:
            assert "refused:" in row and "native bfloat16" in row, row
            continue
        step_s, wait_s, fps = float(parts[2]), float(parts[3]), float(parts[4])
        assert step_s > 0 and 0 <= wait_s <= step_s, row
        # Printed to 3 and 2 decimals: frames/s is frames / step within those
        # roundings (half a unit each; the step's relative error carries over).
        assert abs(fps - frames / step_s) <= 0.005 + frames / step_s * 5e-4 / step_s * 1.01 \
            + 1e-9, row
    assert rows[0].endswith("(1.00x)"), rows[0]
    print(out)


if __name__ == "__main__":
    main()
