"""The refraction preview (``job=preview``): what Snell's law alone says the glass object must show.

For one scene and object it writes, under the run directory:

- ``I_minus.png``: the object-free image I⁻;
- ``mask.png``: the object mask (white), with pixels whose refracted ray I⁻ cannot show in grey;
- ``warp.png``: π^R as a colour code of the *source* pixel (red = x, green = y; identity outside
  the object, so a glass sphere shows the gradient flipped and magnified; black = invalid);
- ``panorama.png``: the 360° panorama centred at the object;
- ``composite.png``: inside the object ``R · π^-R(pano) + (1 - R) · π^R(I⁻)`` in linear RGB
  (where I⁻ cannot show the refracted ray's end, the panorama supplies it through π⁻¹);
- ``preview.png``: the four views side by side; ``summary.json``: warp statistics and timings.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from snell_bench import pipeline
from snell_bench.imaging.blend import absorb, fresnel_combine
from snell_bench.imaging.remap import remap
from snell_bench.optics.warps import WarpSet
from snell_bench.scene.sources import panorama_prior, scene_panorama
from snell_bench.utils.io import save_png, write_json
from snell_bench.utils.tensors import bchw_to_hwc, hwc_to_bchw
from snell_bench.utils.timing import Timer

log = logging.getLogger(__name__)

__all__ = ["run_preview", "composite_refraction", "warp_to_rgb"]


def composite_refraction(i_minus: np.ndarray, panorama: np.ndarray, ws: WarpSet) -> np.ndarray:
    """The physically composited glass: ``(H, W, 3)`` sRGB in [0, 1] (see the module docs)."""
    im, pano = hwc_to_bchw(i_minus), hwc_to_bchw(panorama)
    refr, _ = remap(im, ws.refraction)
    refr_pano, _ = remap(pano, ws.pano_refraction, wrap_x=True)
    refl, _ = remap(pano, ws.pano_reflection, wrap_x=True)
    valid = torch.from_numpy(ws.refraction_valid)[None, None]
    mask = torch.from_numpy(ws.object_mask)[None, None]
    refr = torch.where(valid, refr, refr_pano)
    if ws.absorbs:
        refr = absorb(refr, ws.transmittance())
    glass = fresnel_combine(refl, refr, ws.fresnel)
    return bchw_to_hwc(torch.where(mask, glass, im))


def warp_to_rgb(coords: np.ndarray, width: int, height: int) -> np.ndarray:
    """Source coordinates as colours: red = x / (W - 1), green = y / (H - 1), blue = 0.5; NaN black."""
    rgb = np.zeros(coords.shape[:2] + (3,), np.float32)
    ok = np.isfinite(coords).all(-1)
    rgb[..., 0] = np.where(ok, coords[..., 0] / max(width - 1, 1), 0)
    rgb[..., 1] = np.where(ok, coords[..., 1] / max(height - 1, 1), 0)
    rgb[..., 2] = np.where(ok, 0.5, 0)
    return np.clip(rgb, 0, 1)


def run_preview(cfg: DictConfig) -> dict:
    """Write the preview of ``cfg``'s scene and object into ``cfg.output_dir``; returns the summary."""
    out = Path(cfg.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    inputs = pipeline.prepare_inputs(cfg, references=False)
    ws, image, obj = inputs.warps, inputs.scene.image, inputs.obj
    t = Timer()
    with t("panorama"):  # in the orientation of the warps' panorama camera
        if hasattr(inputs.scene.source, "render_panorama"):  # the source's true panorama
            panorama = scene_panorama(inputs.scene, ws.pano, supersample=cfg.scene.supersample)
        else:  # a photo or a generated scene: I⁻ through π, smoothly filled
            panorama = panorama_prior(inputs.scene, ws, inputs.i_minus, "observed")
    with t("composite"):
        composite = composite_refraction(image, panorama, ws)
        H, W = ws.camera.shape
        mask = np.where(ws.object_mask, np.where(ws.refraction_valid, 1.0, 0.5), 0.0)
        warp_rgb = warp_to_rgb(ws.refraction, W, H)
        for name, img in (
            ("I_minus", image),
            ("mask", mask),
            ("warp", warp_rgb),
            ("panorama", panorama),
            ("composite", composite),
        ):
            save_png(out / f"{name}.png", img)
        top = np.concatenate([image, composite], axis=1)
        bottom = np.concatenate([np.repeat(mask[..., None], 3, -1), warp_rgb], axis=1)
        save_png(out / "preview.png", np.concatenate([top, bottom], axis=0)[::2, ::2])
    summary = {
        "scene": OmegaConf.to_container(cfg.scene, resolve=True, enum_to_str=True),
        "object": {
            "name": obj.name,
            "ior": obj.ior,
            "center": obj.center.round(4).tolist(),
            "size": float(np.ptp(obj.vertices @ obj.up)),
        },
        "warps": ws.summary(),
        "warp_stats": ws.stats,
        "timings_s": {k: round(v, 3) for k, v in {**inputs.timings, **t.seconds}.items()},
    }
    write_json(out / "summary.json", summary)
    log.info("preview written to %s", out)
    print(
        f"refraction preview: {out}  ({summary['warps']['object_pixels']} object pixels, timings {summary['timings_s']})"
    )
    return summary
