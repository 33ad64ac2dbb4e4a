"""Benchmark: the Mitsuba reference render before and after windowing, stratified sampling and LLVM.

Prints, from one run on this machine, per preset (fast, balanced, paper) and cell (the smoke cells
living_room and kitchen with a sphere, procedural; the real RGB-D frame tum_office at 640 x 480):

  (a) before: the reference as it was rendered until now: the whole frame, Mitsuba's ``independent``
      sampler, the preset's former sample count (fast 4, balanced 16, paper 32; ``--before-spp``
      sets one for all) for both passes, ``scalar_rgb`` (``--before-variant``; the variant the
      probe picks with ``probe``);
  (b) after: the preset's own settings: the object's window only, the ``orthogonal`` sampler, the
      preset's ``reference.spp``, the variant the probe picks (``llvm_ad_rgb`` where it works);
  (c) with ``--fallback``: (b) on ``scalar_rgb``, what a machine without a working LLVM gets;

each with its wall time and process CPU time (all threads; steadier than the wall time on a shared
machine), its stages, and its self-noise (the estimated PSNR of the reference against its noise-free
limit, grayscale and RGB, inside the metric mask: ``ReferenceRender.self_noise_db``), and the ratios
after / before. The one-time costs (importing Mitsuba, probing the LLVM variant, compiling the first
kernels) are paid by a warm-up render first and reported apart.

With ``--reflection``, instead: per preset and cell, the reference with ``reference.reflection``
true (the physically complete dielectric) and false (refraction only, the paper's Blender reference
and the authors' ``render_gt``), the same seed, and how much they differ: the mean absolute
difference inside the object mask (sRGB and linear, all channels), the mean signed difference of
the grayscale (refraction only minus with reflection), the PSNR of one against the other inside the
metric mask (grayscale, as the metrics; as rendered and histogram-matched) beside each one's
self-noise.

Convention:
    Inputs are built by ``snell_bench.pipeline.prepare_inputs(cfg, references=False)`` from the
    composed config of each cell, and the reference by ``pipeline.render_reference`` with the
    overrides above; times are medians over ``--repeat`` renders. Usage:
    ``python benchmarks/bench_reference.py [--presets fast,balanced,paper]
    [--cells living_room,kitchen,tum_office] [--repeat 1] [--fallback] [--procedural-size 640x360]
    [--reflection]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import logging
import math
import os
import platform
import statistics
import sys
import time

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import snell_bench  # noqa: E402,F401  (first: sets the OpenMP wait policy before torch loads)
from snell_bench import pipeline  # noqa: E402
from snell_bench.config import compose  # noqa: E402
from snell_bench.render import probe, variants  # noqa: E402

#: The presets' reference sample counts before this benchmark's changes.
BEFORE_SPP = {"fast": 4, "balanced": 16, "paper": 32}
#: Cell name -> the overrides that select it.
CELLS = {
    "living_room": ["+experiment=smoke", "scene=living_room"],
    "kitchen": ["+experiment=smoke", "scene=kitchen"],
    "tum_office": ["+experiment=photo", "scene=tum_office"],
}


@contextlib.contextmanager
def variant(name: str | None):
    """Force the Mitsuba variant (``None``: the probe's choice)."""
    old = os.environ.get(variants.VARIANT_ENV)
    if name:
        os.environ[variants.VARIANT_ENV] = name
    else:
        os.environ.pop(variants.VARIANT_ENV, None)
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(variants.VARIANT_ENV, None)
        else:
            os.environ[variants.VARIANT_ENV] = old


def render(cfg_overrides: list[str], inputs, forced: str | None, repeat: int) -> dict:
    """Median wall and CPU seconds of ``repeat`` references of ``inputs`` under ``cfg_overrides``."""
    cfg = compose(cfg_overrides)
    walls, cpus = [], []
    with variant(forced):
        for _ in range(repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            ref, reason = pipeline.render_reference(cfg, inputs.scene, inputs.obj)
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
    if ref is None:
        raise SystemExit(f"no reference: {reason}")
    return {
        "wall": statistics.median(walls),
        "cpu": statistics.median(cpus),
        "ref": ref,
        "stages": {k: round(v, 1) for k, v in ref.timings.items()},
    }


def warm_up(forced: str | None) -> tuple[str, float]:
    """Import Mitsuba, pick (or force) the variant and compile the tiny probe scene's kernels."""
    t0 = time.perf_counter()
    with variant(forced):
        name = variants.mitsuba_variant()
        os.environ[variants.VARIANT_ENV] = name
        with contextlib.redirect_stdout(io.StringIO()):
            probe.probe_render()
    return name, time.perf_counter() - t0


def fmt_db(v) -> str:
    return "   n/a" if v is None else f"{v:6.1f}"


def row(label: str, r: dict) -> str:
    ref = r["ref"]
    x0, y0, x1, y1 = ref.window
    return (
        f"    {label:8s} {ref.variant:11s} {ref.sampler:11s} {ref.spp:5d} {ref.unobserved_spp:5d}  "
        f"{x1 - x0:4d}x{y1 - y0:<4d} {r['wall']:7.1f} {r['cpu']:7.1f}  {fmt_db(ref.self_noise_db)} "
        f"{fmt_db(ref.self_noise_rgb_db)}  {r['stages']}"
    )


def reflection_effect(args) -> None:
    """The reference with and without the first-surface reflection (see the module's docstring)."""
    import numpy as np

    from snell_bench.imaging.color import srgb_to_linear
    from snell_bench.metrics import masked_psnr

    luma = np.array([0.299, 0.587, 0.114])
    for preset in args.presets.split(","):
        for cell in args.cells.split(","):
            base = [*CELLS[cell], f"preset={preset}", "object=sphere", "output_dir=/tmp/bench_reference"]
            if args.procedural_size and cell != "tum_office":
                w, h = args.procedural_size.lower().split("x")
                base += [f"scene.width={int(w)}", f"scene.height={int(h)}"]
            inputs = pipeline.prepare_inputs(compose(base), references=False)
            rows = {
                r: render([*base, f"reference.reflection={r}"], inputs, None, args.repeat) for r in ("true", "false")
            }
            a, b = rows["true"]["ref"], rows["false"]["ref"]
            m, mm = a.object_mask, a.mask & b.mask
            d = b.image.astype(np.float64) - a.image
            dl = srgb_to_linear(b.image.astype(np.float64)) - srgb_to_linear(a.image.astype(np.float64))
            pairs = [(False, "as rendered"), (True, "histogram-matched")]
            psnr = {k: masked_psnr(b.image, a.image, mm, histogram_match=k) if mm.any() else math.nan for k, _ in pairs}
            H, W = inputs.scene.camera.shape
            print(f"  {preset} / {cell} ({W}x{H}, {int(m.sum())} object pixels, {int(mm.sum())} mask pixels)")
            print(
                f"    wall s: reflection {rows['true']['wall']:.1f}, refraction only {rows['false']['wall']:.1f}; "
                f"self-noise dB: {fmt_db(a.self_noise_db)}, {fmt_db(b.self_noise_db)}"
            )
            print(
                f"    inside the object: mean |difference| sRGB {np.abs(d[m]).mean():.4f}, linear "
                f"{np.abs(dl[m]).mean():.4f}; mean signed grayscale (false - true) {(d[m] @ luma).mean():+.4f}"
            )
            print(
                "    PSNR of one against the other in the metric mask (grayscale): "
                + ", ".join(f"{label} {psnr[k]:.2f} dB" for k, label in pairs)
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default="fast,balanced,paper")
    ap.add_argument("--cells", default=",".join(CELLS))
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--before-spp", type=int, default=None, help="the before row's spp for every preset")
    ap.add_argument("--before-variant", default="scalar_rgb", help="a Mitsuba variant, or 'probe'")
    ap.add_argument("--fallback", action="store_true", help="also the after settings on scalar_rgb")
    ap.add_argument("--procedural-size", default=None, help="WxH of the procedural cells (default: the preset's)")
    ap.add_argument("--reflection", action="store_true", help="compare reference.reflection true and false")
    args = ap.parse_args()
    sys.stdout.reconfigure(line_buffering=True)  # progress shows when piped
    logging.basicConfig(level=logging.ERROR)
    before_variant = None if args.before_variant == "probe" else args.before_variant

    import drjit as dr
    import mitsuba as mi

    print(
        f"snell_bench reference benchmark  ({platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"mitsuba {mi.__version__}, drjit {dr.__version__})"
    )
    after_variant, t_probe = warm_up(None)
    print(f"  warm-up: the probe picks {after_variant} ({t_probe:.1f} s: import, probe, first kernels)")
    for v in {before_variant or after_variant, "scalar_rgb" if args.fallback else after_variant} - {after_variant}:
        _, t = warm_up(v)
        print(f"  warm-up: {v} ({t:.1f} s)")
    print(
        "  columns: variant, sampler, spp (image pass), spp of the unobserved pass, window rendered, wall s, "
        "CPU s (all threads), self-noise dB (grayscale, RGB; the reference vs its noise-free limit, inside the "
        "metric mask), stages s"
    )
    if args.reflection:
        return reflection_effect(args)
    summary = []
    for preset in args.presets.split(","):
        b_spp = args.before_spp or BEFORE_SPP[preset]
        for cell in args.cells.split(","):
            base = [*CELLS[cell], f"preset={preset}", "object=sphere", "output_dir=/tmp/bench_reference"]
            if args.procedural_size and cell != "tum_office":
                w, h = args.procedural_size.lower().split("x")
                base += [f"scene.width={int(w)}", f"scene.height={int(h)}"]
            cfg = compose(base)
            inputs = pipeline.prepare_inputs(cfg, references=False)
            H, W = inputs.scene.camera.shape
            before = [
                *base,
                "reference.crop=false",
                "reference.sampler=independent",
                f"reference.spp={b_spp}",
                "reference.unobserved_spp=null",
            ]
            rows = {"before": render(before, inputs, before_variant, args.repeat)}
            rows["after"] = render(base, inputs, None, args.repeat)
            if args.fallback:
                rows["fallback"] = render(base, inputs, "scalar_rgb", args.repeat)
            print(f"  {preset} / {cell} ({W}x{H}, {int(rows['after']['ref'].mask.sum())} mask pixels)")
            for label, r in rows.items():
                print(row(label, r))
            b, a = rows["before"], rows["after"]
            gain = (
                None
                if a["ref"].self_noise_db is None or b["ref"].self_noise_db is None
                else a["ref"].self_noise_db - b["ref"].self_noise_db
            )
            line = (
                f"    after / before: wall {a['wall'] / b['wall']:.2f}x, CPU {a['cpu'] / b['cpu']:.2f}x, "
                f"self-noise {'n/a' if gain is None else f'{gain:+.1f} dB'}"
            )
            if args.fallback:
                f = rows["fallback"]
                line += f"; fallback / before: wall {f['wall'] / b['wall']:.2f}x, CPU {f['cpu'] / b['cpu']:.2f}x"
            print(line)
            summary.append((preset, cell, a["wall"] / b["wall"], a["ref"].self_noise_db))
    print("summary (after): preset, cell, wall after / before, self-noise dB")
    for preset, cell, ratio, noise in summary:
        print(f"  {preset:9s} {cell:12s} {ratio:5.2f}x {fmt_db(noise)}")


if __name__ == "__main__":
    main()
