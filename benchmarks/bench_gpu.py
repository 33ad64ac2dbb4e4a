"""Benchmark: one GPU node at the paper's settings, with FLUX-shaped random weights (no download).

One Snellcaster perspective + panorama pair (T = 20, the recipe's time travel, 720 x 1280 and a
1024 x 2048 panorama, a procedural room and a glass sphere), then the text-to-image baseline, FLUX
Fill and FLUX Kontext x N candidates, each with the models built at full size with random weights
(``model.random_init``: real shapes and cost, meaningless pixels). Prints, from one run:

- the pair: total seconds, model calls per branch, seconds per step split into the transformer,
  VAE decode, VAE encode and the rest of the loop (warps, blends, steps), the bytes that cross
  between host and device per step, peak device memory;
- the same totals for ``t2i``, Fill and Kontext x N;
- the weights of each model and what they share (loaded once);
- last, the ratios: pair / t2i and the share of the step the transformer takes.

``--tiny`` runs the same code with the tiny FLUX of the tests at small sizes (CPU, seconds): the
script cannot rot without a GPU. ``--json PATH`` writes the figures for ``job=plan plan.bench=PATH``.

Usage: python benchmarks/bench_gpu.py [--device cuda] [--recipe paper] [--candidates 3] [--json out.json]
       python benchmarks/bench_gpu.py --tiny --device cpu
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import replace
from pathlib import Path

import snell_bench  # noqa: F401  (first: sets the OpenMP wait policy before torch loads)

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import torch
from omegaconf import OmegaConf

from snell_bench import pipeline
from snell_bench.config import compose
from snell_bench.pipeline import ModelPool, apply_method, full_prompt, inpaint_mask, model_bytes
from snell_bench.sampler import sample
from snell_bench.utils.transfers import TransferCounter


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


class Timed:
    """A generator whose velocity, decode and encode calls are timed to completion (the device
    synchronised before and after each), counted, and otherwise unchanged."""

    def __init__(self, gen) -> None:
        self.gen = gen
        self.name, self.geometry = gen.name, gen.geometry
        self.device, self.dtype = gen.device, gen.dtype
        self.has_posterior = getattr(gen, "has_posterior", False)
        self.seconds = {"transformer": 0.0, "vae_decode": 0.0, "vae_encode": 0.0}
        self.calls = {k: 0 for k in self.seconds}

    def _timed(self, key, fn, *args, **kw):
        _sync(self.device)
        t0 = time.perf_counter()
        out = fn(*args, **kw)
        _sync(self.device)
        self.seconds[key] += time.perf_counter() - t0
        self.calls[key] += 1
        return out

    def velocity(self, z, sigma, cond):
        return self._timed("transformer", self.gen.velocity, z, sigma, cond)

    def decode(self, z):
        return self._timed("vae_decode", self.gen.decode, z)

    def encode(self, x, generator=None):
        return self._timed("vae_encode", self.gen.encode, x, generator)

    def condition(self, *args, **kw):
        return self.gen.condition(*args, **kw)

    def sigmas(self, *args, **kw):
        return self.gen.sigmas(*args, **kw)


def _peak_reset(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)


def _peak_gb(device: torch.device) -> float | None:
    return torch.cuda.max_memory_allocated(device) / 1e9 if device.type == "cuda" else None


def _timed_call(device: torch.device, fn):
    _peak_reset(device)
    _sync(device)
    t0 = time.perf_counter()
    out = fn()
    _sync(device)
    return out, time.perf_counter() - t0, _peak_gb(device)


def _fmt(x, spec=".2f", none="n/a"):
    return none if x is None else format(x, spec)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--tiny", action="store_true", help="the tiny FLUX of the tests at small sizes (CPU)")
    ap.add_argument("--recipe", default="paper", choices=["paper", "authors"])
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--height", type=int, default=None, help="default 720 (96 with --tiny)")
    ap.add_argument("--width", type=int, default=None, help="default 1280 (160 with --tiny)")
    ap.add_argument("--pano", type=int, default=None, help="panorama rows; default 1024 (64 with --tiny)")
    ap.add_argument("--candidates", type=int, default=3, help="Kontext relighting candidates")
    ap.add_argument("--skip", nargs="*", default=[], choices=["t2i", "fill", "kontext"])
    ap.add_argument("--json", default=None, help="write the figures here (for job=plan plan.bench=...)")
    args = ap.parse_args()
    H = args.height or (96 if args.tiny else 720)
    W = args.width or (160 if args.tiny else 1280)
    P = args.pano or (64 if args.tiny else 1024)
    device = torch.device(args.device)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else f"cpu ({platform.machine()})"

    model = ["model=tiny_flux"] if args.tiny else ["model=flux_dev", "model.random_init=true"]
    base = [
        "preset=paper",
        f"recipe={args.recipe}",
        *model,
        f"model.device={args.device}",
        "scene=living_room",
        # the sampler's cost on the procedural room (named: a text-to-image model would generate I⁻,
        # which needs a depth estimator and is timed by the plan apart)
        "scene.source=procedural",
        f"scene.width={W}",
        f"scene.height={H}",
        "scene.supersample=1",
        f"warps.pano_height={P}",
        f"sampler.steps={args.steps}",
        "sampler.progress=false",
        "reference.enabled=false",
        f"relight.candidates={args.candidates}",
    ]
    if not args.tiny:
        base.append("model.dtype=bfloat16")
    cfg = apply_method(compose([*base, "method=snellcaster_relit"]))
    print(f"snell_bench GPU benchmark: {name}, torch {torch.__version__}, {os.cpu_count()} CPU cores")
    print(
        f"recipe={args.recipe}, T={args.steps}, view {H}x{W}, panorama {P}x{2 * P}, "
        f"{'tiny random FLUX' if args.tiny else 'FLUX.1 [dev] / Fill / Kontext shapes, random weights, bf16'}"
    )

    t0 = time.perf_counter()
    pool = ModelPool(cfg.models.memory_gb, offload=bool(cfg.models.offload))
    inputs = pipeline.prepare_inputs(cfg, references=False, pool=pool)
    print(f"inputs (scene, placement, warps on the CPU): {time.perf_counter() - t0:.1f} s")

    (gen, load_s) = pipeline.inputs.generator_of(cfg, pool)
    timed = Timed(gen)
    settings = OmegaConf.to_object(cfg.sampler)
    prompt, pano_prompt = full_prompt(cfg), str(cfg.scene.pano_prompt)

    def run_pair(s):
        return sample(timed, inputs.warps, inputs.i_minus, prompt, pano_prompt, s, seed=0)

    run_pair(replace(settings, steps=2))  # warm-up: kernels, allocator, caches
    timed.seconds = dict.fromkeys(timed.seconds, 0.0)
    timed.calls = dict.fromkeys(timed.calls, 0)
    with TransferCounter() as moved:
        res, pair_s, pair_peak = _timed_call(device, lambda: run_pair(settings))
    parts = {k: v / args.steps for k, v in timed.seconds.items()}
    passes = timed.calls["transformer"]
    with TransferCounter() as moved_1:
        run_pair(replace(settings, steps=1))
    per_step_bytes = (moved.bytes - moved_1.bytes) / max(args.steps - 1, 1)
    parts["warps_blends"] = max(0.0, pair_s / args.steps - sum(parts.values()) - res.timings["setup"] / args.steps)
    out = {
        "device": name,
        "dtype": str(gen.dtype).removeprefix("torch."),
        "random_weights": True,
        "tiny": bool(args.tiny),
        "settings": {"steps": args.steps, "height": H, "width": W, "pano_height": P, "recipe": args.recipe},
        "load_s": {"flux_dev": round(load_s, 2)},
        "pair": {
            "total_s": round(pair_s, 3),
            "model_calls": dict(res.model_calls),
            "transformer_passes": passes,
            "per_step_s": {k: round(v, 4) for k, v in parts.items()},
            "setup_s": round(res.timings["setup"], 3),
            "peak_memory_gb": pair_peak,
            "host_device_bytes_per_step": int(per_step_bytes),
            "host_device_bytes_per_run": int(moved_1.bytes),
        },
        "memory_gb": {"flux_dev": model_bytes(gen) / 1e9},
    }
    print(
        f"pair: {pair_s:.2f} s, model calls main {res.model_calls.get('main', 0)} + panorama "
        f"{res.model_calls.get('pano', 0)} in {passes} transformer passes; peak "
        f"{_fmt(pair_peak)} GB"
    )
    print("  per step: " + ", ".join(f"{k} {v:.3f} s" for k, v in parts.items()))
    print(f"  host<->device: {moved_1.bytes / 1e6:.1f} MB once per run, {per_step_bytes:.0f} bytes per step")

    if "t2i" not in args.skip:
        t2i = OmegaConf.to_object(apply_method(compose([*base, "method=t2i"])).sampler)
        r, s_, peak = _timed_call(device, lambda: sample(gen, inputs.warps, inputs.i_minus, prompt, pano_prompt, t2i))
        out["t2i"] = {"total_s": round(s_, 3), "steps": t2i.steps, "peak_memory_gb": peak}
        print(f"t2i: {s_:.2f} s ({t2i.steps} steps, {r.model_calls.get('main', 0)} model calls); peak {_fmt(peak)} GB")

    if "fill" not in args.skip:
        fcfg = compose([*base, "method=inpaint"])
        fill, fill_load = pool.get("fill", "fill", lambda: pipeline.cell.build(fcfg.model.fill), label="fill")
        steps = int(fcfg.method.steps or 30)
        guidance = None if fcfg.method.guidance is None else float(fcfg.method.guidance)
        mask = inpaint_mask(fcfg, inputs.warps)
        from snell_bench.models.external import inpaint_external

        fill.to(device)
        fill.set_progress_bar_config(disable=True)
        _, s_, peak = _timed_call(
            device,
            lambda: inpaint_external(fill, prompt, inputs.i_minus, mask, steps=steps, guidance=guidance),
        )
        out["fill"] = {"total_s": round(s_, 3), "steps": steps, "peak_memory_gb": peak}
        out["load_s"]["fill"] = round(fill_load, 2)
        out["memory_gb"]["fill"] = model_bytes(fill) / 1e9
        print(f"fill: {s_:.2f} s ({steps} steps); peak {_fmt(peak)} GB")

    if "kontext" not in args.skip:
        relighter, k_load = pipeline.methods.relighter_of(cfg, inputs)
        n = int(args.candidates)
        _, s_, peak = _timed_call(
            device,
            lambda: [relighter.relight(res.image, prompt="add shadows and caustics", seed=i) for i in range(n)],
        )
        out["kontext"] = {"total_s": round(s_, 3), "steps": relighter.steps, "candidates": n, "peak_memory_gb": peak}
        out["load_s"]["kontext"] = round(k_load, 2)
        out["memory_gb"]["kontext"] = model_bytes(relighter) / 1e9
        print(f"kontext x {n}: {s_:.2f} s ({relighter.steps} steps each); peak {_fmt(peak)} GB")
        shared = sum(
            model_bytes(getattr(gen.pipe, c))
            for c in ("text_encoder", "text_encoder_2", "vae")
            if getattr(relighter.pipe, c) is getattr(gen.pipe, c)
        )
        out["memory_gb"]["shared_text_vae"] = shared / 1e9
    out["memory_gb"] = {k: round(v, 3) for k, v in out["memory_gb"].items()}
    out["pool"] = pool.summary()
    print("weights (GB): " + ", ".join(f"{k} {v:.2f}" for k, v in out["memory_gb"].items()))
    for ev in pool.loads:
        if ev.event != "load":
            print(f"  pool: {ev.event} {ev.label} {ev.bytes / 1e9:.2f} GB in {ev.seconds:.2f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
        print(f"figures: {args.json}")
    ratios = []
    if "t2i" in out:
        ratios.append(f"pair / t2i {pair_s / out['t2i']['total_s']:.2f}x")
    step = pair_s / args.steps
    ratios.append(f"transformer share of a pair's step {parts['transformer'] / step:.0%}")
    print("ratios: " + ", ".join(ratios))


if __name__ == "__main__":
    main()
