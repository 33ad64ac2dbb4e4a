"""Benchmark: pyramid warping and per-level blending against a single-level remap.

Prints, for one RGB frame warped through a smooth synthetic distortion (a lens-like bulge that
compresses up to ~2.5x at its centre and magnifies around it, on top of a gentle global swirl, with an
invalid region), the median time of
  (a) remap                          single-level bilinear warp (the floor),
  (b) pyramid_warp (collapse=True)   the anti-aliased warp,
  (c) pyramid_warp (collapse=False)  the destination Laplacian pyramid (the blend's input),
  (d) lod_warp                       per-pixel level-of-detail warp,
  (e) blend_pyramids of 3 inputs     per-level detail-preserving average + collapse,
and each one's ratio to (a). Usage: python benchmarks/bench_imaging.py [--height 720 --width 1280
--levels 5 --repeat 5]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import torch

import snell_bench  # noqa: F401  (first: sets the OpenMP wait policy before torch loads)
from snell_bench.imaging import blend_pyramids, laplacian_pyramid, lod_warp, pyramid_warp
from snell_bench.imaging.remap import remap


def synthetic_map(H: int, W: int) -> torch.Tensor:
    """(H, W, 2) backward map: a bulge at the centre (compressing inside, magnifying on its rim),
    a slow swirl elsewhere, NaN in a band at the bottom."""
    y, x = torch.meshgrid(torch.arange(H, dtype=torch.float32), torch.arange(W, dtype=torch.float32), indexing="ij")
    cx, cy, r0 = W / 2, H / 2, 0.25 * H
    dx, dy = x - cx, y - cy
    r2 = (dx**2 + dy**2) / r0**2
    k = 1 + 1.5 * torch.exp(-r2)  # radial scale of the backward map: > 1 compresses
    a = 0.05 * torch.sin(2 * torch.pi * y / H)
    sx = cx + k * (dx * torch.cos(a) - dy * torch.sin(a))
    sy = cy + k * (dx * torch.sin(a) + dy * torch.cos(a))
    c = torch.stack([sx, sy], -1)
    c[int(0.9 * H) :, : W // 3] = float("nan")
    return c


def median_time(fn, repeat: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--height", type=int, default=720)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--levels", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    H, W, L = args.height, args.width, args.levels

    g = torch.Generator().manual_seed(0)
    src = torch.rand(1, 3, H, W, generator=g)
    c = synthetic_map(H, W)
    others = [torch.rand(1, 3, H, W, generator=g) for _ in range(2)]
    own = laplacian_pyramid(src, L)
    warped = [pyramid_warp(o, c, levels=L, collapse=False) for o in others]
    levels = [own] + [w[0] for w in warped]
    masks = [None] + [w[1] for w in warped]

    cases = {
        "remap": lambda: remap(src, c),
        f"pyramid_warp ({L} levels, collapse=True)": lambda: pyramid_warp(src, c, levels=L),
        f"pyramid_warp ({L} levels, collapse=False)": lambda: pyramid_warp(src, c, levels=L, collapse=False),
        f"lod_warp ({L} levels)": lambda: lod_warp(src, c, levels=L),
        f"laplacian_pyramid ({L} levels)": lambda: laplacian_pyramid(src, L),
        "blend_pyramids (3 inputs, DPA per level + collapse)": lambda: blend_pyramids(levels, masks, lam=0.5),
    }
    times = {name: median_time(fn, args.repeat) for name, fn in cases.items()}

    print(
        f"snell_bench imaging benchmark  ({platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"{torch.get_num_threads()} torch threads, torch {torch.__version__})"
    )
    valid = torch.isfinite(c).all(-1).float().mean()
    print(f"RGB {H}x{W}, synthetic bulge + swirl map ({valid:.0%} valid), median of {args.repeat}")
    base = times["remap"]
    for name, t in times.items():
        print(f"  {name:52s}: {t * 1e3:8.1f} ms  ({t / base:5.1f}x remap)")


if __name__ == "__main__":
    main()
