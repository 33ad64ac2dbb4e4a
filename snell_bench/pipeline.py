"""The Snellcaster pipeline: every stage from a config to a scored image, in order.

Every job (``preview``, ``generate``, the experiment grid and the speed/accuracy sweep) calls
these two functions and wires no stage itself::

    inputs = prepare_inputs(cfg)           # 1-5: what every method of a (scene, object) shares
    result = run_method(cfg, inputs)       # 6-8: one method's image, scored

1. scene source: I⁻ (sRGB), its z-depth and camera, from a procedural scene, a photo or RGB-D
   frame, or generated from p⁻, with a depth estimator where needed (:func:`load_scene`);
2. where the object stands: the surface ``scene.surface`` names, segmented
   (:func:`surface_region`); the glass object, built from ``object.factory``
   (:func:`build_object`), placed on it (:func:`place`);
3. ray-traced warps (:func:`trace_warps`);
4. the reference render and its metric mask, by an independent renderer (:func:`render_reference`);
5. the true render of the full procedural scene with the object (:func:`render_true_scene`);
6. the generator, built from ``model.generator`` once per inputs (:func:`build_generator`);
7. sampling with the method's settings (:func:`sample_method`): the synchronized sampler, the
   generator alone, or a diffusers pipeline baseline (another text-to-image model, FLUX Fill);
   7b. relighting (``method.relight``): N candidates from the model's relighter, the one closest to
   the un-relit image inside the object kept (:func:`relight_image`);
8. masked metrics against the reference (:func:`score`).

Conventions: images handed between stages are ``(1, 3, H, W)`` float32 sRGB tensors in [0, 1]
(``CellInputs.i_minus``, ``CellResult.image``) or ``(H, W, 3)`` numpy arrays where a stage
works in numpy (``SceneInputs.image``, references); depth is camera-frame z in metres (NaN: unknown);
the camera frame is OpenCV's. Stage times are wall seconds in ``timings`` (one
:class:`~snell_bench.utils.timing.Timer` per call), keyed ``scene``, ``warps``, ``reference``,
``true_render`` (inputs) and ``generator``, ``sampling``, ``relighter``, ``relight``, ``metrics``
(a method).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from snell_bench.optics.warps import WarpSet
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.sources import SceneInputs
from snell_bench.utils.tensors import hwc_to_bchw
from snell_bench.utils.timing import Timer

log = logging.getLogger(__name__)

__all__ = [
    "SceneInputs",
    "CellInputs",
    "CellResult",
    "Skip",
    "apply_method",
    "full_prompt",
    "object_phrase",
    "prompt_of",
    "cell_seed",
    "data_path",
    "load_scene",
    "build_object",
    "surface_region",
    "place",
    "trace_warps",
    "render_reference",
    "render_true_scene",
    "build_generator",
    "sample_method",
    "relight_image",
    "relight_prompt",
    "score",
    "prepare_inputs",
    "run_method",
    "cached_generator",
]

#: The checkout's root (``datasets/`` is found there when a relative mesh path is not found in the
#: working folder).
_CHECKOUT = Path(__file__).resolve().parents[1]


class Skip(Exception):
    """A method that cannot run here; the message says why."""


@dataclass
class CellInputs:
    """Everything the methods of one (scene, variation, object) share."""

    scene: SceneInputs
    obj: GlassObject  #: placed, in the camera frame
    warps: WarpSet
    warps_config: dict  #: the resolved ``warps`` node the warps were traced with
    i_minus: torch.Tensor  #: (1, 3, H, W) float32 sRGB
    reference: Any = None  #: a ReferenceRender (image, mask, unobserved) or None
    reference_reason: str | None = None  #: why there is no reference
    true_render: np.ndarray | None = None  #: (H, W, 3) sRGB, procedural scenes only
    timings: dict = field(default_factory=dict)
    #: generators built on these inputs, by model config (built once, shared by methods)
    generators: dict = field(default_factory=dict, repr=False)


@dataclass
class CellResult:
    """One method's output on one :class:`CellInputs`."""

    image: torch.Tensor  #: (1, 3, H, W) float32 sRGB
    panorama: torch.Tensor | None = None  #: (1, 3, h, 2h) or None
    stats: dict = field(default_factory=dict)  #: model_calls, sampler_timings_s, decisions
    dumps: list = field(default_factory=list)  #: intermediate estimates (sampler.dump_every)
    scores: dict = field(default_factory=dict)  #: {"metrics": ..., "missing": ...} when scored
    timings: dict = field(default_factory=dict)
    warps: WarpSet | None = None  #: the warps the method used
    unrelit: torch.Tensor | None = None  #: the image before relighting (``method.relight``)


