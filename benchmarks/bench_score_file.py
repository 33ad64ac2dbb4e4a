"""Benchmark: what scoring the saved 8-bit image (``metrics.score_file=true``, the default) instead of
the sampler's float image changes, measured in one run.

Every method is scored as its ``image.png`` holds it, so that images made elsewhere (``method=images``)
and the built-in methods are scored alike, and a saved image re-scores to its record's number. This
measures the cost of that choice: the same images (one sampling per cell) scored both ways against
the same references, on the paper's six indoor scenes with a glass sphere, for Snellcaster and the
text-to-image baseline on a CPU stand-in for FLUX. Prints per method the mean and the largest
|difference| of the masked PSNR (dB) and MAE, and the PSNR against the true render.

Usage:
python benchmarks/bench_score_file.py [--model analytic --preset balanced]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import snell_bench  # noqa: F401  (first: sets the OpenMP wait policy before torch loads)

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np

from snell_bench.config import compose
from snell_bench.pipeline import ModelPool, apply_method, prepare_inputs, run_method, score, scorers_of

INDOOR = ("living_room", "dining_room", "office", "kitchen", "artroom", "cafe")
METHODS = ("snellcaster", "t2i")
METRICS = ("psnr", "mae", "psnr_true")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="analytic")
    ap.add_argument("--preset", default="balanced")
    ap.add_argument("--scenes", nargs="*", default=list(INDOOR))
    args = ap.parse_args()
    print(
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores; model={args.model}, preset={args.preset}"
    )
    diffs: dict[str, dict[str, list[float]]] = {m: {k: [] for k in METRICS} for m in METHODS}
    t0 = time.perf_counter()
    pool = ModelPool()
    for scene in args.scenes:
        base = [f"scene={scene}", f"model={args.model}", f"preset={args.preset}", "warps.cache_dir=null"]
        inputs = prepare_inputs(compose(base), pool=pool)
        for method in METHODS:
            saved = apply_method(compose([*base, f"method={method}"]))
            floats = apply_method(compose([*base, f"method={method}", "metrics.score_file=false"]))
            scorers = scorers_of(saved.metrics, pool)
            res = run_method(saved, inputs, scorers=scorers)
            as_float = score(floats, inputs, res.image, scorers)["metrics"]
            for k in METRICS:
                a, b = res.scores["metrics"].get(k), as_float.get(k)
                if a is not None and b is not None:
                    diffs[method][k].append(a - b)
        print(f"  {scene}: done ({time.perf_counter() - t0:.0f} s)")
    print("\nsaved 8-bit image minus float image, over the scenes (mean, largest |difference|):")
    for method, by in diffs.items():
        parts = []
        for k, d in by.items():
            d = np.asarray(d)
            if d.size:
                if k == "mae":
                    parts.append(f"{k} {d.mean():+.2e} (max |{np.abs(d).max():.2e}|)")
                else:
                    parts.append(f"{k} {d.mean():+.4f} dB (max |{np.abs(d).max():.4f}|)")
        print(f"  {method:12s} " + "; ".join(parts))
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
