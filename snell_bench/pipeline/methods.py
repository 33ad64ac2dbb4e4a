"""Stages 6-7b: one method's image on shared inputs.

6. the generator, built from ``model.generator`` (:func:`build_generator`), from the model pool;
7. sampling with the method's settings: what the method's kind runs (:func:`sample_method`, the
   registry of :mod:`snell_bench.methods`: the synchronized sampler, the generator alone, FLUX Fill
   or its CPU stand-in, another text-to-image pipeline, images made elsewhere, a user's method),
   with the helpers the kinds share (:func:`cell_generator`, :func:`baseline_prompt`,
   :func:`inpaint_mask`);
7b. relighting (``method.relight``): N candidates from the model's relighter, the one closest to
   the un-relit image inside the object kept (:func:`relight_image`).

Every model comes from the inputs' :class:`~snell_bench.pipeline.pool.ModelPool`; a method that
cannot run here (no weights, no device) raises :class:`~snell_bench.pipeline.cell.Skip`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from omegaconf import DictConfig, OmegaConf
from scipy.ndimage import binary_dilation

from snell_bench.config import InpaintMask, PromptKind
from snell_bench.methods.registry import method_of
from snell_bench.models.errors import DeviceNotAvailableError, WeightsNotFoundError
from snell_bench.models.sizes import node_weights_bytes
from snell_bench.optics.warps import WarpSet
from snell_bench.pipeline.cell import (
    CellInputs,
    CellResult,
    Skip,
    build,
    cell_seed,
    full_prompt,
    node_key,
    object_phrase,
    prompt_of,
)
from snell_bench.pipeline.inputs import generator_of
from snell_bench.relight import candidate_seeds, relight
from snell_bench.scene.sources import panorama_prior
from snell_bench.utils.timing import Timer

__all__ = [
    "architecture",
    "baseline_prompt",
    "cell_generator",
    "generator_scope",
    "build_generator",
    "inpaint_mask",
    "sample_method",
    "relight_prompt",
    "relighter_of",
    "relight_image",
]


# ---------------------------------------------------------------------------- 6. generator
def build_generator(model_cfg: DictConfig, inputs: CellInputs):
    """Stage 6: ``instantiate(model.generator)``; a generator built from the scene
    (``model.from_scene``) also gets ``i_minus``, ``object_mask`` and a ``panorama`` of the kind
    ``model.pano_prior`` (:func:`~snell_bench.scene.sources.panorama_prior`)."""
    if not model_cfg.get("generator"):
        raise ValueError(f"model {model_cfg.name!r} has no model.generator._target_; choose a model (model=analytic)")
    kwargs = {}
    if model_cfg.from_scene:
        kwargs = {
            "i_minus": inputs.scene.image,
            "object_mask": inputs.warps.object_mask,
            "panorama": panorama_prior(inputs.scene, inputs.warps, inputs.i_minus, model_cfg.pano_prior),
        }
    return build(model_cfg.generator, **kwargs)


def generator_scope(inputs: CellInputs) -> tuple:
    """The pool scope of generators built from ``inputs`` (``model.from_scene``)."""
    return ("inputs", id(inputs))


def cell_generator(cfg: DictConfig, inputs: CellInputs) -> tuple[Any, float]:
    """The generator of the cell from the inputs' pool. One built from the scene lives as long as
    the inputs (its scope); any other is shared by every cell of the sweep."""
    pool = inputs.pool
    if not cfg.model.from_scene:
        return generator_of(cfg, pool, lambda: build_generator(cfg.model, inputs))
    scope = generator_scope(inputs)
    pool.end_with(inputs, scope)  # released with the inputs
    return pool.get(
        "generator",
        node_key(cfg.model),
        lambda: build_generator(cfg.model, inputs),
        label=cfg.model.name,
        scope=scope,
    )


# ---------------------------------------------------------------------------- 7. sampling
def inpaint_mask(cfg: DictConfig, warps: WarpSet) -> np.ndarray:
    """The region ``method=inpaint`` repaints, boolean ``(H, W)``: the object's silhouette
    (``method.mask=object``) or its bounding box (``box``), grown by ``method.mask_dilate_px``."""
    m = np.asarray(warps.object_mask, bool)
    if cfg.method.mask is InpaintMask.box:
        ys, xs = np.nonzero(m)
        box = np.zeros_like(m)
        if ys.size:
            box[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1] = True
        m = box
    r = cfg.method.mask_dilate_px
    if r < 0:
        raise ValueError(f"method.mask_dilate_px must be >= 0, got {r}")
    if r:
        yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
        m = binary_dilation(m, structure=yy**2 + xx**2 <= r * r)
    return m


def baseline_prompt(cfg: DictConfig) -> str:
    """The text a baseline sees (``method.prompt``): the full prompt p or the object phrase p_obj,
    with ``baselines.object_phrase`` (``{object}``: the object's noun) in place of p_obj where it
    is set (the authors' "a solid transparent glass {object}").

    Raises:
        ValueError: the scene's p_obj does not occur in its p, so it cannot be replaced (naming
            ``baselines.object_phrase``).
    """
    kind = cfg.method.prompt
    phrase = OmegaConf.select(cfg, "baselines.object_phrase", default=None)
    if phrase is None:
        return prompt_of(cfg, kind)
    new = phrase.replace("{object}", cfg.object.noun)
    if kind is PromptKind.object:
        return new
    full, old = full_prompt(cfg), object_phrase(cfg)
    if old not in full:
        raise ValueError(
            f"baselines.object_phrase={phrase!r}: the scene's object phrase {old!r} is not in its prompt "
            f"{full!r}, so it cannot be replaced; set baselines.object_phrase=null"
        )
    return full.replace(old, new, 1)


def architecture(cfg: DictConfig) -> str:
    """``method.architecture`` of an external baseline, which a model's ``pipelines`` builder needs."""
    if not cfg.method.get("architecture"):
        raise ValueError(
            f"method={cfg.method.name}: model={cfg.model.name} builds the external baselines' pipelines "
            "(model.pipelines) by architecture: set method.architecture (flux2, qwen_image or sd3)"
        )
    return cfg.method.architecture


def sample_method(cfg: DictConfig, inputs: CellInputs, warps: WarpSet, t: Timer) -> CellResult:
    """Stage 7: the method's image: :meth:`~snell_bench.methods.Method.run` of the kind
    ``method.kind`` (or ``method._target_``) names (:func:`~snell_bench.methods.method_of`).
    Raises :class:`Skip` for a method that cannot run here (no weights, no device, no image)."""
    return method_of(cfg).run(cfg, inputs, warps, t)


# ---------------------------------------------------------------------------- 7b. relighting
def relight_prompt(cfg: DictConfig) -> str:
    """The relighting instruction ``relight.prompt`` with ``{object_phrase}`` replaced by p_obj."""
    return cfg.relight.prompt.replace("{object_phrase}", object_phrase(cfg))


def relighter_of(cfg: DictConfig, inputs: CellInputs) -> tuple[Any, float]:
    """``instantiate(relight.relighter)``, else ``instantiate(model.relighter)``, from the inputs' pool
    and the seconds its load took.
    Raises :class:`Skip` when the model has no relighter or it cannot load here."""
    node = cfg.relight.get("relighter") or cfg.model.get("relighter")
    if not node:
        raise Skip(f"model {cfg.model.name!r} has no relighter (model.relighter); {cfg.method.label} cannot run")
    try:
        return inputs.pool.get(
            "relighter",
            node_key(node),
            lambda: build(node),
            label=f"{cfg.model.name} relighter",
            size=lambda: node_weights_bytes(node),
        )
    except (WeightsNotFoundError, DeviceNotAvailableError) as e:
        raise Skip(f"{cfg.method.label} cannot run here: {e}") from None


def relight_image(cfg: DictConfig, inputs: CellInputs, result: CellResult, t: Timer) -> CellResult:
    """Stage 7b (``method.relight``): ``relight.candidates`` candidates from the model's relighter,
    seeded from the cell's seed; the one with the highest PSNR against the un-relit image inside
    the object's silhouette replaces the image. Every candidate's score and the choice go to
    ``stats["relight"]`` (JSON-safe); the un-relit image is kept as ``result.unrelit``."""
    relighter, t.seconds["relighter"] = relighter_of(cfg, inputs)
    warps = result.warps
    with t("relight"):
        res = relight(
            result.image,
            relighter=relighter,
            prompt=relight_prompt(cfg),
            seeds=candidate_seeds(cell_seed(cfg), cfg.relight.candidates),
            object_mask=warps.object_mask,
            scene=inputs.scene,
            obj=inputs.obj,
            warps=warps,
            panorama=result.panorama,
        )
    result.unrelit = result.image
    result.image = res.image
    result.stats["relight"] = res.to_json()
    if getattr(relighter, "last_record", None):  # what a traced relighter lit with, and its beams' energy
        result.stats["relight"]["transport"] = relighter.last_record
    return result