# ---------------------------------------------------------------------------- config helpers
def apply_method(cfg: DictConfig) -> DictConfig:
    """A copy of ``cfg`` with its method's switches (``method.sampler``, ``method.warps``) merged
    over the ``sampler`` and ``warps`` nodes, keeping their structured schema (an unknown key is
    an error); ``cfg`` itself is unchanged. Idempotent."""
    c = cfg.copy()
    c.sampler = OmegaConf.merge(c.sampler, c.method.sampler or {})
    c.warps = OmegaConf.merge(c.warps, c.method.warps or {})
    return c


def cell_seed(cfg: DictConfig) -> int:
    """The seed of a cell's sampling: ``seed + scene.variation`` (a generated I⁻ uses the same one,
    so every method of the cell, the baselines included, starts from the seed of its scene)."""
    return int(cfg.seed) + int(cfg.scene.variation)


def full_prompt(cfg: DictConfig) -> str:
    """The full prompt p of a config, ``{object}`` replaced by the object's noun."""
    return str(cfg.scene.prompt).replace("{object}", str(cfg.object.noun))


def object_phrase(cfg: DictConfig) -> str:
    """The object phrase p_obj of a config (``"a big glass sphere"``), ``{object}`` replaced."""
    return str(cfg.scene.object_phrase).replace("{object}", str(cfg.object.noun))


#: What ``method.prompt`` and ``metrics.clip_text`` may name.
PROMPT_KINDS = ("full", "object")


def prompt_of(cfg: DictConfig, kind: str, key: str) -> str:
    """The full prompt (``kind="full"``) or the object phrase (``"object"``); ``key`` names the
    config key in the error for any other value."""
    if kind == "full":
        return full_prompt(cfg)
    if kind == "object":
        return object_phrase(cfg)
    raise ValueError(f"{key}={kind!r} is unknown; use one of {PROMPT_KINDS}")


def _plain(node) -> Any:
    return OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else node


# ---------------------------------------------------------------------------- 1. scene source
def data_path(value: str, key: str, what: str = "file") -> str:
    """A file a config names: as given (absolute or relative to the working folder), else relative
    to the checkout (where ``datasets/`` lies). Raises ``FileNotFoundError`` naming ``key``."""
    path = Path(str(value))
    if not path.is_absolute() and not path.exists():
        path = _CHECKOUT / path
    if path.is_dir():
        inside = sorted(p.name for p in path.iterdir() if p.is_file() and not p.name.startswith("."))[:5]
        raise IsADirectoryError(
            f"{key}={str(value)!r} is a folder, not a {what}; set {key} to a file"
            + (f" (it holds {', '.join(inside)}{', ...' if len(inside) == 5 else ''})" if inside else "")
        )
    if not path.is_file():
        raise FileNotFoundError(f"{key}={str(value)!r}: no such {what}; set {key} to an existing {what}")
    return str(path)


def _model_key(model_cfg: DictConfig) -> str:
    return OmegaConf.to_yaml(model_cfg, resolve=True)


