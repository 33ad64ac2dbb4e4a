"""Benchmark: a full WarpSet against one raw Open3D cast of the same frame.

Prints, from one run on this machine, the median time of
  (a) a raw Open3D cast: RaycastingScene built from the frame's depth mesh and the object, plus one
      cast of every camera ray (the floor set by the ray engine), and
  (b) compute_warps: depth mesh, both acceleration structures, object mask, multi-bounce refraction,
      reflection, the panorama warps and all visibility checks,
and their ratio, and the share of the whole-frame π⁻¹ (stage ``frame``: one re-cast per pixel from
the panorama centre). Usage: python benchmarks/bench_warps.py [--height 720 --width 1280 --pano 1024 --repeat 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np
import open3d as o3d
import torch

import snell_bench  # noqa: F401  (first: sets the OpenMP wait policy before torch loads)
from snell_bench.optics import compute_warps
from snell_bench.scene.depth_mesh import depth_to_mesh
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.placement import place_object
from snell_bench.scene.procedural import ProceduralScene


def raw_cast(vertices, faces, obj, rays) -> float:
    t0 = time.perf_counter()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor.from_numpy(vertices), o3d.core.Tensor.from_numpy(faces))
    scene.add_triangles(
        o3d.core.Tensor.from_numpy(np.ascontiguousarray(obj.vertices, np.float32)),
        o3d.core.Tensor.from_numpy(np.ascontiguousarray(obj.faces, np.uint32)),
    )
    r = scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
    r["t_hit"].numpy()
    return time.perf_counter() - t0


_OMP_PROBE = """
import time, torch
d = torch.nn.functional.normalize(torch.randn(54_000, 3, dtype=torch.float64), dim=-1)
for _ in range(5): d * d
t0 = time.perf_counter()
for _ in range(200): (d * d).sum(-1)
print((time.perf_counter() - t0) / 200)
"""


def omp_wait_policy_probe() -> dict[tuple[str, bool], float]:
    """Seconds per small multi-threaded torch op under each OpenMP wait policy, in fresh processes,
    on an idle machine and next to one busy process (a parallel sweep, a renderer)."""
    import subprocess
    import sys

    out = {}
    for contended in (False, True):
        busy = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if contended else None
        try:
            for policy in ("ACTIVE", "PASSIVE"):
                env = dict(os.environ, OMP_WAIT_POLICY=policy)
                r = subprocess.run(
                    [sys.executable, "-c", _OMP_PROBE], env=env, capture_output=True, text=True, check=True
                )
                out[policy, contended] = float(r.stdout.strip())
        finally:
            if busy is not None:
                busy.kill()
                busy.wait()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--height", type=int, default=720)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--pano", type=int, default=1024, help="panorama height (width is twice that)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--scene", default="room")
    args = ap.parse_args()

    scene = ProceduralScene(args.scene, seed=0)
    r = scene.render(args.width, args.height)
    cam, depth = r.camera, r.depth
    obj = place_object(GlassObject.sphere(), depth, cam, up_hint=scene.up)
    vertices, faces, _ = depth_to_mesh(depth, cam)
    d = cam.pixel_rays().reshape(-1, 3)
    rays = np.concatenate([np.zeros_like(d), d], 1).astype(np.float32)

    raw, full, stages = [], [], []
    for _ in range(args.repeat):
        raw.append(raw_cast(vertices, faces, obj, rays))
        t0 = time.perf_counter()
        ws = compute_warps(depth, cam, obj, pano_height=args.pano)
        full.append(time.perf_counter() - t0)
        stages.append(ws.stats["timings_s"])
    raw_t, full_t = statistics.median(raw), statistics.median(full)
    print(
        f"snell_bench warp benchmark  ({platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"torch {torch.__version__}, open3d {o3d.__version__})"
    )
    print(
        f"frame {args.height}x{args.width} ({len(d):,} rays, {len(faces):,} background triangles, "
        f"{len(obj.faces):,} object triangles), panorama {args.pano}x{2 * args.pano}, "
        f"object pixels {int(ws.object_mask.sum()):,}, median of {args.repeat}"
    )
    print(f"  raw Open3D cast (scene build + 1 cast): {raw_t:7.3f} s")
    print(f"  full WarpSet (compute_warps)          : {full_t:7.3f} s")
    print(f"  ratio WarpSet / raw cast              : {full_t / raw_t:7.2f}x   (goal: <= 4x)")
    keys = stages[0].keys()
    med = {k: statistics.median(s[k] for s in stages) for k in keys}
    print("  WarpSet stages: " + ", ".join(f"{k} {v:.3f} s" for k, v in med.items()))
    print(
        f"  whole-frame π⁻¹ (stage frame)         : {med['frame']:7.3f} s ({100 * med['frame'] / full_t:.1f} % of the "
        f"WarpSet; {float(ws.pano_refraction_frame_valid.mean()):.3f} of the pixels valid)"
    )
    probe = omp_wait_policy_probe()
    print(
        "OpenMP wait policy, one small torch op (54k x 3, float64; snell_bench sets PASSIVE unless OMP_WAIT_POLICY is set):"
    )
    for contended, label in ((False, "idle machine"), (True, "one busy process beside it")):
        a, p = probe["ACTIVE", contended], probe["PASSIVE", contended]
        print(f"  {label:27s}: ACTIVE {a * 1e3:7.2f} ms, PASSIVE {p * 1e3:6.2f} ms, ACTIVE / PASSIVE {a / p:6.1f}x")


if __name__ == "__main__":
    main()
