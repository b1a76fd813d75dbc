#!/usr/bin/env python3
"""Can an image's overall appearance tell a cut to another scene from a fast
move? The Bhattacharyya distance of colour (hue-saturation, 16 x 8 bins) and
grey-level (32 bins) histograms between consecutive frames of each TUM-layout
folder, and between every frame of one folder and every frame of another
(docs/model_card.md, "A cut to another scene").

    /usr/bin/python3 scripts/cut_appearance.py test/data/tum_fr1_rpy/one_hz test/data/tum_fr1_rpy/video
"""
import glob
import sys

import numpy as np
from PIL import Image


def histograms(path):
    hsv = np.asarray(Image.open(path).convert('HSV')).reshape(-1, 3).astype(int)
    hs, _, _ = np.histogram2d(hsv[:, 0], hsv[:, 1], bins=[16, 8], range=[[0, 256], [0, 256]])
    grey, _ = np.histogram(np.asarray(Image.open(path).convert('L')).ravel(), bins=32,
                           range=(0, 256))
    return hs.ravel() / hs.sum(), grey / grey.sum()


def distance(p, q):
    return float(np.sqrt(max(0.0, 1.0 - np.sum(np.sqrt(p * q)))))


def main(folders):
    if not folders:
        sys.exit(__doc__)
    frames = {}
    for d in folders:
        files = sorted(glob.glob(d + '/rgb/*.png') + glob.glob(d + '/rgb/*.jpg'))
        if len(files) < 2:
            sys.exit('%s: fewer than two images in rgb/' % d)
        frames[d] = [histograms(f) for f in files]
    for d, h in frames.items():
        for k, name in ((0, 'hue-saturation'), (1, 'grey')):
            v = [distance(a[k], b[k]) for a, b in zip(h, h[1:])]
            print('%s, consecutive frames, %s: median %.3f, max %.3f' % (d, name, np.median(v), max(v)))
    names = list(frames)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            for k, name in ((0, 'hue-saturation'), (1, 'grey')):
                v = [distance(x[k], y[k]) for x in frames[a] for y in frames[b]]
                print('%s x %s, %s: median %.3f, min %.3f' % (a, b, name, np.median(v), min(v)))


if __name__ == '__main__':
    main(sys.argv[1:])