def _depth_estimator(cfg: DictConfig, why: str):
    if not cfg.depth.get("estimator"):
        raise ValueError(
            f"{why}: choose a depth estimator (depth=moge2, depth=depth_pro, depth=depth_anything_v2) or give "
            "scene.depth"
        )
    return _instantiate(cfg.depth.estimator)


def load_scene(cfg: DictConfig, generators: dict | None = None) -> SceneInputs:
    """Stage 1: I⁻, its depth and camera from ``scene.source`` (``procedural``, ``image``,
    ``generated``; :mod:`snell_bench.scene.sources`).

    Args:
        cfg: the cell's config (``scene``; ``model`` for the size rule and a generated I⁻;
            ``depth`` for an image without depth or a generated one).
        generators: where a generator built to generate I⁻ is kept for stage 6 (by model config).
    """
    from snell_bench.scene import sources

    sc = cfg.scene
    src = sc.source
    up = None if sc.up is None else np.asarray(list(sc.up), np.float64)
    intrinsics = None if sc.intrinsics is None else list(sc.intrinsics)
    if src == "procedural":
        return sources.procedural_scene(
            sc.kind, int(sc.seed_offset) + int(sc.variation), sc.width, sc.height, sc.supersample, up
        )
    if src == "image":
        from snell_bench.scene.image_source import fit_to_block, load_frame

        if not sc.image:
            raise ValueError("scene.source=image needs scene.image (a PNG or JPEG file of the object-free scene)")
        if sc.depth:
            frame = load_frame(
                data_path(sc.image, "scene.image", "image file"),
                data_path(sc.depth, "scene.depth", "depth file"),
                depth_scale=sc.depth_scale,
                depth_kind=str(sc.depth_kind),
                intrinsics=intrinsics,
                fov_deg=sc.fov_deg,
                block=int(cfg.model.multiple),
            )
            return SceneInputs(image=frame.image, depth=frame.depth, camera=frame.camera, up=up, source=frame)
        from snell_bench.scene.image_source import load_image

        image = load_image(data_path(sc.image, "scene.image", "image file"))
        depth, camera = sources.estimate_depth(
            image, _depth_estimator(cfg, "scene.depth is not set"), intrinsics=intrinsics, fov_deg=sc.fov_deg
        )
        image, depth, camera = fit_to_block(image, depth, camera, int(cfg.model.multiple))
        return SceneInputs(image=image, depth=depth, camera=camera, up=up, source="image")
    if src == "generated":
        if cfg.model.from_scene:
            raise ValueError(
                f"scene.source=generated needs a text-to-image generator; model={cfg.model.name} is built from the "
                "scene itself: use model=tiny_flux (CPU, random weights) or model=flux_dev (GPU)"
            )
        generators = {} if generators is None else generators

        def build():
            return cached_generator(cfg.model, generators, lambda: _instantiate(cfg.model.generator))[0]

        image, info = sources.generated_image(
            build,
            str(sc.prompt_minus),
            int(sc.height),
            int(sc.width),
            steps=int(sc.steps),
            seed=cell_seed(cfg),
            schedule=str(sc.schedule),
            cache_dir=sc.cache_dir,
            model_key=_model_key(cfg.model),
        )
        depth, camera = sources.estimate_depth(
            image, _depth_estimator(cfg, "scene.source=generated"), intrinsics=intrinsics, fov_deg=sc.fov_deg
        )
        return SceneInputs(image=image, depth=depth, camera=camera, up=up, source="generated", info=info)
    raise ValueError(f"scene.source={src!r} is unknown; use procedural, image or generated")


# ---------------------------------------------------------------------------- 2. the object
def _mesh_path(obj_cfg: DictConfig) -> str:
    return data_path(obj_cfg.path, "object.path", "mesh file (.ply/.obj/.glb/.stl)")


