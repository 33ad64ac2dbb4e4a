"""From config to the inputs every method shares: I⁻, its depth and camera, the placed object."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from snell_bench.scene.camera import Camera
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.placement import place_object

log = logging.getLogger(__name__)

__all__ = ["SceneInputs", "make_scene_inputs", "make_object", "place_from_config", "warps_from_config", "scene_panorama",
           "make_generator", "apply_method"]

_REPO = Path(__file__).resolve().parents[2]


@dataclass
class SceneInputs:
    image: np.ndarray  # (H, W, 3) float32 sRGB in [0, 1]: I⁻
    depth: np.ndarray  # (H, W) float32 z-depth
    camera: Camera
    up: np.ndarray | None  # scene up in camera coordinates, if the source knows it
    source: object  # the scene source (e.g. a ProceduralScene), for panoramas and ground truth


def make_scene_inputs(scene_cfg: DictConfig) -> SceneInputs:
    if scene_cfg.source != "procedural":
        raise ValueError(
            f"scene.source={scene_cfg.source!r} is not available yet; use scene.source=procedural"
        )
    from snell_bench.scene.procedural import ProceduralScene

    scene = ProceduralScene(kind=scene_cfg.kind, seed=int(scene_cfg.seed_offset) + int(scene_cfg.variation))
    r = scene.render(width=int(scene_cfg.width), height=int(scene_cfg.height), supersample=int(scene_cfg.supersample))
    return SceneInputs(image=r.image, depth=r.depth, camera=r.camera, up=scene.up, source=scene)


def make_object(obj_cfg: DictConfig) -> GlassObject:
    """The canonical (unplaced) object a config names."""
    shape = obj_cfg.shape
    if shape == "sphere":
        return GlassObject.sphere(ior=obj_cfg.ior)
    if shape == "cylinder":
        return GlassObject.cylinder(ior=obj_cfg.ior)
    if shape == "pyramid":
        return GlassObject.pyramid(ior=obj_cfg.ior)
    if shape == "mesh":
        if not obj_cfg.path:
            raise ValueError(f"object {obj_cfg.name!r}: shape=mesh needs object.path (a mesh file)")
        path = Path(obj_cfg.path)
        if not path.is_absolute() and not path.exists():
            path = _REPO / path
        if not path.is_file():
            raise FileNotFoundError(
                f"object {obj_cfg.name!r}: mesh file {obj_cfg.path!r} not found; set object.path to an existing "
                ".ply/.obj/.glb/.stl file"
            )
        obj = GlassObject.from_file(path, ior=obj_cfg.ior, up_axis=obj_cfg.up_axis)
        return obj
    raise ValueError(f"object.shape={shape!r} is unknown; use sphere, cylinder, pyramid or mesh")


def place_from_config(obj: GlassObject, inputs: SceneInputs, obj_cfg: DictConfig, seed: int = 0) -> GlassObject:
    kwargs = {"seed": seed}
    if inputs.up is not None:
        kwargs["up_hint"] = inputs.up
    return place_object(
        obj,
        inputs.depth,
        inputs.camera,
        size=obj_cfg.size,
        relative_size=float(obj_cfg.relative_size),
        yaw_deg=float(obj_cfg.yaw_deg),
        **kwargs,
    )


def apply_method(cfg: DictConfig) -> DictConfig:
    """``cfg`` with its method's switches (``method.sampler``, ``method.warps``, conf/method/) merged
    over the ``sampler`` and ``warps`` nodes; ``cfg`` itself is left unchanged."""
    from omegaconf import OmegaConf

    c = OmegaConf.create(OmegaConf.to_container(cfg, resolve=False))
    OmegaConf.set_struct(c, False)
    method = c.get("method") or {}
    c.sampler = OmegaConf.merge(c.sampler, method.get("sampler") or {})
    c.warps = OmegaConf.merge(c.warps, method.get("warps") or {})
    return c


def warps_from_config(inputs: SceneInputs, obj: GlassObject, warps_cfg: DictConfig):
    """:func:`~snell_bench.optics.compute_warps` with the ``warps`` node of a config."""
    from snell_bench.optics.warps import compute_warps

    w = warps_cfg
    return compute_warps(
        inputs.depth,
        inputs.camera,
        obj,
        pano_height=int(w.pano_height),
        max_bounces=int(w.max_bounces),
        normals=str(w.normals),
        edge_threshold=float(w.edge_threshold),
        cache_dir=w.cache_dir,
        roi=bool(w.get("roi", True)),
        infinity_tolerance_px=w.get("infinity_tolerance_px"),
    )


def scene_panorama(inputs: SceneInputs, pano, supersample: int = 1) -> np.ndarray:
    """The source's true panorama seen by a :class:`~snell_bench.imaging.PanoramaCamera` (sRGB)."""
    if not hasattr(inputs.source, "render_panorama"):
        raise ValueError("this scene source cannot render panoramas")
    return inputs.source.render_panorama(
        center=pano.center,
        height=pano.height,
        up=-pano.rotation[:, 1],
        forward=pano.rotation[:, 2],
        supersample=supersample,
    )


def make_generator(model_cfg: DictConfig, inputs: SceneInputs, warps):
    """The generator a config names. The analytic backend is built from the scene: its main prior
    is I⁻ with a wrong glass blob in the object, its panorama prior the true panorama."""
    name = model_cfg.name
    if name == "analytic":
        from snell_bench.models.analytic import AnalyticGenerator

        pano = scene_panorama(inputs, warps.pano)
        return AnalyticGenerator.from_scene(
            inputs.image,
            warps.object_mask,
            pano,
            prior_std=float(model_cfg.prior_std),
            glass_std=float(model_cfg.glass_std),
            seed=int(model_cfg.seed),
        )
    from snell_bench.models import build_generator

    if name == "tiny_flux":
        return build_generator("tiny_flux", seed=int(model_cfg.seed))
    if name in ("flux", "flux_dev"):
        kwargs = {"guidance": float(model_cfg.guidance), "vae_tiling": bool(model_cfg.vae_tiling)}
        if model_cfg.device:
            kwargs["device"] = model_cfg.device
        if model_cfg.dtype:
            import torch

            kwargs["dtype"] = getattr(torch, model_cfg.dtype)
        return build_generator("flux", model_id_or_path=model_cfg.path or "black-forest-labs/FLUX.1-dev", **kwargs)
    raise ValueError(f"model.name={name!r} is unknown; use analytic, tiny_flux or flux")
