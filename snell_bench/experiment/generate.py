"""The generation job (``job=generate``): one scene, one object, one method.

Writes ``image.png`` (the generated view; relit with ``method.relight``, ``image_unrelit.png``
before relighting), ``panorama.png`` (the panorama branch, if any),
``I_minus.png``, ``mask.png``, the intermediate estimates of ``sampler.dump_every`` and
``summary.json`` (model calls, time per stage, the sampler's decisions, and the PSNR of the
object region against π^R(I⁻), the part of the glass Snell's law fixes) under the run directory.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from snell_bench import pipeline
from snell_bench.utils.io import save_png, write_json
from snell_bench.utils.tensors import bchw_to_hwc

log = logging.getLogger(__name__)

__all__ = ["run_generate"]


def run_generate(cfg: DictConfig) -> dict:
    """Generate ``cfg``'s image into ``cfg.output_dir``; returns the summary."""
    from snell_bench.metrics.refraction import refraction_psnr

    cfg = pipeline.apply_method(cfg)  # the method's switches (conf/method/) over the sampler and warps nodes
    out = Path(cfg.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    inputs = pipeline.prepare_inputs(cfg, references=False)
    res = pipeline.run_method(cfg, inputs)
    ws = res.warps
    save_png(out / "image.png", bchw_to_hwc(res.image))
    if res.panorama is not None:
        save_png(out / "panorama.png", bchw_to_hwc(res.panorama))
    if res.unrelit is not None:
        save_png(out / "image_unrelit.png", bchw_to_hwc(res.unrelit))
    save_png(out / "I_minus.png", inputs.scene.image)
    save_png(out / "mask.png", ws.object_mask.astype(np.float32))
    for d in res.dumps:
        for key in ("main_x0", "main_sync", "pano_x0", "pano_sync"):
            if d[key] is not None:
                save_png(out / f"step{d['step']:03d}_{key}.png", bchw_to_hwc(d[key]))
    psnr = refraction_psnr(res.image, inputs.i_minus, ws)
    summary = {
        "model": cfg.model.name,
        "method": cfg.method.name,
        "prompt": pipeline.full_prompt(cfg),
        "sampler": OmegaConf.to_container(cfg.sampler),
        **res.stats,
        "warps": {k: ws.stats.get(k) for k in ("roi", "traced_primary_rays", "far_background") if k in ws.stats},
        "timings_s": {k: round(v, 3) for k, v in {**inputs.timings, **res.timings}.items()},
        "refraction_psnr_db": psnr,
    }
    write_json(out / "summary.json", summary)
    print(
        f"generated {out}/image.png  (object PSNR vs pi^R(I-): "
        f"{'n/a' if psnr is None else f'{psnr:.2f} dB'}, model calls {res.stats.get('model_calls')}, "
        f"sampling {res.timings.get('sampling', 0.0):.1f} s)"
    )
    return summary