def build_object(obj_cfg: DictConfig) -> GlassObject:
    """Stage 2a: the canonical (unplaced) object, ``instantiate(object.factory, ior=object.ior)``
    (with ``path=`` the resolved ``object.path`` for factories that read a file)."""
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate

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
        kwargs["path"] = _mesh_path(obj_cfg)
    try:
        return instantiate(factory, **kwargs)
    except InstantiationException as e:
        cause = e.__cause__
        if isinstance(cause, (ValueError, OSError)) and "path" in kwargs:
            raise type(cause)(f"object {obj_cfg.name!r} (object.path={str(obj_cfg.path)!r}): {cause}") from None
        if isinstance(cause, (ValueError, OSError)):
            raise cause from None
        raise ValueError(f"object.factory._target_={factory['_target_']!r} failed: {cause or e}") from None


#: Segmenters built in this process, by their resolved config (a real SAM 3 is large: built once).
_SEGMENTERS: dict[str, Any] = {}


def _instantiate(node: DictConfig):
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate

    try:
        return instantiate(node)
    except InstantiationException as e:  # the constructor's own error (missing weights, no GPU, bad file)
        raise (e.__cause__ or e) from None


def surface_region(cfg: DictConfig, scene: SceneInputs) -> np.ndarray | None:
    """Stage 2a: where the object may stand, ``(H, W)`` bool: the surface ``scene.surface`` names,
    segmented by ``segment.segmenter`` (SAM 3, a mask file), or ``None`` (RANSAC near the image
    centre, the default)."""
    from snell_bench.models.segment import surface_region as segment

    if not cfg.segment.get("segmenter"):
        return None
    key = OmegaConf.to_yaml(cfg.segment, resolve=True)
    if key not in _SEGMENTERS:
        _SEGMENTERS.clear()
        _SEGMENTERS[key] = _instantiate(cfg.segment.segmenter)
    phrase = cfg.scene.surface
    if not phrase:
        raise ValueError(
            f"segment={cfg.segment.name} needs the surface to find: set scene.surface (e.g. 'wooden table')"
        )
    return segment(_SEGMENTERS[key], scene.image, str(phrase))


def place(obj: GlassObject, scene: SceneInputs, obj_cfg: DictConfig, seed: int = 0, region=None) -> GlassObject:
    """Stage 2b: ``obj`` standing on a supporting surface of the scene (``object.size``,
    ``object.relative_size``, ``object.yaw_deg``), inside ``region`` when given."""
    from snell_bench.scene.placement import place_object

    kwargs: dict[str, Any] = {"seed": seed, "max_tilt_deg": float(obj_cfg.max_tilt_deg)}
    if scene.up is not None:
        kwargs["up_hint"] = scene.up
    if region is not None:
        kwargs["region"] = region
    try:
        return place_object(
            obj,
            scene.depth,
            scene.camera,
            size=obj_cfg.size,
            relative_size=float(obj_cfg.relative_size),
            yaw_deg=float(obj_cfg.yaw_deg),
            **kwargs,
        )
    except ValueError as e:
        if "surface" not in str(e) or region is not None:
            raise
        raise ValueError(
            f"placing object {obj_cfg.name!r}: {e}. The depth (scene.depth) must cover a horizontal surface near the "
            "image centre; for a tilted camera set scene.up (e.g. [0, -0.87, -0.5] for 30 degrees down) or widen "
            "object.max_tilt_deg"
        ) from None


# ---------------------------------------------------------------------------- 3. warps
def trace_warps(scene: SceneInputs, obj: GlassObject, warps_cfg: DictConfig) -> WarpSet:
    """Stage 3: :func:`~snell_bench.optics.compute_warps` with the ``warps`` node."""
    from snell_bench.optics.warps import compute_warps

    w = warps_cfg
    return compute_warps(
        scene.depth,
        scene.camera,
        obj,
        pano_height=int(w.pano_height),
        max_bounces=int(w.max_bounces),
        normals=str(w.normals),
        edge_threshold=float(w.edge_threshold),
        cache_dir=w.cache_dir,
        roi=bool(w.roi),
        infinity_tolerance_px=w.infinity_tolerance_px,
    )


