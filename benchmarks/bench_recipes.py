"""Benchmark: the effect of each recipe switch, one at a time, measured in one run.

The full method (``method=snellcaster``) on the paper's six indoor scenes with a glass sphere, on a
CPU stand-in for FLUX (``model=mixture`` by default). The ``paper`` recipe is the baseline; each
switch of :data:`snell_bench.config.recipes.SWITCHES` is set to the authors' value (and, where
snell_bench has its own option, to that) alone, and the whole ``authors`` recipe last; the switches
of relighting and the baselines (which the full method does not read) are left out. Each scene's
inputs (scene, placement, warps, references) are prepared once per distinct setting of those nodes:
a switch of the inputs prepares its own (``reference.renderer=cycles`` renders in Blender Cycles,
``make setup-cycles``, at ``--cycles-spp``); a switch of the metrics rescores the same images.

Prints, per setting, the mean masked PSNR / MAE over the scenes, the difference from ``paper``
(dB, with the per-scene spread of that difference), the model calls and the sampling seconds.
Usage:
python benchmarks/bench_recipes.py [--model mixture --width 320 --height 176 --steps 12 --pano 128]
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time

import snell_bench  # noqa: F401  (first: sets the OpenMP wait policy before torch loads)

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np
import torch

from snell_bench.config import compose
from snell_bench.config.recipes import SWITCHES
from snell_bench.pipeline import ModelPool, apply_method, prepare_inputs, run_method, scorers_of
from snell_bench.pipeline.cell import node_key

INDOOR = ("living_room", "dining_room", "office", "kitchen", "artroom", "cafe")
#: Switches the full method does not read (relighting, the baselines' settings).
SKIPPED = ("relight.", "baselines.")
#: The nodes a cell's shared inputs (scene, placement, warps, reference) are computed from.
INPUT_NODES = ("scene", "object", "warps", "reference", "depth", "segment")


def _override(key: str, value) -> str:
    v = "null" if value is None else str(value).lower() if isinstance(value, bool) else str(value)
    return f"{key}={v}"


def settings() -> list[tuple[str, list[str]]]:
    """(label, overrides) of every measured setting: the paper recipe, each switch flipped alone to
    the authors' value and to snellcaster's own option, and the whole authors recipe."""
    out: list[tuple[str, list[str]]] = [("paper", ["recipe=paper"])]
    for s in SWITCHES:
        if s.key.startswith(SKIPPED):
            continue  # the full method neither relights nor runs a baseline
        for which, value in (("authors", s.authors), ("own", s.own)):
            if which == "own" and value is None or value == s.paper:
                continue
            out.append((f"{s.key}={value}", ["recipe=paper", _override(s.key, value)]))
    out.append(("authors (all)", ["recipe=authors"]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="mixture")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=176)
    ap.add_argument("--pano", type=int, default=128)
    ap.add_argument("--steps", type=int, default=12)
    ap.add_argument("--spp", type=int, default=50)
    ap.add_argument("--cycles-spp", type=int, default=256, help="Blender Cycles' samples (reference.renderer=cycles)")
    ap.add_argument("--scenes", nargs="*", default=list(INDOOR))
    args = ap.parse_args()
    size = [
        f"model={args.model}",
        f"scene.width={args.width}",
        f"scene.height={args.height}",
        f"warps.pano_height={args.pano}",
        f"sampler.steps={args.steps}",
        f"reference.spp={args.spp}",
        f"reference.cycles_spp={args.cycles_spp}",
        "reference.true_render=false",
        "sampler.progress=false",
        "warps.cache_dir=null",
        "output_dir=/tmp/bench_recipes",
    ]
    print(
        f"# recipe switches, one at a time: {args.model}, {args.width} x {args.height}, panorama {args.pano}, "
        f"T = {args.steps}, {len(args.scenes)} scenes, reference {args.spp} spp; "
        f"{platform.processor() or platform.machine()}, {torch.get_num_threads()} threads"
    )
    pool = ModelPool(None)
    rows = []
    inputs_of: dict[tuple, object] = {}
    for label, ov in settings():
        psnr, mae, secs, calls = [], [], 0.0, 0
        for scene in args.scenes:
            cfg = apply_method(compose([f"scene={scene}", "method=snellcaster", *size, *ov]))
            key = tuple(node_key(cfg[n]) for n in INPUT_NODES)  # a switch of the inputs prepares its own
            if key not in inputs_of:
                inputs_of[key] = prepare_inputs(cfg, references=True, pool=pool)
            t0 = time.perf_counter()
            result = run_method(cfg, inputs_of[key], scorers=scorers_of(cfg.metrics, pool))
            secs += time.perf_counter() - t0
            metrics = result.scores.get("metrics", {})
            psnr.append(metrics.get("psnr"))
            mae.append(metrics.get("mae"))
            calls += sum(result.stats.get("model_calls", {}).values())
        rows.append((label, np.array(psnr, float), np.array(mae, float), secs, calls))
    base_psnr = rows[0][1]
    print(f"{'setting':44s} {'PSNR':>7s} {'dPSNR':>7s} {'spread':>7s} {'MAE':>7s} {'calls':>6s} {'sec':>6s}")
    for label, p, m, secs, calls in rows:
        d = p - base_psnr
        spread = float(d.std(ddof=1)) if len(d) > 1 else math.nan
        print(
            f"{label:44s} {np.nanmean(p):7.2f} {np.nanmean(d):+7.2f} {spread:7.2f} {np.nanmean(m):7.4f} "
            f"{calls:6d} {secs:6.1f}"
        )
    markdown(rows)


def markdown(rows) -> None:
    """The recipe table of docs/paper.md: every switch with its values and the measured effects."""

    def cell(v) -> str:
        return "–" if v is None else f"`{str(v).lower() if isinstance(v, bool) else v}`"

    effect = {label: (np.nanmean(p - rows[0][1]), np.std(p - rows[0][1], ddof=1)) for label, p, *_ in rows}
    print("\n| switch | paper | authors | snell_bench's option | what it changes | effect on CPU (dB) |")
    print("|---|---|---|---|---|---|")
    for s in SWITCHES:
        parts = []
        for which, value in (("authors", s.authors), ("own", s.own)):
            key = f"{s.key}={value}"
            if key in effect and value != s.paper:
                d, sd = effect[key]
                parts.append(f"{which} {d:+.2f} ± {sd:.2f}")
        text = "; ".join(parts) or "not measured (the full method neither relights nor runs a baseline)"
        print(f"| `{s.key}` | {cell(s.paper)} | {cell(s.authors)} | {cell(s.own)} | {s.what} | {text} |")


if __name__ == "__main__":
    main()
