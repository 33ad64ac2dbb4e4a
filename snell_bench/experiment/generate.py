"""The generation job: one scene, one object, one sampler setting.

Writes ``image.png`` (the generated view), ``panorama.png`` (the panorama branch, if any),
``I_minus.png``, ``mask.png`` and ``summary.json`` (model calls, time per stage, and the masked
PSNR of the object region against π^R(I⁻), the part of the glass Snell's law fixes) under the run
directory.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from snell_bench.experiment.preview import save_png
from snell_bench.imaging.remap import remap
from snell_bench.optics.warps import WarpSet
from snell_bench.sampler.settings import SamplerSettings

log = logging.getLogger(__name__)

__all__ = ["run_generate", "refraction_psnr"]


def refraction_psnr(image: torch.Tensor, i_minus: torch.Tensor, ws: WarpSet) -> float:
    """PSNR (dB) over object pixels whose refracted ray I⁻ observes, of ``image`` against
    π^R(I⁻); NaN where there is no such pixel."""
    target, _ = remap(i_minus, ws.refraction)
    m = torch.from_numpy(ws.object_mask & ws.refraction_valid)
    if not m.any():
        return float("nan")
    mse = float(((image - target) ** 2).mean(1)[0][m].mean())
    return float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)


def run_generate(cfg: DictConfig) -> dict:
    from snell_bench.experiment.inputs import (
        apply_method,
        make_generator,
        make_object,
        make_scene_inputs,
        place_from_config,
        warps_from_config,
    )
    from snell_bench.sampler.snellcaster import sample

    cfg = apply_method(cfg)  # the method's switches (conf/method/) over the sampler and warps nodes
    out = Path(cfg.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    t = {}
    t0 = time.perf_counter()
    inputs = make_scene_inputs(cfg.scene)
    obj = place_from_config(make_object(cfg.object), inputs, cfg.object, seed=int(cfg.seed))
    ws = warps_from_config(inputs, obj, cfg.warps)
    t["inputs_and_warps"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    gen = make_generator(cfg.model, inputs, ws)
    t["generator"] = time.perf_counter() - t0
    settings: SamplerSettings = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(SamplerSettings), cfg.sampler))
    i_minus = torch.from_numpy(inputs.image).permute(2, 0, 1)[None].float()
    t0 = time.perf_counter()
    res = sample(gen, ws, i_minus, cfg.scene.prompt, cfg.scene.pano_prompt, settings, seed=int(cfg.seed))
    t["sampling"] = time.perf_counter() - t0

    img = res.image[0].permute(1, 2, 0).numpy()
    save_png(out / "image.png", img)
    if res.panorama is not None:
        save_png(out / "panorama.png", res.panorama[0].permute(1, 2, 0).numpy())
    save_png(out / "I_minus.png", inputs.image)
    save_png(out / "mask.png", ws.object_mask.astype(np.float32))
    for d in res.dumps:
        for key in ("main_x0", "main_sync", "pano_x0", "pano_sync"):
            if d[key] is not None:
                save_png(out / f"step{d['step']:03d}_{key}.png", d[key][0].permute(1, 2, 0).numpy())
    summary = {
        "model": cfg.model.name,
        "sampler": OmegaConf.to_container(cfg.sampler),
        "model_calls": res.model_calls,
        "decisions": res.decisions,
        "warps": {k: ws.stats.get(k) for k in ("roi", "traced_primary_rays", "far_background") if k in ws.stats},
        "sampler_timings_s": {k: round(v, 3) for k, v in res.timings.items()},
        "timings_s": {k: round(v, 3) for k, v in t.items()},
        "refraction_psnr_db": refraction_psnr(res.image, i_minus, ws),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"generated {out}/image.png  (object PSNR vs pi^R(I-): {summary['refraction_psnr_db']:.2f} dB, "
          f"model calls {res.model_calls}, sampling {t['sampling']:.1f} s)")
    return summary
