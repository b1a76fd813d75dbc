#!/usr/bin/python3
"""The CPU kernel checks behind the precision choices of docs/performance.md,
on the libtorch that Debian's python3-torch shares with the engine (1.13):

  /usr/bin/python3 scripts/bench_cpu_kernels.py [--threads T]

Prints, for the shapes of the models (ViT-L tokens, DPT head maps), the time
of each kernel and the max relative error of the bfloat16 one against float32
on the same bfloat16-rounded inputs:
  - layer_norm in bfloat16 against casting to float32 and back;
  - conv2d (3x3, 256 channels) in bfloat16 against float32;
  - bilinear 2x upsampling (align_corners) in bfloat16 against float32;
  - the attention softmax in bfloat16 against the float32 softmax rounded
    once to bfloat16 (what the models run), and how many values differ;
  - the vector norm over a permuted (strided) last dimension against the same
    view made contiguous first (the heads' postprocess);
  - linear layers of the models' sizes in float32, bfloat16 and int8
    (dynamically quantised weights and activations through torch's oneDNN
    quantised engine, the only one Debian's torch has besides QNNPACK), with
    each one's error against float32.
A figure printer, not a test. bfloat16 figures mean little on a CPU without
native bfloat16 (AVX512-BF16 / AMX): it says which it is.
"""
import argparse
import time

import torch
import torch.nn.functional as F


def timed_ms(fn, reps):
    fn()
    fn()
    t0 = time.perf_counter()
    for _ in range(reps):
        fn()
    return (time.perf_counter() - t0) / reps * 1e3


def rel(a, ref):
    return ((a.float() - ref).abs().max() / ref.abs().max()).item()


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--threads", type=int, default=2)
    opts = p.parse_args()
    torch.set_num_threads(opts.threads)
    torch.manual_seed(0)
    flags = open("/proc/cpuinfo").read()
    native = " avx512_bf16" in flags or " amx_bf16" in flags
    print("torch %s, %d threads, native bfloat16: %s" %
          (torch.__version__, opts.threads, "yes" if native else "no (emulated)"))

    x = torch.randn(1, 196, 1024).bfloat16()
    w, b = torch.randn(1024).bfloat16(), torch.randn(1024).bfloat16()
    ref = F.layer_norm(x.float(), (1024,), w.float(), b.float())
    print("layer_norm 196x1024: bfloat16 %.3f ms (error %.1e), via float32 %.3f ms (error %.1e)" % (
        timed_ms(lambda: F.layer_norm(x, (1024,), w, b), 50),
        rel(F.layer_norm(x, (1024,), w, b), ref),
        timed_ms(lambda: F.layer_norm(x.float(), (1024,), w.float(), b.float()).bfloat16(), 50),
        rel(F.layer_norm(x.float(), (1024,), w.float(), b.float()).bfloat16(), ref)))

    for hw in (56, 112):
        x = torch.randn(1, 256, hw, hw).bfloat16()
        w = (torch.randn(256, 256, 3, 3) * 0.02).bfloat16()
        xf, wf = x.float(), w.float()
        gflop = 2 * 256 * 256 * 9 * hw * hw / 1e9
        t32 = timed_ms(lambda: F.conv2d(xf, wf, padding=1), 5)
        t16 = timed_ms(lambda: F.conv2d(x, w, padding=1), 5)
        print("conv2d 3x3 256ch %dx%d: float32 %.1f ms (%.0f GFLOP/s), bfloat16 %.1f ms "
              "(%.0f GFLOP/s, error %.1e)" % (hw, hw, t32, gflop / t32 * 1e3, t16,
                                             gflop / t16 * 1e3,
                                             rel(F.conv2d(x, w, padding=1),
                                                 F.conv2d(xf, wf, padding=1))))

    for hw in (14, 56, 112):
        x = torch.randn(1, 128, hw, hw).bfloat16()
        up = lambda t: F.interpolate(t, scale_factor=2, mode="bilinear", align_corners=True)
        print("upsample 2x bilinear %dx%d: bfloat16 error %.1e" % (hw, hw, rel(up(x), up(x.float()))))

    for shape in ((1, 3, 196, 196), (1, 3, 196, 1620)):
        a = (torch.randn(shape) * 4).bfloat16()
        via32 = lambda: torch.softmax(a, -1, dtype=torch.float32).bfloat16()
        direct = lambda: torch.softmax(a, -1)
        print("softmax %s: via float32 %.3f ms, bfloat16 directly %.3f ms (%d of %d values differ, "
              "max %.1e)" % ("x".join(map(str, shape)), timed_ms(via32, 50), timed_ms(direct, 50),
                             (via32() != direct()).sum().item(), a.numel(),
                             (via32().float() - direct().float()).abs().max().item()))

    raw = torch.randn(1, 4, 224, 224)
    xyz = raw.permute(0, 2, 3, 1)[..., :3]
    norm = lambda t: torch.linalg.vector_norm(t, 2, dim=-1, keepdim=True)
    same = torch.equal(norm(xyz), norm(xyz.contiguous()))
    print("vector norm of a permuted 224x224x3 view: strided %.2f ms, contiguous first %.2f ms "
          "(same bits: %s)" % (timed_ms(lambda: norm(xyz), 20),
                               timed_ms(lambda: norm(xyz.contiguous()), 20), same))

    if "onednn" in torch.backends.quantized.supported_engines:
        torch.backends.quantized.engine = "onednn"
        # (tokens, in, out): the shipped model's MLP, the paper-size encoder's
        # attention projection and MLP.
        for m, k, n in ((196, 128, 512), (196, 1024, 1024), (196, 1024, 4096)):
            lin = torch.nn.Linear(k, n)
            x = torch.randn(1, m, k)
            q = torch.ao.quantization.quantize_dynamic(torch.nn.Sequential(lin),
                                                       {torch.nn.Linear}, dtype=torch.qint8)
            lin16 = torch.nn.Linear(k, n).bfloat16()
            lin16.load_state_dict({key: v.bfloat16() for key, v in lin.state_dict().items()})
            x16 = x.bfloat16()
            with torch.inference_mode():
                ref = lin(x)
                print("linear %dx%d -> %d: float32 %.3f ms, bfloat16 %.3f ms (error %.1e), "
                      "int8 dynamic %.3f ms (error %.1e)" % (
                          m, k, n, timed_ms(lambda: lin(x), 50), timed_ms(lambda: lin16(x16), 50),
                          rel(lin16(x16), ref), timed_ms(lambda: q(x), 50), rel(q(x), ref)))
    else:
        print("linear int8: no oneDNN quantised engine in this torch")


if __name__ == "__main__":
    main()
