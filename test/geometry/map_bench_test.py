#!/usr/bin/python3
"""long3r_map_bench: a row per checkpoint frame, both maps of the same points
at about the same size, every time positive, and the mean line's ratio the
one its means give."""
import re
import subprocess
import sys


def main():
    bench = sys.argv[1]
    out = subprocess.run([bench, "--frames", "12", "--voxel-size-m", "0.05"],
                         check=True, capture_output=True, text=True).stdout
    assert out.startswith("cpu: "), out
    rows = re.findall(r"^\s*(\d+)\s+(\d+)\s+([0-9.]+)\s+([0-9.]+)\s+([0-9.]+)\s+"
                      r"\(PCL map (\d+) points\)$", out, re.M)
    assert [int(r[0]) for r in rows] == [10, 12], out
    previous = 0
    for frame, ours, ours_ms, pcl_ms, to_pcl_ms, pcl_points in rows:
        ours, pcl_points = int(ours), int(pcl_points)
        assert ours > 0 and ours >= previous, out  # the map only grows
        previous = ours
        # Both bin the same points into 5 cm voxels (PCL's grid starts at the
        # cloud's corner, ours at the origin): about the same count.
        assert abs(ours - pcl_points) <= 0.1 * ours, out
        assert min(float(ours_ms), float(pcl_ms), float(to_pcl_ms)) > 0.0, out
    m = re.search(r"mean ms per frame: voxel map ([0-9.]+), PCL re-filter ([0-9.]+) "
                  r"\(ratio ([0-9.]+)x\)", out)
    assert m, out
    ours_mean, pcl_mean, ratio = (float(g) for g in m.groups())
    assert abs(pcl_mean / ours_mean - ratio) <= 0.06 + 0.01 * ratio, m.group(0)
    bad = subprocess.run([bench, "--frames", "0"], capture_output=True, text=True)
    assert bad.returncode != 0 and "--frames" in bad.stderr, bad.stderr
    print("map_bench: ok")


if __name__ == "__main__":
    main()
