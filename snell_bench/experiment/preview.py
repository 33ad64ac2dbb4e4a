"""The refraction preview: what Snell's law alone says the glass object must show.

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

import json
import logging
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from PIL import Image

from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear
from snell_bench.imaging.remap import remap
from snell_bench.optics.warps import WarpSet

log = logging.getLogger(__name__)

__all__ = ["run_preview", "composite_refraction", "warp_to_rgb", "save_png"]


def save_png(path: Path, image: np.ndarray) -> None:
    """Save a float image in [0, 1] ``(H, W)`` or ``(H, W, 3)`` as 8-bit PNG (atomic rename)."""
    arr = np.clip(np.rint(np.asarray(image, np.float64) * 255.0), 0, 255).astype(np.uint8)
    tmp = path.with_name(path.name + ".tmp.png")
    Image.fromarray(arr).save(tmp)
    tmp.replace(path)


def _to_tensor(img: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(img, np.float32)).permute(2, 0, 1)[None]


def _to_numpy(t: torch.Tensor) -> np.ndarray:
    return t[0].permute(1, 2, 0).numpy()


def composite_refraction(i_minus: np.ndarray, panorama: np.ndarray, ws: WarpSet) -> np.ndarray:
    """The physically composited glass: ``(H, W, 3)`` sRGB in [0, 1] (see the module docs)."""
    im = _to_tensor(i_minus)
    pano = _to_tensor(panorama)
    refr, _ = remap(im, ws.refraction)
    refr_pano, ok_p = remap(pano, ws.pano_refraction, wrap_x=True)
    refl, _ = remap(pano, ws.pano_reflection, wrap_x=True)
    valid = torch.from_numpy(ws.refraction_valid)[None, None]
    c_refr = torch.where(valid, srgb_to_linear(refr), srgb_to_linear(refr_pano))
    c_refl = srgb_to_linear(refl)
    R = torch.from_numpy(ws.fresnel)[None, None]
    c = R * (c_refl - c_refr) + c_refr
    mask = torch.from_numpy(ws.object_mask)[None, None]
    out = torch.where(mask, linear_to_srgb(c), im)
    return _to_numpy(out)


def warp_to_rgb(coords: np.ndarray, width: int, height: int) -> np.ndarray:
    """Source coordinates as colours: red = x / (W - 1), green = y / (H - 1), blue = 0.5; NaN black."""
    rgb = np.zeros(coords.shape[:2] + (3,), np.float32)
    ok = np.isfinite(coords).all(-1)
    rgb[..., 0] = np.where(ok, coords[..., 0] / max(width - 1, 1), 0)
    rgb[..., 1] = np.where(ok, coords[..., 1] / max(height - 1, 1), 0)
    rgb[..., 2] = np.where(ok, 0.5, 0)
    return np.clip(rgb, 0, 1)


def run_preview(cfg: DictConfig) -> dict:
    from snell_bench.experiment.inputs import (
        make_object,
        make_scene_inputs,
        place_from_config,
        scene_panorama,
        warps_from_config,
    )

    out = Path(cfg.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    timings = {}
    t0 = time.perf_counter()
    inputs = make_scene_inputs(cfg.scene)
    timings["scene"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    obj = place_from_config(make_object(cfg.object), inputs, cfg.object, seed=int(cfg.seed))
    timings["placement"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    ws = warps_from_config(inputs, obj, cfg.warps)
    timings["warps"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    # the source's true panorama, in the orientation of the warps' panorama camera
    panorama = scene_panorama(inputs, ws.pano, supersample=int(cfg.scene.supersample))
    timings["panorama"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    composite = composite_refraction(inputs.image, panorama, ws)
    H, W = ws.camera.shape
    mask = np.where(ws.object_mask, np.where(ws.refraction_valid, 1.0, 0.5), 0.0)
    warp_rgb = warp_to_rgb(ws.refraction, W, H)
    save_png(out / "I_minus.png", inputs.image)
    save_png(out / "mask.png", mask)
    save_png(out / "warp.png", warp_rgb)
    save_png(out / "panorama.png", panorama)
    save_png(out / "composite.png", composite)
    top = np.concatenate([inputs.image, composite], axis=1)
    bottom = np.concatenate([np.repeat(mask[..., None], 3, -1), warp_rgb], axis=1)
    save_png(out / "preview.png", np.concatenate([top, bottom], axis=0)[::2, ::2])
    timings["composite"] = time.perf_counter() - t0

    summary = {
        "scene": OmegaConf.to_container(cfg.scene),
        "object": {"name": obj.name, "ior": obj.ior, "center": obj.center.round(4).tolist(), "size": float(np.ptp(obj.vertices @ obj.up))},
        "warps": ws.summary(),
        "warp_stats": ws.stats,
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    log.info("preview written to %s", out)
    print(f"refraction preview: {out}  ({summary['warps']['object_pixels']} object pixels, timings {summary['timings_s']})")
    return summary