# ---------------------------------------------------------------------------- 4-5. references
def render_reference(cfg: DictConfig, scene: SceneInputs, obj: GlassObject, *, spp: int | None = None):
    """Stage 4: the reference render and metric mask (``reference.*``), or ``(None, reason)``."""
    if not cfg.reference.enabled:
        return None, "reference.enabled=false"
    from snell_bench.render import render_reference as render

    try:  # Mitsuba is imported on the first render
        ref = render(
            scene.image,
            scene.depth,
            scene.camera,
            obj,
            spp=int(cfg.reference.spp if spp is None else spp),
            edge_threshold=float(cfg.warps.edge_threshold),
            seed=int(cfg.seed),
            unobserved_threshold=float(cfg.reference.unobserved_threshold),
            sampler=str(cfg.reference.sampler),
            crop=bool(cfg.reference.crop),
            crop_margin_px=int(cfg.reference.crop_margin_px),
            self_noise=bool(cfg.reference.self_noise),
            unobserved_spp=None if cfg.reference.unobserved_spp is None else int(cfg.reference.unobserved_spp),
        )
    except ImportError as e:
        reason = f"reference renderer unavailable ({e}); install the render extra: make setup EXTRAS=test,render"
        log.warning(reason)
        return None, reason
    return ref, None


def render_true_scene(cfg: DictConfig, scene: SceneInputs, obj: GlassObject) -> np.ndarray | None:
    """Stage 5: the procedural scene rendered with the object (``reference.true_render``), or None."""
    if not (cfg.reference.true_render and cfg.scene.source == "procedural"):
        return None
    from snell_bench.render import render_true

    bounces = cfg.reference.true_max_bounces or cfg.warps.max_bounces
    return render_true(
        scene.source, scene.camera, obj, spp=int(cfg.reference.true_spp), max_bounces=int(bounces), seed=int(cfg.seed)
    )


def prepare_inputs(cfg: DictConfig, *, references: bool = True) -> CellInputs:
    """Stages 1-5 for the scene, object, warps and reference settings of ``cfg``.

    Args:
        cfg: a composed config (the method's switches are not applied here: methods that change
            the warps get their own in :func:`run_method`).
        references: render the reference and the true render (stages 4 and 5).

    Returns:
        The shared inputs, with ``timings`` for ``scene``, ``warps``, ``reference``, ``true_render``.
    """
    t = Timer()
    with t("scene"):
        generators: dict = {}
        scene = load_scene(cfg, generators)
        region = surface_region(cfg, scene)
        obj = place(build_object(cfg.object), scene, cfg.object, seed=int(cfg.seed), region=region)
    # a generator built to generate I⁻ is reported as "generator" (by every method that reuses it)
    t.seconds["scene"] -= sum(seconds for _, seconds in generators.values())
    with t("warps"):
        ws = trace_warps(scene, obj, cfg.warps)
    if not ws.stats.get("object_pixels", 1):
        raise ValueError(
            f"object {cfg.object.name!r} covers no pixel of the {scene.camera.width}x{scene.camera.height} image "
            f"(object.size={cfg.object.size}, object.relative_size={cfg.object.relative_size}): nothing to trace or "
            "score; make it larger (object.size, object.relative_size) or the image larger (scene.width, scene.height)"
        )
    reference, reason, true = None, "not rendered", None
    if references:
        with t("reference"):
            reference, reason = render_reference(cfg, scene, obj)
        with t("true_render"):
            true = render_true_scene(cfg, scene, obj)
    return CellInputs(
        scene=scene,
        obj=obj,
        warps=ws,
        warps_config=_plain(cfg.warps),
        i_minus=hwc_to_bchw(scene.image),
        reference=reference,
        reference_reason=reason,
        true_render=true,
        timings=t.seconds,
        generators=generators,
    )


