"""Benchmark: one synchronized sampler step, split into model call, decode/encode and warp + blend.

For the analytic backend and tiny FLUX at 720 x 1280 with a 1024 x 2048 panorama (a procedural
room, a glass sphere), prints the time per step of each part (median over the steps of a short
run without time travel) and the synchronisation overhead: decode/encode plus warp + blend, which
a plain sampler does not spend, as a fraction of the step; and the bytes that cross between the
host and the generator's device (``--device cuda`` for tiny FLUX on a GPU): once per run (the
warps of the scene and the final images) and per step (the goal: 0). On a CPU-only machine there
is one device and nothing can cross.
Usage: python benchmarks/bench_sampler.py [--height 720 --width 1280 --pano 1024 --steps 3]
"""

from __future__ import annotations

import argparse
import os
import platform

import snell_bench  # noqa: F401  (first: sets the OpenMP wait policy before torch loads)

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import torch

from snell_bench.models.analytic import AnalyticGenerator
from snell_bench.optics import compute_warps
from snell_bench.sampler import SamplerSettings, sample
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.placement import place_object
from snell_bench.scene.procedural import ProceduralScene
from snell_bench.utils.transfers import TransferCounter


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--height", type=int, default=720)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--pano", type=int, default=1024)
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--skip-tiny-flux", action="store_true")
    ap.add_argument("--device", default="cpu", help="where tiny FLUX runs (cpu, cuda)")
    args = ap.parse_args()

    scene = ProceduralScene("room", seed=0)
    r = scene.render(args.width, args.height)
    obj = place_object(GlassObject.sphere(), r.depth, r.camera, up_hint=scene.up)
    ws = compute_warps(r.depth, r.camera, obj, pano_height=args.pano)
    p = ws.pano
    pano = scene.render_panorama(center=p.center, height=p.height, up=-p.rotation[:, 1], forward=p.rotation[:, 2])
    i_minus = torch.from_numpy(r.image).permute(2, 0, 1)[None].float()
    settings = SamplerSettings(steps=args.steps, time_travel=False, progress=False)

    gens = [("analytic", lambda: AnalyticGenerator.from_scene(r.image, ws.object_mask, pano))]
    if not args.skip_tiny_flux:
        from snell_bench.models.tiny_flux import TinyFluxGenerator

        gens.append(("tiny_flux", lambda: TinyFluxGenerator(seed=0, device=args.device)))
    print(f"snell_bench sampler benchmark ({platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__})")
    print(
        f"view {args.height}x{args.width}, panorama {args.pano}x{2 * args.pano}, {args.steps} steps, no time travel; "
        "seconds per synchronized step (both branches)"
    )
    print(
        f"  {'backend':10s} {'device':>7s} {'model':>8s} {'codec':>8s} {'warp+blend':>11s} {'step':>7s} {'total':>8s} "
        f"{'sync overhead':>14s} {'MB moved/run':>13s} {'bytes/step':>11s}"
    )
    one_step = SamplerSettings(steps=1, time_travel=False, progress=False)
    for name, build in gens:
        gen = build()
        with TransferCounter() as moved:
            res = sample(gen, ws, i_minus, "a glass sphere", "a panorama", settings, seed=0)
        with TransferCounter() as moved_1:
            sample(gen, ws, i_minus, "a glass sphere", "a panorama", one_step, seed=0)
        per_step = (moved.bytes - moved_1.bytes) / max(args.steps - 1, 1)
        t = {k: v / args.steps for k, v in res.timings.items() if k != "setup"}
        total = sum(t.values())
        overhead = (t["codec"] + t["warp_blend"]) / total
        device = str(getattr(gen, "device", "cpu"))
        print(
            f"  {name:10s} {device:>7s} {t['model']:8.3f} {t['codec']:8.3f} {t['warp_blend']:11.3f} {t['step']:7.3f} "
            f"{total:8.3f} {overhead:13.0%} {moved_1.bytes / 1e6:13.1f} {per_step:11.0f}"
            f"   (once per run: warps of I⁻ {res.timings['setup']:.2f} s)"
        )


if __name__ == "__main__":
    main()
