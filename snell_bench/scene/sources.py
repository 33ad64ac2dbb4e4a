"""Scene sources: where I⁻, its depth and the camera come from.

- ``procedural``: a :class:`~snell_bench.scene.procedural.ProceduralScene` (CPU, exact 3-D truth);
- ``image``: a user's photo or RGB-D frame (:mod:`snell_bench.scene.image_source`), its depth from
  a file or a monocular depth estimator;
- ``generated``: I⁻ generated from the object-free prompt p⁻ by the configured generator at the
  cell's seed (the paper's setting), its depth and intrinsics from a depth estimator.

Convention: I⁻ ``(H, W, 3)`` float32 sRGB in [0, 1]; depth ``(H, W)`` float32 camera-frame z in
metres, NaN where unknown (unobserved space); the camera in the OpenCV frame with K in pixels.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from snell_bench.config.choices import PanoPrior
from snell_bench.scene.camera import Camera
from snell_bench.utils.io import json_hash, save_npy, save_png, write_json
from snell_bench.utils.tensors import bchw_to_hwc

log = logging.getLogger(__name__)

__all__ = ["SceneInputs", "procedural_scene", "estimate_depth", "generated_image", "scene_panorama", "panorama_prior"]


@dataclass
class SceneInputs:
    """What a scene source gives: I⁻, its depth and camera."""

    image: np.ndarray  #: (H, W, 3) float32 sRGB in [0, 1]: I⁻
    depth: np.ndarray  #: (H, W) float32 camera-frame z, NaN where unknown
    camera: Camera
    up: np.ndarray | None  #: scene up in camera coordinates, if known
    source: Any  #: the source object (a ProceduralScene, an RGBDFrame, ...), for panoramas and truth
    #: what a generated source recorded (seed, prompt, cache file, generator build time)
    info: dict = field(default_factory=dict)


def procedural_scene(
    kind: str, seed: int, width: int, height: int, supersample: int = 1, up: np.ndarray | None = None
) -> SceneInputs:
    """A procedural scene rendered at ``width x height``; its exact depth and camera."""
    from snell_bench.scene.procedural import ProceduralScene

    scene = ProceduralScene(kind=kind, seed=int(seed))
    r = scene.render(width=int(width), height=int(height), supersample=int(supersample))
    return SceneInputs(image=r.image, depth=r.depth, camera=r.camera, up=scene.up if up is None else up, source=scene)


def estimate_depth(
    image: np.ndarray, estimator: Callable, *, intrinsics=None, fov_deg: float | None = None
) -> tuple[np.ndarray, Camera]:
    """Metric depth and the camera of ``image`` from a depth estimator.

    Args:
        image: ``(H, W, 3)`` sRGB.
        estimator: a :class:`~snell_bench.models.depth.DepthEstimator` (returns ``depth`` in metres
            and, for models that estimate it, ``intrinsics`` ``(fx, fy, cx, cy)``).
        intrinsics: ``[fx, fy, cx, cy]`` that override the estimator's (``scene.intrinsics``).
        fov_deg: a horizontal field of view that overrides them (``scene.fov_deg``).

    Returns:
        ``(depth, camera)``.

    Raises:
        ValueError: no intrinsics (neither given nor estimated) or no valid depth.
    """
    from snell_bench.scene.photo_camera import camera_from

    H, W = image.shape[:2]
    est = estimator(image)
    depth = np.asarray(est.depth, np.float32)
    if depth.shape != (H, W):
        raise ValueError(f"the depth estimator returned shape {depth.shape} for an image of {(H, W)}")
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)
    if not np.isfinite(depth).any():
        raise ValueError("the depth estimator gave no valid depth; check depth.path (the weights) or give scene.depth")
    if intrinsics is None and fov_deg is None:
        if est.intrinsics is None:
            raise ValueError(
                f"depth estimator {getattr(estimator, 'name', estimator)!r} does not estimate intrinsics: set "
                "scene.fov_deg or scene.intrinsics"
            )
        intrinsics = list(est.intrinsics)
    return depth, camera_from(W, H, intrinsics=intrinsics, fov_deg=fov_deg)


def _cache_key(meta: dict) -> str:
    return json_hash(meta)


def generated_image(
    build: Callable[[], Any],
    prompt: str,
    height: int,
    width: int,
    *,
    steps: int,
    seed: int,
    schedule: str = "flux",
    cache_dir: str | Path | None = None,
    model_key: str = "",
) -> tuple[np.ndarray, dict]:
    """I⁻ generated from ``prompt`` (p⁻) at ``seed``, cached by content.

    Args:
        build: returns the generator (called only on a cache miss).
        prompt: the object-free prompt p⁻.
        height: image height (a multiple of the generator's block).
        width: image width.
        steps: denoising steps.
        seed: the seed (the paper: variation = seed; the baselines reuse it).
        schedule: the noise schedule's kind.
        cache_dir: where generated images are kept (``None``: no cache); a file that cannot be
            read is a miss.
        model_key: what identifies the generator (its resolved config) in the cache key.

    Returns:
        ``(image (H, W, 3) float32 sRGB, info)`` with ``seed``, ``prompt``, ``cache`` (the file or
        ``None``), ``cached`` (whether it was read from the cache) and ``initial_noise`` (the digest
        of the initial noise it was generated from: the synchronised sampler of the same seed draws
        the same, which its own record shows).
    """
    meta = {
        "prompt": prompt,
        "height": int(height),
        "width": int(width),
        "steps": int(steps),
        "seed": int(seed),
        "schedule": schedule,
        "model": model_key,
    }
    info = {"seed": int(seed), "prompt": prompt, "cache": None, "cached": False}
    path = None
    if cache_dir is not None:
        folder = Path(cache_dir) / _cache_key(meta)
        path = folder / "I_minus.npy"
        info["cache"] = str(path)
        if path.is_file():
            try:
                image = np.load(path)
                if image.shape == (int(height), int(width), 3):
                    noise = _cached_noise(path.with_name("meta.json"))
                    return image.astype(np.float32), dict(info, cached=True, **noise)
            except (OSError, ValueError) as e:
                log.warning("generated scene cache %s unreadable (%s): generating again", path, e)
    from snell_bench.sampler.text_to_image import text_to_image

    model = build()
    drawn: dict = {}
    image = bchw_to_hwc(
        text_to_image(model, prompt, int(height), int(width), steps=steps, seed=seed, schedule=schedule, record=drawn)
    ).astype(np.float32)
    info.update(drawn)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        save_npy(path, image)
        save_png(path.with_suffix(".png"), image)
        write_json(path.with_name("meta.json"), {**meta, **drawn})
    return image, info


def _cached_noise(meta_path: Path) -> dict:
    """``initial_noise`` of a cached I⁻ as its generation recorded it (``{}`` for an older cache)."""
    try:
        value = json.loads(meta_path.read_text()).get("initial_noise")
    except (OSError, ValueError, AttributeError):
        return {}
    return {"initial_noise": value} if isinstance(value, str) else {}


def scene_panorama(scene: SceneInputs, pano, supersample: int = 1) -> np.ndarray:
    """The source's true panorama seen by a :class:`~snell_bench.imaging.PanoramaCamera` (sRGB)."""
    if not hasattr(scene.source, "render_panorama"):
        raise ValueError("this scene source cannot render panoramas")
    return scene.source.render_panorama(
        center=pano.center,
        height=pano.height,
        up=-pano.rotation[:, 1],
        forward=pano.rotation[:, 2],
        supersample=supersample,
    )


#: The kinds of panorama prior :func:`panorama_prior` builds (config key ``model.pano_prior``).
PANO_PRIORS = PanoPrior.values()
#: ``pano_prior="other"``: the procedural seed of the other variation is the scene's plus this.
OTHER_VARIATION_OFFSET = 1000


def panorama_prior(scene: SceneInputs, warps, i_minus, kind: str = "other") -> np.ndarray:
    """The panorama a generator built from the scene starts from, ``(Hp, 2 Hp, 3)`` sRGB.

    Kinds (config key ``model.pano_prior``):
        - ``other``: the true panorama of another variation of the same procedural scene kind
          (seed + :data:`OTHER_VARIATION_OFFSET`), seen from the same pose: a plausible room that
          is wrong everywhere, which only synchronisation with I⁻ through π corrects;
        - ``blur``: the scene's true panorama blurred (a Gaussian of ``Hp / 32`` pixels, periodic
          in x): right in colour and layout, wrong in detail;
        - ``truth``: the scene's true panorama (the ground truth of every surface I⁻ does not show);
        - ``observed``: I⁻ seen from the object through π where I⁻ observes the panorama's rays,
          smoothly filled elsewhere (:func:`~snell_bench.imaging.fill.push_pull_fill`): nothing but
          I⁻ is used. Sources that cannot render a panorama (photos, RGB-D frames, generated
          scenes) always get this one.

    Args:
        scene: the scene's inputs.
        warps: its :class:`~snell_bench.optics.warps.WarpSet` (π and the panorama camera).
        i_minus: I⁻ as a ``(1, 3, H, W)`` tensor.
        kind: one of :data:`PANO_PRIORS`.

    Raises:
        ValueError: for an unknown kind.
    """
    if kind not in PANO_PRIORS:
        raise ValueError(f"model.pano_prior={kind!r} is unknown; use one of {PANO_PRIORS}")
    if kind != "observed" and hasattr(scene.source, "render_panorama"):
        if kind == "other":
            src = scene.source
            other = type(src)(kind=src.kind, seed=int(src.seed) + OTHER_VARIATION_OFFSET)
            pano = warps.pano
            return other.render_panorama(
                center=pano.center, height=pano.height, up=-pano.rotation[:, 1], forward=pano.rotation[:, 2]
            )
        true = scene_panorama(scene, warps.pano)
        if kind == "blur":
            from scipy.ndimage import gaussian_filter1d

            sigma = true.shape[0] / 32
            out = gaussian_filter1d(true, sigma, axis=0, mode="nearest")
            return gaussian_filter1d(out, sigma, axis=1, mode="wrap").astype(np.float32)
        return true
    import torch

    from snell_bench.imaging.fill import push_pull_fill
    from snell_bench.imaging.remap import remap
    from snell_bench.utils.tensors import bchw_to_hwc

    seen, _ = remap(i_minus, warps.pano_to_persp)
    known = torch.from_numpy(warps.pano_to_persp_valid & np.isfinite(warps.pano_to_persp).all(-1))
    return bchw_to_hwc(push_pull_fill(torch.nan_to_num(seen), known, wrap_x=True)).clip(0, 1)