# ---------------------------------------------------------------------------- 6. generator
def build_generator(model_cfg: DictConfig, inputs: CellInputs):
    """Stage 6: ``instantiate(model.generator)``; a generator built from the scene
    (``model.from_scene``) also gets ``i_minus``, ``object_mask`` and a ``panorama`` of the kind
    ``model.pano_prior`` (:func:`~snell_bench.scene.sources.panorama_prior`)."""
    from hydra.utils import instantiate

    from snell_bench.scene.sources import panorama_prior

    if not model_cfg.get("generator"):
        raise ValueError(f"model {model_cfg.name!r} has no model.generator._target_; choose a model (model=analytic)")
    kwargs = {}
    if model_cfg.from_scene:
        kwargs = {
            "i_minus": inputs.scene.image,
            "object_mask": inputs.warps.object_mask,
            "panorama": panorama_prior(inputs.scene, inputs.warps, inputs.i_minus, str(model_cfg.pano_prior)),
        }
    return instantiate(model_cfg.generator, **kwargs)


def cached_generator(model_cfg: DictConfig, generators: dict, build) -> tuple[Any, float]:
    """The generator of ``model_cfg`` from ``generators`` (built by ``build()`` the first time, one
    model at a time) and the seconds its build took (reported by every method that reuses it)."""
    key = _model_key(model_cfg)
    if key not in generators:
        generators.clear()
        t = Timer()
        with t("generator"):
            gen = build()
        generators[key] = (gen, t.seconds["generator"])
    return generators[key]


# ---------------------------------------------------------------------------- 7. sampling
METHOD_KINDS = ("snellcaster", "t2i", "inpaint", "external")


def inpaint_mask(cfg: DictConfig, warps: WarpSet) -> np.ndarray:
    """The region ``method=inpaint`` repaints, boolean ``(H, W)``: the object's silhouette
    (``method.mask=object``) or its bounding box (``box``), grown by ``method.mask_dilate_px``."""
    from scipy.ndimage import binary_dilation

    m = np.asarray(warps.object_mask, bool)
    kind = str(cfg.method.mask)
    if kind == "box":
        ys, xs = np.nonzero(m)
        box = np.zeros_like(m)
        if ys.size:
            box[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1] = True
        m = box
    elif kind != "object":
        raise ValueError(f"method.mask={kind!r} is unknown; use 'object' or 'box'")
    r = int(cfg.method.mask_dilate_px)
    if r < 0:
        raise ValueError(f"method.mask_dilate_px must be >= 0, got {r}")
    if r:
        yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
        m = binary_dilation(m, structure=yy**2 + xx**2 <= r * r)
    return m


def _pipeline_method(cfg: DictConfig, inputs: CellInputs, warps: WarpSet, t: Timer) -> CellResult:
    """A baseline that is a diffusers pipeline: another text-to-image model (``external``, from
    ``method.model_id``) or FLUX Fill (``inpaint``, from ``model.fill``), with the method's steps,
    guidance and prompt, seeded with the cell's seed, on ``model.device``."""
    from snell_bench.models.errors import DeviceNotAvailableError, WeightsNotFoundError
    from snell_bench.models.external import generate_external, inpaint_external

    kind = cfg.method.kind
    text = prompt_of(cfg, str(cfg.method.prompt), "method.prompt")
    steps = None if cfg.method.steps is None else int(cfg.method.steps)
    guidance = None if cfg.method.guidance is None else float(cfg.method.guidance)
    device, dtype = cfg.model.device, cfg.model.dtype
    try:
        with t("sampling"):  # loading the pipeline included
            if kind == "external":
                img, used = generate_external(
                    cfg.method.model_id,
                    text,
                    warps.camera.shape,
                    seed=cell_seed(cfg),
                    steps=steps,
                    guidance=guidance,
                    device=device,
                    dtype=dtype,
                    return_settings=True,
                )
            else:
                img, used = inpaint_external(
                    _instantiate(cfg.model.fill),
                    text,
                    inputs.i_minus,
                    inpaint_mask(cfg, warps),
                    seed=cell_seed(cfg),
                    steps=steps,
                    guidance=guidance,
                    return_settings=True,
                )
    except (WeightsNotFoundError, DeviceNotAvailableError) as e:
        raise Skip(f"{cfg.method.label} cannot run here: {e}") from None
    return CellResult(image=img, warps=warps, stats={"pipeline": {**used.as_dict(), "prompt": text}})


