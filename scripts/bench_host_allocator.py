#!/usr/bin/python3
"""The host allocator's effect on one step-sized kernel, side by side.

The RoPE of a paper-size q/k pair ([2, 1, 16, 196, 64], as the attention
hands it over: a view of the permuted qkv) in two forms, float32 and
bfloat16, each in a child process under glibc's malloc settings:
defaults, the trim threshold alone, the mmap threshold alone, and both (what
reuse_freed_memory sets through mallopt, here through GLIBC_TUNABLES):

  table      x * cos + rotate_half(x) * sin with a flipped copy of x (the
             model's Rope2D::apply)
  in-place   each half one product and one multiply-add into a preallocated
             output (tried, not kept: docs/performance.md, "The host allocator")

    /usr/bin/python3 scripts/bench_host_allocator.py [--threads 2] [--reps 200]

Prints the CPU (/proc/cpuinfo model name) and the mean time per
call in microseconds after a warm-up. Needs Debian's python3-torch (the same
torch 1.13 the engine links).
"""
import argparse
import os
import subprocess
import sys
import time

SETTINGS = [
    ("glibc defaults", ""),
    ("trim threshold 1 GiB", "glibc.malloc.trim_threshold=1073741824"),
    ("mmap threshold 32 MiB", "glibc.malloc.mmap_threshold=33554432"),
    ("both (reuse_freed_memory)",
     "glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=1073741824"),
]


def cpu_name():
    with open("/proc/cpuinfo") as f:
        for line in f:
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return "unknown CPU"


def child(threads, reps):
    import torch
    torch.set_num_threads(threads)
    heads, dh, n = 16, 64, 196
    out = []
    for dtype in (torch.float32, torch.bfloat16):
        x = torch.randn(1, n, 3, heads, dh).to(dtype).permute(2, 0, 3, 1, 4)[:2]
        cos, sin = torch.randn(n, dh).to(dtype), torch.randn(n, dh).to(dtype)
        split = (*x.shape[:-1], 2, 2, dh // 4)

        def table():
            swapped = x.reshape(split).flip(-2).reshape(x.shape)
            return x * cos + swapped * sin

        def in_place():
            xs = x.view(split)
            c, s = cos.view(n, 2, 2, dh // 4), sin.view(n, 2, 2, dh // 4)
            y = torch.empty(xs.shape, dtype=dtype)
            for h in range(2):
                o = y.select(-2, h)
                torch.mul(xs.select(-2, h), c.select(-2, h), out=o)
                o.addcmul_(xs.select(-2, 1 - h), s.select(-2, h))
            return y

        with torch.inference_mode():
            for fn in (table, in_place):
                for _ in range(30):
                    fn()
                t = time.perf_counter()
                for _ in range(reps):
                    fn()
                out.append((time.perf_counter() - t) / reps * 1e6)
    print(" ".join("%.1f" % v for v in out))


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--reps", type=int, default=200)
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.child:
        child(a.threads, a.reps)
        return
    print("cpu %s; %d torch threads" % (cpu_name(), a.threads))
    print("%-28s %14s %14s %14s %14s" % ("malloc", "table f32 us", "in-place f32", "table bf16",
                                          "in-place bf16"))
    for name, tunables in SETTINGS:
        env = dict(os.environ)
        env.pop("GLIBC_TUNABLES", None)
        if tunables:
            env["GLIBC_TUNABLES"] = tunables
        res = subprocess.run([sys.executable, __file__, "--child", "--threads", str(a.threads),
                              "--reps", str(a.reps)], env=env, check=True, stdout=subprocess.PIPE,
                             text=True)
        print("%-28s %14s %14s %14s %14s" % ((name,) + tuple(res.stdout.split())))


if __name__ == "__main__":
    main()
