"""Map comparisons shared by the rostest checks."""
import math

import numpy as np


def cloud_points(msg):
    """x, y, z of an unorganised PointCloud2 (float32 fields) as an (N, 3) array."""
    offsets = {f.name: f.offset for f in msg.fields}
    n = msg.width * msg.height
    raw = np.frombuffer(msg.data, dtype=np.uint8).reshape(n, msg.point_step)
    return np.stack([raw[:, offsets[c]:offsets[c] + 4].copy().view(np.float32)[:, 0]
                     for c in 'xyz'], axis=1).astype(np.float64)


def lost_points(old, new, voxel_m):
    """How many points of `old` have no point of `new` within a voxel diagonal
    (a voxel map's point is the mean of its voxel, which moves inside it as
    points are fused, or merges with a neighbour's)."""
    reach = voxel_m * math.sqrt(3.0)
    cells = {}
    for p in new:
        cells.setdefault(tuple(np.floor(p / voxel_m).astype(int)), []).append(p)
    lost = 0
    for p in old:
        c = np.floor(p / voxel_m).astype(int)
        near = [q for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)
                for q in cells.get((c[0] + dx, c[1] + dy, c[2] + dz), [])]
        if not near or np.min(np.linalg.norm(np.array(near) - p, axis=1)) > reach:
            lost += 1
    return lost
