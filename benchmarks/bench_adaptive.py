"""Benchmark: what modelling only what a scene requires saves, measured in one run.

At the paper's size by default (720 x 1280, panorama 1024 x 2048), a procedural scene with a glass
sphere, the analytic backend:

1. warps: primary rays over the full frame vs. the object's projected box (region of interest);
   exact geometry vs. far background at infinity (1 px) on an outdoor scene;
2. sampler, per synchronized step: warp + blend over whole frames vs. in windows around each warp's
   valid pixels (and the maximum difference of the images);
3. sampler, per step: a weak lens (IOR 1.05) with the panorama branch and reflection vs. the adaptive
   decisions (reflection below R = 1 % dropped, panorama skipped when 90 % of rays are observed).

Prints seconds and ratios (best of ``--repeat``). Usage:
python benchmarks/bench_adaptive.py [--height 720 --width 1280 --pano 1024 --steps 3 --repeat 2]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from dataclasses import replace

import snell_bench  # noqa: F401  (first: sets the OpenMP wait policy before torch loads)

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import torch

from snell_bench.models.analytic import AnalyticGenerator
from snell_bench.optics import compute_warps
from snell_bench.sampler import SamplerSettings, sample
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.placement import place_object
from snell_bench.scene.procedural import ProceduralScene


def best(fn, repeat):
    out, t = None, float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        t = min(t, time.perf_counter() - t0)
    return out, t


def scene_setup(kind, seed, args, ior=1.5):
    scene = ProceduralScene(kind, seed=seed)
    r = scene.render(args.width, args.height)
    obj = place_object(GlassObject.sphere(ior=ior), r.depth, r.camera, up_hint=scene.up)
    return scene, r, obj


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--height", type=int, default=720)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--pano", type=int, default=1024)
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    print(
        f"snell_bench adaptive benchmark ({platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}); "
        f"view {args.height}x{args.width}, panorama {args.pano}x{2 * args.pano}, best of {args.repeat}"
    )

    # 1. warps
    scene, r, obj = scene_setup("room", 0, args)
    full, t_full = best(lambda: compute_warps(r.depth, r.camera, obj, args.pano, roi=False), args.repeat)
    roi, t_roi = best(lambda: compute_warps(r.depth, r.camera, obj, args.pano, roi=True), args.repeat)
    print("\nwarps (room, sphere)")
    print(
        f"  full frame {t_full:6.2f} s  primary {full.stats['timings_s']['primary']:.2f} s  "
        f"({full.stats['traced_primary_rays']} rays)"
    )
    print(
        f"  ROI        {t_roi:6.2f} s  primary {roi.stats['timings_s']['primary']:.2f} s  "
        f"({roi.stats['traced_primary_rays']} rays)   speed-up x{t_full / t_roi:.2f}"
    )
    _, ro, oo = scene_setup("outdoor", 700, args)  # the desert
    ex, t_ex = best(lambda: compute_warps(ro.depth, ro.camera, oo, args.pano), args.repeat)
    inf, t_inf = best(lambda: compute_warps(ro.depth, ro.camera, oo, args.pano, infinity_tolerance_px=1.0), args.repeat)
    fb = inf.stats["far_background"]
    both = torch.from_numpy(ex.refraction).isfinite().all(-1) & torch.from_numpy(inf.refraction).isfinite().all(-1)
    dmax = float((torch.from_numpy(ex.refraction) - torch.from_numpy(inf.refraction)).abs()[both].max())
    print(
        f"warps (desert, sphere): exact {t_ex:.2f} s, far background at infinity {t_inf:.2f} s "
        f"(x{t_ex / t_inf:.2f}); {100 * fb['far_fraction']:.1f} % of pixels far (depth >= "
        f"{fb['nearest_far_depth'] or float('nan'):.0f}), largest change of π^R {dmax:.3f} px"
    )

    # 2. sampler windows
    p = roi.pano
    pano = scene.render_panorama(center=p.center, height=p.height, up=-p.rotation[:, 1], forward=p.rotation[:, 2])
    gen = AnalyticGenerator.from_scene(r.image, roi.object_mask, pano)
    i_minus = torch.from_numpy(r.image).permute(2, 0, 1)[None].float()
    base = SamplerSettings(steps=args.steps, time_travel=False, progress=False)

    def per_step(res):
        return res.timings["warp_blend"] / args.steps, sum(
            v for k, v in res.timings.items() if k != "setup"
        ) / args.steps

    a, _ = best(lambda: sample(gen, roi, i_minus, "p", "p360", replace(base, roi=False), seed=0), args.repeat)
    b, _ = best(lambda: sample(gen, roi, i_minus, "p", "p360", replace(base, roi=True), seed=0), args.repeat)
    (wa, sa), (wb, sb) = per_step(a), per_step(b)
    diff = float((a.image - b.image).abs().max())
    print("\nsampler per synchronized step (room, sphere IOR 1.5)")
    print(f"  whole frames  warp+blend {wa:6.3f} s  step {sa:6.3f} s")
    print(
        f"  windows (ROI) warp+blend {wb:6.3f} s  step {sb:6.3f} s   warp+blend x{wa / wb:.2f}, step x{sa / sb:.2f}; "
        f"max image difference {diff:.1e}"
    )

    # 3. adaptive decisions on a weak lens
    _, rw, ow = scene_setup("room", 0, args, ior=1.05)
    ww = compute_warps(rw.depth, rw.camera, ow, args.pano)
    genw = AnalyticGenerator.from_scene(rw.image, ww.object_mask, pano)
    full_w, _ = best(lambda: sample(genw, ww, i_minus, "p", "p360", base, seed=0), args.repeat)
    adapt = replace(base, reflection_min_fresnel=0.01, skip_panorama_above=0.9)
    ad_w, _ = best(lambda: sample(genw, ww, i_minus, "p", "p360", adapt, seed=0), args.repeat)
    (_, sf), (_, sa2) = per_step(full_w), per_step(ad_w)
    m = torch.from_numpy(ww.object_mask)
    mse = float(((full_w.image - ad_w.image) ** 2).mean(1)[0][m].mean())
    d = ad_w.decisions
    print("\nsampler per step, weak lens (IOR 1.05)")
    print(f"  all modelled  step {sf:6.3f} s  model calls {full_w.model_calls}")
    print(
        f"  adaptive      step {sa2:6.3f} s  model calls {ad_w.model_calls}   x{sf / sa2:.2f}; reflection kept on "
        f"{100 * d['reflection']['share_kept']:.1f} % of object pixels, panorama used: {d['panorama']['used']} "
        f"({100 * d['panorama'].get('observed_share', float('nan')):.1f} % observed); object PSNR between the two "
        f"{10 * torch.log10(torch.tensor(1 / max(mse, 1e-12))).item():.1f} dB"
    )


if __name__ == "__main__":
    main()
