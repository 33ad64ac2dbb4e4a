"""Stages 1-5: what every method of one (scene, variation, object) shares.

1. scene source: I⁻ (sRGB), its z-depth and camera, from a procedural scene, a photo or RGB-D
   frame (turned upright by its EXIF orientation, resized for ``scene.max_side``: what was done is
   the inputs' ``scene.info``, a cell's ``scene_info``), or generated from p⁻, with a depth
   estimator where needed (:func:`load_scene`);
2. where the object stands: the surface ``scene.surface`` names, segmented
   (:func:`surface_region`); the glass object, built from ``object.factory``
   (:func:`build_object`), placed on it (:func:`place`);
3. ray-traced warps (:func:`trace_warps`);
4. the reference render and its metric mask, by an independent renderer (:func:`render_reference`);
5. the true render of the full procedural scene with the object (:func:`render_true_scene`).

Every model a stage needs (a depth estimator, a segmenter, the generator of a generated I⁻) comes
from the :class:`~snell_bench.pipeline.pool.ModelPool` handed in, so a sweep loads each once.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
from hydra.errors import InstantiationException
from hydra.utils import instantiate
from omegaconf import DictConfig

from snell_bench.config import Source
from snell_bench.config.materials import absorption_coefficients
from snell_bench.models.segment import surface_region as segment_surface
from snell_bench.models.sizes import node_weights_bytes
from snell_bench.optics.warps import WarpSet, compute_warps
from snell_bench.pipeline.cell import CellInputs, Degenerate, build, cell_seed, kwargs_for, node_key, plain
from snell_bench.pipeline.degenerate import reference_problem, warps_problem
from snell_bench.pipeline.pool import ModelPool
from snell_bench.render import render_reference as render
from snell_bench.render import render_true
from snell_bench.scene import sources
from snell_bench.scene.image_source import load_frame, load_photo, photo_info
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.photo_size import fit_to_block
from snell_bench.scene.placement import place_object
from snell_bench.scene.resting import rest_on_surface
from snell_bench.scene.sources import SceneInputs
from snell_bench.utils.paths import data_path
from snell_bench.utils.tensors import hwc_to_bchw
from snell_bench.utils.timing import Timer

log = logging.getLogger(__name__)

__all__ = [
    "load_scene",
    "build_object",
    "surface_region",
    "place",
    "trace_warps",
    "render_reference",
    "render_true_scene",
    "prepare_inputs",
    "generator_of",
    "generate_i_minus",
]


# ---------------------------------------------------------------------------- 1. scene source
def generator_of(cfg: DictConfig, pool: ModelPool, build_it=None):
    """The generator of ``model.generator`` from the pool (``build_it``: how to build it, default
    ``instantiate(model.generator)``) and the seconds its load took."""
    return pool.get(
        "generator",
        node_key(cfg.model),
        build_it or (lambda: build(cfg.model.generator)),
        label=cfg.model.name,
        size=lambda: node_weights_bytes(cfg.model.generator),
    )


def _depth_estimator(cfg: DictConfig, pool: ModelPool, why: str):
    if not cfg.depth.get("estimator"):
        raise ValueError(
            f"{why}: choose a depth estimator (depth=moge2, depth=depth_pro, depth=depth_anything_v2) or give "
            "scene.depth"
        )
    return pool.get("depth", node_key(cfg.depth), lambda: build(cfg.depth.estimator), label=cfg.depth.name)[0]


def _up(sc: DictConfig) -> np.ndarray | None:
    return None if sc.up is None else np.asarray(list(sc.up), np.float64)


def _intrinsics(sc: DictConfig) -> list | None:
    return None if sc.intrinsics is None else list(sc.intrinsics)


def _procedural(cfg: DictConfig, pool: ModelPool) -> SceneInputs:
    sc = cfg.scene
    return sources.procedural_scene(
        sc.kind, sc.seed_offset + sc.variation, sc.width, sc.height, sc.supersample, _up(sc)
    )


def _max_side(sc: DictConfig) -> int | None:
    return sc.max_side


def _image(cfg: DictConfig, pool: ModelPool) -> SceneInputs:
    sc = cfg.scene
    image_file = data_path(sc.image, "scene.image", "image file")
    block = cfg.model.multiple
    if sc.depth:
        frame = load_frame(
            image_file,
            data_path(sc.depth, "scene.depth", "depth file"),
            depth_scale=sc.depth_scale,
            depth_kind=sc.depth_kind,
            intrinsics=_intrinsics(sc),
            fov_deg=sc.fov_deg,
            block=block,
            max_side=_max_side(sc),
        )
        return SceneInputs(
            image=frame.image, depth=frame.depth, camera=frame.camera, up=_up(sc), source=frame, info=frame.info
        )
    image, camera, header = load_photo(
        image_file, intrinsics=_intrinsics(sc), fov_deg=sc.fov_deg, max_side=_max_side(sc), block=block
    )
    resized = (image.shape[1], image.shape[0])
    k = None if camera is None else [camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2]]
    depth, camera = sources.estimate_depth(
        image, _depth_estimator(cfg, pool, "scene.depth is not set"), intrinsics=k, fov_deg=None
    )
    image, depth, camera = fit_to_block(image, depth, camera, block)
    info = photo_info(header, _max_side(sc), resized, (camera.width, camera.height))
    return SceneInputs(image=image, depth=depth, camera=camera, up=_up(sc), source="image", info=info)


def generate_i_minus(cfg: DictConfig, pool: ModelPool) -> tuple[np.ndarray, dict]:
    """I⁻ generated from p⁻ at the cell's seed by ``model.generator`` (cached by content in
    ``scene.cache_dir``; the generator is loaded only on a cache miss), and what the source
    records."""
    if cfg.model.from_scene:
        raise ValueError(
            f"scene.source=generated needs a text-to-image generator; model={cfg.model.name} is built from the "
            "scene itself: use model=tiny_flux (CPU, random weights) or model=flux_dev (GPU)"
        )
    sc = cfg.scene
    return sources.generated_image(
        lambda: generator_of(cfg, pool)[0],
        sc.prompt_minus,
        sc.height,
        sc.width,
        steps=sc.steps,
        seed=cell_seed(cfg),
        schedule=sc.schedule,
        cache_dir=sc.cache_dir,
        model_key=node_key(cfg.model),
    )


def _generated(cfg: DictConfig, pool: ModelPool) -> SceneInputs:
    sc = cfg.scene
    image, info = generate_i_minus(cfg, pool)
    depth, camera = sources.estimate_depth(
        image,
        _depth_estimator(cfg, pool, "scene.source=generated"),
        intrinsics=_intrinsics(sc),
        fov_deg=sc.fov_deg,
    )
    return SceneInputs(image=image, depth=depth, camera=camera, up=_up(sc), source="generated", info=info)


#: ``scene.source`` -> the loader of stage 1.
SOURCES = {Source.procedural: _procedural, Source.image: _image, Source.generated: _generated}


def load_scene(cfg: DictConfig, pool: ModelPool | None = None) -> SceneInputs:
    """Stage 1: I⁻, its depth and camera from ``scene.source`` (:data:`SOURCES`;
    :mod:`snell_bench.scene.sources`).

    Args:
        cfg: the cell's config (``scene``; ``model`` for the size rule and a generated I⁻;
            ``depth`` for an image without depth or a generated one).
        pool: where the depth estimator and a generator for I⁻ come from (a new pool if None).
    """
    return SOURCES[cfg.scene.source](cfg, ModelPool() if pool is None else pool)


# ---------------------------------------------------------------------------- 2. the object
def build_object(obj_cfg: DictConfig) -> GlassObject:
    """Stage 2a: the canonical (unplaced) object, ``instantiate(object.factory, ior=object.ior)``
    (with ``path=`` the resolved ``object.path`` for factories that read a file), of the material's
    absorption (``object.absorption``: σ per metre of the placed object)."""
    factory = obj_cfg.get("factory")
    if not factory or "_target_" not in factory:
        raise ValueError(
            f"object {obj_cfg.get('name')!r} has no object.factory._target_; choose an object (object=sphere) or set "
            "it, e.g. object.factory._target_=snell_bench.scene.objects.GlassObject.sphere"
        )
    kwargs: dict[str, Any] = {"ior": obj_cfg.ior}
    if "path" in factory:
        if not obj_cfg.path:
            raise ValueError(f"object {obj_cfg.name!r} reads a mesh file: set object.path")
        kwargs["path"] = data_path(obj_cfg.path, "object.path", "mesh file (.ply/.obj/.glb/.stl)")
        if obj_cfg.get("allow_self_intersecting") and "allow_self_intersecting" not in factory:
            kwargs["allow_self_intersecting"] = True  # a mesh reader's switch (GlassObject.from_file)
    try:
        obj = instantiate(factory, **kwargs)
    except InstantiationException as e:
        cause = e.__cause__
        if isinstance(cause, (ValueError, OSError)) and "path" in kwargs:
            raise type(cause)(f"object {obj_cfg.name!r} (object.path={obj_cfg.path!r}): {cause}") from None
        if isinstance(cause, (ValueError, OSError)):
            raise cause from None
        raise ValueError(f"object.factory._target_={factory['_target_']!r} failed: {cause or e}") from None
    sigma = absorption_coefficients(list(obj_cfg.absorption.color), obj_cfg.absorption.distance)
    return obj.with_absorption(sigma) if any(sigma) else obj


def surface_region(cfg: DictConfig, scene: SceneInputs, pool: ModelPool | None = None) -> np.ndarray | None:
    """Stage 2a: where the object may stand, ``(H, W)`` bool: the surface ``scene.surface`` names,
    segmented by ``segment.segmenter`` (SAM 3, a mask file; SAM 3's instances combined as
    ``segment.instance`` says, the mask carrying their box), or ``None`` (RANSAC near the image
    centre, the default)."""
    if not cfg.segment.get("segmenter"):
        return None
    phrase = cfg.scene.surface
    if not phrase:
        raise ValueError(
            f"segment={cfg.segment.name} needs the surface to find: set scene.surface (e.g. 'wooden table')"
        )
    pool = ModelPool() if pool is None else pool
    segmenter = pool.get(
        "segmenter", node_key(cfg.segment), lambda: build(cfg.segment.segmenter), label=cfg.segment.name
    )[0]
    return segment_surface(segmenter, scene.image, phrase, instance=str(cfg.segment.get("instance", "union")))


def place(obj: GlassObject, scene: SceneInputs, obj_cfg: DictConfig, seed: int = 0, region=None) -> GlassObject:
    """Stage 2b: ``obj`` standing on a supporting surface of the scene (``object.size``,
    ``object.relative_size``, ``object.yaw_deg``), inside ``region`` when given; ``object.anchor``:
    on a plane fitted there, or where the ray through the centre of the region's box meets the
    depth (the authors' rule); ``object.rest``: then lifted to stand on the surface under it."""
    anchor = str(obj_cfg.get("anchor", "plane"))
    kwargs: dict[str, Any] = {"seed": seed, "max_tilt_deg": float(obj_cfg.max_tilt_deg), "anchor": anchor}
    if scene.up is not None:
        kwargs["up_hint"] = scene.up
    if region is not None:
        kwargs["region"] = region
    try:
        placed = place_object(
            obj,
            scene.depth,
            scene.camera,
            size=obj_cfg.size,
            relative_size=float(obj_cfg.relative_size),
            yaw_deg=float(obj_cfg.yaw_deg),
            **kwargs,
        )
    except ValueError as e:
        if "surface" not in str(e) or region is not None or anchor != "plane":
            raise
        raise ValueError(
            f"placing object {obj_cfg.name!r}: {e}. The depth (scene.depth) must cover a horizontal surface near the "
            "image centre; for a tilted camera set scene.up (e.g. [0, -0.87, -0.5] for 30 degrees down) or widen "
            "object.max_tilt_deg"
        ) from None
    if obj_cfg.get("rest"):
        placed, lift = rest_on_surface(placed, scene.depth, scene.camera)
        log.info("object.rest: lifted %s by %.3g to stand on the surface under it", obj_cfg.name, lift)
    return placed


# ---------------------------------------------------------------------------- 3. warps
def trace_warps(scene: SceneInputs, obj: GlassObject, warps_cfg: DictConfig) -> WarpSet:
    """Stage 3: :func:`~snell_bench.optics.compute_warps` with every key of the ``warps`` node."""
    return compute_warps(scene.depth, scene.camera, obj, **kwargs_for(compute_warps, warps_cfg))


# ---------------------------------------------------------------------------- 4-5. references
def render_reference(cfg: DictConfig, scene: SceneInputs, obj: GlassObject, *, spp: int | None = None):
    """Stage 4: the reference render and metric mask, or ``(None, reason)``.

    ``reference.renderer``: ``mitsuba`` (one
    :class:`~snell_bench.render.reference_settings.ReferenceSettings` made of every key of the
    ``reference`` node that it has, ``spp`` replaced when given) or ``cycles`` (the authors'
    ``render_gt`` scene, ``cycles_spp`` samples; skipped, with the reason, where no Python with
    ``bpy`` is found: never another renderer instead). ``reference.ior`` replaces the object's IOR
    in the render and the mask. ``reference.mask``: ``unobserved`` (Mitsuba's unobserved pass; with
    ``cycles`` rendered at one sample per pixel for its mask only) or ``authors`` (the authors'
    ray-traced mask).
    """
    import dataclasses

    from snell_bench.render.authors_mask import authors_mask
    from snell_bench.render.cycles import CyclesUnavailable, render_cycles
    from snell_bench.render.reference_settings import ReferenceSettings
    from snell_bench.scene.depth_mesh import build_background

    rc = cfg.reference
    if not rc.enabled:
        return None, "reference.enabled=false"
    glass = obj if rc.get("ior") is None else dataclasses.replace(obj, ior=rc.ior, _cache={})
    edge = cfg.warps.edge_threshold
    renderer, mask_kind = str(rc.get("renderer", "mitsuba")), str(rc.get("mask", "unobserved"))
    mitsuba_spp = int(rc.spp if spp is None else spp)
    if renderer == "cycles" and mask_kind == "unobserved":
        mitsuba_spp = 1  # only the unobserved pass (the mask) is kept
    settings = ReferenceSettings(
        **kwargs_for(ReferenceSettings, rc, spp=mitsuba_spp, edge_threshold=edge, seed=cfg.seed)
    )
    if renderer == "cycles" and mitsuba_spp == 1:
        settings = dataclasses.replace(settings, self_noise=False)
    ref = None
    if renderer == "cycles":
        try:
            ref = render_cycles(
                scene.image,
                scene.depth,
                scene.camera,
                glass,
                spp=int(rc.cycles_spp if spp is None else spp),
                seed=cfg.seed,
                edge_threshold=edge,
                ior=None,
                blender_python=rc.get("blender_python"),
            )
        except CyclesUnavailable as e:
            reason = f"reference skipped: {e}"
            log.warning(reason)
            return None, reason
        if mask_kind == "authors":
            return ref, None
    try:  # Mitsuba is imported on the first render
        mitsuba = render(scene.image, scene.depth, scene.camera, glass, settings)
    except ImportError as e:
        reason = f"reference renderer unavailable ({e}); install the render extra: make setup EXTRAS=test,render"
        log.warning(reason)
        return None, reason
    if ref is not None:  # Cycles' image, Mitsuba's unobserved share and mask
        return dataclasses.replace(ref, unobserved=mitsuba.unobserved, mask=mitsuba.mask), None
    if mask_kind == "authors":
        bg = build_background(scene.depth, scene.camera, edge)
        mask, _ = authors_mask(scene.camera, (bg.vertices, bg.faces), (glass.vertices, glass.faces), ior=glass.ior)
        mitsuba = dataclasses.replace(mitsuba, mask=mask)
    return mitsuba, None


def render_true_scene(cfg: DictConfig, scene: SceneInputs, obj: GlassObject) -> np.ndarray | None:
    """Stage 5: the procedural scene rendered with the object (``reference.true_render``), or None."""
    if not (cfg.reference.true_render and cfg.scene.source is Source.procedural):
        return None
    bounces = cfg.reference.true_max_bounces or cfg.warps.get("recipe_max_bounces") or cfg.warps.max_bounces
    return render_true(
        scene.source, scene.camera, obj, spp=cfg.reference.true_spp, max_bounces=int(bounces), seed=cfg.seed
    )


def prepare_inputs(cfg: DictConfig, *, references: bool = True, pool: ModelPool | None = None) -> CellInputs:
    """Stages 1-5 for the scene, object, warps and reference settings of ``cfg``.

    Args:
        cfg: a composed config (the method's switches are not applied here: methods that change
            the warps get their own in :func:`~snell_bench.pipeline.run_method`).
        references: render the reference and the true render (stages 4 and 5).
        pool: the models to use (a new pool if None); the inputs keep it for their methods.

    Returns:
        The shared inputs, with ``timings`` for ``scene``, ``warps``, ``reference``, ``true_render``.
    """
    pool = ModelPool() if pool is None else pool
    t = Timer()
    loads = len(pool.loads)
    with t("scene"):
        scene = load_scene(cfg, pool)
        region = surface_region(cfg, scene, pool)
        obj = place(build_object(cfg.object), scene, cfg.object, seed=cfg.seed, region=region)
    # a generator loaded to generate I⁻ is reported as "generator" (by every method that uses it)
    t.seconds["scene"] -= sum(x.seconds for x in pool.loads[loads:] if x.kind == "generator")
    with t("warps"):
        ws = trace_warps(scene, obj, cfg.warps)
    if not ws.object_mask.any():
        raise ValueError(
            f"object {cfg.object.name!r} covers no pixel of the {scene.camera.width}x{scene.camera.height} image "
            f"(object.size={cfg.object.size}, object.relative_size={cfg.object.relative_size}): nothing to trace or "
            "score; make it larger (object.size, object.relative_size) or the image larger (scene.width, scene.height)"
        )
    if (problem := warps_problem(ws, cfg.warps.max_bounces)) is not None:
        raise Degenerate(problem)
    reference, reason, true = None, "not rendered", None
    if references:
        with t("reference"):
            reference, reason = render_reference(cfg, scene, obj)
        if (problem := reference_problem(reference)) is not None:
            raise Degenerate(problem)
        with t("true_render"):
            true = render_true_scene(cfg, scene, obj)
    return CellInputs(
        scene=scene,
        obj=obj,
        warps=ws,
        warps_config=plain(cfg.warps),
        i_minus=hwc_to_bchw(scene.image),
        reference=reference,
        reference_reason=reason,
        true_render=true,
        timings=t.seconds,
        pool=pool,
    )
