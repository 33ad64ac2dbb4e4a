"""Benchmark: a grid on one node as fast as its slowest resource, by preparing the groups' inputs in
worker processes while the generator samples (``grid.prefetch``).

A 4-group grid (4 procedural scenes x a glass sphere x Snellcaster, 320 x 176, a 5618-spp
reference: about 11 s of preparation per group on 2 cores) runs twice into temporary folders, with
``grid.prefetch=0`` (every stage in order) and ``grid.prefetch=2`` (one worker process). The
generator is ``model=sleeping``: the analytic CPU stand-in whose every model call also sleeps
(``--sleep`` seconds), so that sampling takes GPU-like wall time and leaves the CPU free, as FLUX
on a GPU does; the default sleep (0.25 s, about 50 calls per cell) makes sampling take about as
long as preparing (~1.2x on 2 cores). For each run it prints the grid's wall time, the sums over
its cells of the sampling time and of the preparation time (``scene + warps + reference +
true_render``, measured where each stage ran) from the cells' ``metrics.json``, and the ratio of
the wall time to the larger sum: about (S + P) / max(S, P) when the two run one after the other,
1 when the grid takes exactly as long as its slower resource (the runner's own work, planning the
cells and writing their records, comes on top). The last line is that ratio with prefetch (the
goal: <= 1.15). Mitsuba's variant is probed, and the renderer warmed up, before either run is
timed.
Usage: python benchmarks/bench_overlap.py [--sleep 0.25 --spp 5618 --workers 1 --ahead 2]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import snell_bench  # noqa: F401  (first: sets the OpenMP wait policy before torch loads)

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from snell_bench.config import compose  # noqa: E402

PREPARATION = ("scene", "warps", "reference", "true_render")


def run(tmp: Path, name: str, overrides: list[str]) -> dict:
    """One grid into ``tmp/name``: its wall time and the sums of its cells' stage timings."""
    from snell_bench.experiment.runner import run_grid

    cfg = compose([*overrides, f"runs_dir={tmp / name}", f"reports_dir={tmp / 'reports'}"])
    t0 = time.perf_counter()
    summary = run_grid(cfg)
    wall = time.perf_counter() - t0
    if summary["ok"] != summary["cells"]:
        raise RuntimeError(f"{name}: not every cell finished: {summary}")
    cells = [json.loads(p.read_text()) for p in sorted((tmp / name).rglob("metrics.json"))]
    sampling = sum(c["timings_s"]["sampling"] for c in cells)
    preparation = sum(c["timings_s"].get(k, 0.0) for c in cells for k in PREPARATION)
    return {
        "wall": wall,
        "sampling": sampling,
        "preparation": preparation,
        "ratio": wall / max(sampling, preparation),
        "prefetch": summary["prefetch"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--sleep", type=float, default=0.25, help="seconds each model call sleeps (model.generator.sleep_s)"
    )
    ap.add_argument("--spp", type=int, default=5618, help="reference samples per pixel (reference.spp)")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=176)
    ap.add_argument("--ahead", type=int, default=2, help="grid.prefetch of the second run")
    ap.add_argument("--workers", type=int, default=1, help="grid.workers of the second run")
    args = ap.parse_args()

    from snell_bench.render.probe import probe_render
    from snell_bench.render.variants import mitsuba_variant

    variant = mitsuba_variant()  # probed once, here; the workers are handed it
    with contextlib.redirect_stdout(io.StringIO()):
        probe_render()  # Mitsuba imported and its kernels compiled before any timing
    grid = [
        "+experiment=smoke",
        "preset=fast",
        "model=sleeping",
        f"model.generator.sleep_s={args.sleep}",
        f"scene.width={args.width}",
        f"scene.height={args.height}",
        "warps.pano_height=128",
        "warps.cache_dir=null",
        f"reference.spp={args.spp}",
        "grid.scenes=[living_room,kitchen,office,dining_room]",
        "grid.methods=[snellcaster]",
        "grid.report=false",
        "sampler.progress=false",
    ]
    print(
        f"snell_bench overlap benchmark ({platform.machine()}, {os.cpu_count()} cores, Mitsuba {variant}): "
        f"4 groups x Snellcaster, {args.height}x{args.width}, reference {args.spp} spp, "
        f"model=sleeping ({args.sleep} s per model call)"
    )
    results = {}
    with tempfile.TemporaryDirectory(prefix="bench_overlap_") as d:
        for label, extra in (
            ("prefetch off", ["grid.prefetch=0"]),
            (
                f"prefetch {args.ahead}, {args.workers} worker(s)",
                [f"grid.prefetch={args.ahead}", f"grid.workers={args.workers}"],
            ),
        ):
            results[label] = r = run(Path(d), label.split(",")[0].replace(" ", "_"), [*grid, *extra])
            print(
                f"{label}: grid wall {r['wall']:.1f} s, sampling sum {r['sampling']:.1f} s, "
                f"preparation sum {r['preparation']:.1f} s, wall / max(sampling, preparation) = {r['ratio']:.2f}"
            )
    off, on = results.values()
    print(f"speed-up of the grid with prefetch: {off['wall'] / on['wall']:.2f}x")
    print(f"wall / max(sampling sum, preparation sum) with prefetch: {on['ratio']:.2f} (goal <= 1.15)")


if __name__ == "__main__":
    main()