def sample_method(cfg: DictConfig, inputs: CellInputs, warps: WarpSet, t: Timer) -> CellResult:
    """Stage 7: the method's image (``method.kind``: ``snellcaster``, ``t2i``, ``inpaint``,
    ``external``). Raises :class:`Skip` for a method that cannot run here (no weights, no device)."""
    from snell_bench.sampler.settings import SamplerSettings
    from snell_bench.sampler.snellcaster import sample

    kind = cfg.method.kind
    if kind not in METHOD_KINDS:
        raise ValueError(f"method.kind={kind!r} is unknown; use one of {METHOD_KINDS}")
    if kind == "external" or (kind == "inpaint" and cfg.model.get("fill")):
        return _pipeline_method(cfg, inputs, warps, t)
    gen, t.seconds["generator"] = cached_generator(
        cfg.model, inputs.generators, lambda: build_generator(cfg.model, inputs)
    )
    settings = OmegaConf.to_object(cfg.sampler)
    assert isinstance(settings, SamplerSettings)
    prompt = full_prompt(cfg)
    if kind == "inpaint":  # the CPU stand-in: the generator alone, pasted into the region
        prompt = prompt_of(cfg, str(cfg.method.prompt), "method.prompt")
        if cfg.method.steps is not None:
            settings.steps = int(cfg.method.steps)
    with t("sampling"):
        res = sample(gen, warps, inputs.i_minus, prompt, str(cfg.scene.pano_prompt), settings, seed=cell_seed(cfg))
    img = res.image
    if kind == "inpaint":
        img = torch.where(torch.from_numpy(inpaint_mask(cfg, warps))[None, None], img, inputs.i_minus)
    stats = {
        "model_calls": res.model_calls,
        "sampler_timings_s": {k: round(v, 3) for k, v in res.timings.items()},
        "decisions": res.decisions,
    }
    return CellResult(image=img, panorama=res.panorama, stats=stats, dumps=res.dumps, warps=warps)


# ---------------------------------------------------------------------------- 7b. relighting
#: One relighter kept between cells (FLUX Kontext is ~34 GB): its resolved config and itself.
_RELIGHTER: dict = {}


def relight_prompt(cfg: DictConfig) -> str:
    """The relighting instruction ``relight.prompt`` with ``{object_phrase}`` replaced by p_obj."""
    return str(cfg.relight.prompt).replace("{object_phrase}", object_phrase(cfg))


def build_relighter(cfg: DictConfig) -> tuple[Any, float]:
    """``instantiate(model.relighter)``, reused while that node is unchanged, and the seconds its
    build took. Raises :class:`Skip` when the model has no relighter or it cannot load here."""
    from snell_bench.models.errors import DeviceNotAvailableError, WeightsNotFoundError

    node = cfg.model.get("relighter")
    if not node:
        raise Skip(f"model {cfg.model.name!r} has no relighter (model.relighter); {cfg.method.label} cannot run")
    key = OmegaConf.to_yaml(node, resolve=True)
    if _RELIGHTER.get("key") != key:
        _RELIGHTER.clear()
        t = Timer()
        try:
            with t("relighter"):
                relighter = _instantiate(node)
        except (WeightsNotFoundError, DeviceNotAvailableError) as e:
            raise Skip(f"{cfg.method.label} cannot run here: {e}") from None
        _RELIGHTER.update(key=key, relighter=relighter, seconds=t.seconds["relighter"])
    return _RELIGHTER["relighter"], _RELIGHTER["seconds"]


