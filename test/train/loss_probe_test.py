#!/usr/bin/env python3
"""scripts/loss_probe.sh end to end on the shipped model (two strides, one
short sequence): every row is printed; the still oracle (true depth, no
motion) is all registration (loss_reg 0, reg_left 1) and costs more at the
wider baseline; the shipped model has shape error left after registration."""
import argparse
import os
import subprocess
import sys
import tempfile


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--script', required=True)
    ap.add_argument('--bin', required=True)
    ap.add_argument('--model', required=True)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        r = subprocess.run(['bash', a.script, tmp, '--bin', a.bin, '--model', a.model,
                            '--strides', '1 8', '--frames', '3', '--sequences', '1',
                            '--threads', '2'], capture_output=True, text=True)
        print(r.stdout)
        print(r.stderr, file=sys.stderr)
        if r.returncode != 0:
            sys.exit('loss_probe.sh failed with %d' % r.returncode)
        for stride in (1, 8):
            for name in ('model', 'model_no_memory', 'true_depth_no_motion', 'frame0_geometry',
                         'constant_depth'):
                if not os.path.isfile(os.path.join(tmp, '%s_s%d.json' % (name, stride))):
                    sys.exit('no JSON for %s at stride %d' % (name, stride))
    rows = {}
    for line in r.stdout.splitlines():
        cells = line.split()
        if len(cells) == 9 and cells[0].isdigit():
            rows[(int(cells[0]), cells[2])] = cells
    if len(rows) != 10:
        sys.exit('expected 10 rows (2 strides x 5 predictions), got %d' % len(rows))
    failures = []
    for stride in (1, 8):
        still = rows[(stride, 'true_depth_no_motion')]
        if not (float(still[4]) < 1e-3 and still[6] == '1.00'):
            failures.append('still oracle at stride %d is not all registration: %s' %
                            (stride, ' '.join(still)))
        model = rows[(stride, 'model')]
        if not float(model[4]) > 0.01:
            failures.append('model without shape error at stride %d: %s' % (stride, ' '.join(model)))
    if not float(rows[(8, 'true_depth_no_motion')][3]) > float(rows[(1, 'true_depth_no_motion')][3]):
        failures.append('the still oracle does not cost more at the wider baseline')
    for f in failures:
        print('FAIL: ' + f)
    sys.exit(1 if failures else 0)


if __name__ == '__main__':
    main()
