"""What flows between the pipeline's stages, and the few facts of a cell's config every stage reads.

Conventions: images handed between stages are ``(1, 3, H, W)`` float32 sRGB tensors in [0, 1]
(``CellInputs.i_minus``, ``CellResult.image``) or ``(H, W, 3)`` numpy arrays where a stage works in
numpy (``SceneInputs.image``, references); depth is camera-frame z in metres (NaN: unknown); the
camera frame is OpenCV's.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from hydra.errors import InstantiationException
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from snell_bench.config import PromptKind
from snell_bench.optics.warps import WarpSet
from snell_bench.pipeline.pool import ModelPool
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.sources import SceneInputs

__all__ = [
    "CellInputs",
    "CellResult",
    "Skip",
    "Degenerate",
    "apply_method",
    "cell_seed",
    "generator_on_procedural",
    "initial_noise_record",
    "scene_pipeline_record",
    "full_prompt",
    "object_phrase",
    "prompt_of",
    "plain",
    "node_key",
    "build",
    "kwargs_for",
]


class Skip(Exception):
    """A method that cannot run here; the message says why."""


class Degenerate(Exception):
    """A cell whose result could not mean anything, detected by the pipeline (the object's warps void
    over every object pixel, an empty metric mask, a reference without one finite pixel): recorded
    as ``degenerate`` with the message, shown in the reports and in no mean."""


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
    #: the models these inputs were prepared with (a generator that made I⁻ is reused by the methods)
    pool: ModelPool = field(default_factory=ModelPool, repr=False, compare=False)
    #: the group's id, ``<scene>-<variation>/<object>`` (the grid's folder and the benchmark kit's id;
    #: set by the grid, empty elsewhere)
    group: str = ""


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
    return cfg.seed + cfg.scene.variation


def generator_on_procedural(cfg: DictConfig) -> bool:
    """Whether a text-to-image generator (``model.from_scene: false``: FLUX, the tiny random FLUX)
    is synchronised with a procedural scene: a named choice (``scene.source=procedural``), never the
    paper's scene pipeline, in which such a model generates I⁻ from p⁻ (``scene.source=generated``,
    which ``conf/model/flux_dev.yaml`` and ``tiny_flux.yaml`` select)."""
    return cfg.scene.source == "procedural" and not cfg.model.from_scene


def scene_pipeline_record(cfg: DictConfig) -> dict:
    """What a cell's record says of its scene pipeline beyond ``scene_source``:
    ``{"generator_on_procedural": true}`` where :func:`generator_on_procedural` holds, else ``{}``."""
    return {"generator_on_procedural": True} if generator_on_procedural(cfg) else {}


def initial_noise_record(scene_info: dict | None, decisions: dict | None) -> dict:
    """``{"initial_noise": {"i_minus", "main", "same"}}``: the digests of the initial noise a
    generated I⁻ and the cell's main branch were drawn from (same seed, same first draw: the paper's
    main branch starts from I⁻'s noise), and whether they are bit-identical; ``{}`` where either
    is unknown (a procedural scene or a photo; a method that does not sample)."""
    a = (scene_info or {}).get("initial_noise")
    b = (decisions or {}).get("initial_noise")
    if not (isinstance(a, str) and isinstance(b, str)):
        return {}
    return {"initial_noise": {"i_minus": a, "main": b, "same": a == b}}


def full_prompt(cfg: DictConfig) -> str:
    """The full prompt p of a config, ``{object}`` replaced by the object's noun."""
    return cfg.scene.prompt.replace("{object}", cfg.object.noun)


def object_phrase(cfg: DictConfig) -> str:
    """The object phrase p_obj of a config (``"a big glass sphere"``), ``{object}`` replaced."""
    return cfg.scene.object_phrase.replace("{object}", cfg.object.noun)


def prompt_of(cfg: DictConfig, kind: PromptKind | str, key: str = "method.prompt") -> str:
    """The full prompt (``kind="full"``) or the object phrase (``"object"``), the two texts
    ``method.prompt`` and ``metrics.clip_text`` choose between (``key`` names the setting in the
    error for any other value)."""
    return full_prompt(cfg) if PromptKind.of(kind, key) is PromptKind.full else object_phrase(cfg)


def plain(node: Any) -> Any:
    """A config node as plain Python (resolved; choices as their strings), anything else as is."""
    if isinstance(node, DictConfig):
        return OmegaConf.to_container(node, resolve=True, enum_to_str=True)
    return node


def node_key(node: Any) -> str:
    """What identifies a model: the YAML of its resolved config node."""
    return OmegaConf.to_yaml(node, resolve=True) if isinstance(node, DictConfig) else repr(node)


def build(node: DictConfig, **kwargs: Any) -> Any:
    """``instantiate(node, **kwargs)``, raising the constructor's own error (missing weights, no
    GPU, a bad file) rather than Hydra's wrapper."""
    try:
        return instantiate(node, **kwargs)
    except InstantiationException as e:
        raise (e.__cause__ or e) from None


def kwargs_for(fn: Callable, node: Any, **extra: Any) -> dict[str, Any]:
    """The keys of a config node (as plain values) that ``fn`` takes as keyword arguments, updated
    with ``extra``: a setting added to the node and to ``fn`` needs no third place."""
    params = inspect.signature(fn).parameters
    values = {k: v for k, v in plain(node).items() if k in params}
    return {**values, **extra}