def relight_image(cfg: DictConfig, inputs: CellInputs, result: CellResult, t: Timer) -> CellResult:
    """Stage 7b (``method.relight``): ``relight.candidates`` candidates from the model's relighter,
    seeded from the cell's seed; the one with the highest PSNR against the un-relit image inside
    the object's silhouette replaces the image. Every candidate's score and the choice go to
    ``stats["relight"]`` (JSON-safe); the un-relit image is kept as ``result.unrelit``."""
    from snell_bench.relight import candidate_seeds, relight

    relighter, t.seconds["relighter"] = build_relighter(cfg)
    warps = result.warps
    with t("relight"):
        res = relight(
            result.image,
            relighter=relighter,
            prompt=relight_prompt(cfg),
            seeds=candidate_seeds(cell_seed(cfg), int(cfg.relight.candidates)),
            object_mask=warps.object_mask,
            scene=inputs.scene,
            obj=inputs.obj,
            warps=warps,
        )
    result.unrelit = result.image
    result.image = res.image
    result.stats["relight"] = res.to_json()
    return result


# ---------------------------------------------------------------------------- 8. metrics
def score(
    cfg: DictConfig, inputs: CellInputs, image: torch.Tensor, scorers, *, image_path=None, reference=None
) -> dict:
    """Stage 8: masked metrics of ``image`` against the reference (``reference``: another
    ReferenceRender to score against, e.g. a converged one) and PSNR against the true render:
    ``{"metrics": {name: float | None}, "missing": {name: reason}}``."""
    from snell_bench.metrics import score_cell
    from snell_bench.utils.tensors import bchw_to_hwc

    ref = inputs.reference if reference is None else reference
    return score_cell(
        bchw_to_hwc(image),
        None if ref is None else ref.image,
        None if ref is None else ref.mask,
        prompt_of(cfg, str(cfg.metrics.clip_text), "metrics.clip_text"),
        scorers,
        reference_reason=inputs.reference_reason,
        true_render=inputs.true_render if reference is None else None,
        object_mask=inputs.warps.object_mask,
        generated_path=image_path,
        protocol=str(cfg.metrics.protocol),
    )


def run_method(cfg: DictConfig, inputs: CellInputs, *, scorers=None, image_path=None) -> CellResult:
    """Stages 6-8: one method (``cfg`` with :func:`apply_method` applied) on shared inputs.

    A method whose ``warps`` settings differ from those the inputs were traced with gets its own
    warps (timed as ``warps``). With ``scorers`` (:func:`snell_bench.metrics.load_scorers`) the
    image is scored and ``CellResult.scores`` filled; ``image_path`` is the saved image, handed to
    scorers that read files. Raises :class:`Skip` for a method that cannot run here.
    """
    t = Timer()
    warps = inputs.warps
    if _plain(cfg.warps) != inputs.warps_config:
        with t("warps"):
            warps = trace_warps(inputs.scene, inputs.obj, cfg.warps)
    result = sample_method(cfg, inputs, warps, t)
    if cfg.method.relight:
        result = relight_image(cfg, inputs, result, t)
    if scorers is not None:
        if image_path is not None:
            from snell_bench.utils.io import save_png
            from snell_bench.utils.tensors import bchw_to_hwc

            save_png(image_path, bchw_to_hwc(result.image))
            if result.unrelit is not None:
                p = Path(image_path)
                save_png(p.with_name(f"{p.stem}_unrelit{p.suffix}"), bchw_to_hwc(result.unrelit))
        with t("metrics"):
            result.scores = score(cfg, inputs, result.image, scorers, image_path=image_path)
    result.timings = {**t.seconds, **result.timings}
    return result
