"""Checks of a composed config before any work: every key known, every value usable.

:func:`check_config` runs at the start of every job (and, on the command line, before Hydra
creates its output folder or configures logging: :class:`snell_bench.preflight.Preflight`), and
on every cell a sweep composes, so a bad setting fails in the first second, not after the scene
and the warps are built. Each problem names the key, the bad value and the fix; all of them are
reported together in one :class:`ConfigError`.

- **Unknown keys.** Hydra's ``+key=value`` adds a key even in struct mode; a key that no schema
  (:mod:`snell_bench.config`) knows would be ignored silently. Free-form nodes (``_target_``
  nodes such as ``object.factory``, ``tradeoff.axes``) may hold anything; ``method.sampler`` and
  ``method.warps`` are checked against the ``sampler`` and ``warps`` schemas they override.
- **Values.** Sizes, seeds, counts, angles, the materials, the choices of string keys, the
  generator's size rule and the pyramid's depth, each against its documented range.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf

__all__ = [
    "ConfigError",
    "check_config",
    "unknown_keys",
    "max_levels",
    "check_grid_entries",
    "check_tradeoff_entries",
]


class ConfigError(ValueError):
    """One or more settings are unusable; the message lists each with its fix."""

    def __init__(self, problems: Iterable[str]) -> None:
        self.problems = list(problems)
        if len(self.problems) == 1:
            super().__init__(self.problems[0])
        else:
            super().__init__(
                f"{len(self.problems)} settings are unusable:\n" + "\n".join(f"  - {p}" for p in self.problems)
            )


# ---------------------------------------------------------------------------- unknown keys
#: Nodes that override another node's schema: their keys must be keys of that node.
_OVERRIDE_NODES = {"method.sampler": "sampler", "method.warps": "warps"}
#: Keys outside the schema that a composed config may carry.
_RUNTIME_KEYS = {"hydra"}


def _schema():
    from snell_bench.config import Config

    return OmegaConf.structured(Config)


def _is_structured(node: Any) -> bool:
    return isinstance(node, DictConfig) and dataclasses.is_dataclass(OmegaConf.get_type(node))


def _unknown(node: DictConfig, schema: DictConfig, prefix: str, out: list[str], root_schema: DictConfig) -> None:
    known = list(schema.keys())  # with MISSING values (``key in schema`` is False for those)
    for key in node.keys():
        path = f"{prefix}{key}"
        if key not in known:
            close = difflib.get_close_matches(str(key), [str(k) for k in known], n=1, cutoff=0.6)
            hint = (
                f"did you mean {prefix}{close[0]}?"
                if close
                else f"{prefix.rstrip('.') or 'the config'} has {sorted(map(str, known))}"
            )
            out.append(f"{path}: no setting has this name ({hint}); remove it or fix its spelling")
            continue
        sub_schema = schema._get_node(key)
        if path in _OVERRIDE_NODES:
            target = root_schema[_OVERRIDE_NODES[path]]
            value = node._get_node(key)
            if isinstance(value, DictConfig):
                _unknown(value, target, f"{path}.", out, root_schema)
            continue
        if _is_structured(sub_schema):
            value = node._get_node(key)
            if isinstance(value, DictConfig):
                _unknown(value, sub_schema, f"{path}.", out, root_schema)


def unknown_keys(cfg: DictConfig) -> list[str]:
    """One line per key of ``cfg`` that no schema knows (``+warps.max_bounce=1``: a typo), each
    naming the closest known key."""
    schema = _schema()
    out: list[str] = []
    node = cfg
    if any(k in _RUNTIME_KEYS for k in cfg.keys()):
        node = OmegaConf.masked_copy(cfg, [k for k in cfg.keys() if k not in _RUNTIME_KEYS])
    _unknown(node, schema, "", out, schema)
    return out


# ---------------------------------------------------------------------------- values
def _get(cfg: DictConfig, key: str) -> Any:
    return OmegaConf.select(cfg, key, throw_on_missing=False)


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _int_at_least(cfg, key: str, lo: int, out: list[str], why: str = "", example: int | None = None) -> None:
    v = _get(cfg, key)
    if not _is_int(v) or v < lo:
        fix = f"e.g. {key}={lo if example is None else example}"
        out.append(f"{key}={v!r}: must be an integer >= {lo}{why}; {fix}")


def _finite(cfg, key: str, out: list[str], *, positive: bool = False, lo=None, hi=None, optional=False, fix=""):
    v = _get(cfg, key)
    if v is None and optional:
        return
    ok = _is_number(v) and math.isfinite(float(v))
    if ok and positive and float(v) <= 0:
        ok = False
    if ok and lo is not None and float(v) < lo:
        ok = False
    if ok and hi is not None and float(v) > hi:
        ok = False
    if not ok:
        rng = "a finite number" + (" > 0" if positive else "")
        if lo is not None and hi is not None:
            rng = f"a number in [{lo}, {hi}]"
        elif lo is not None:
            rng = f"a number >= {lo}"
        out.append(f"{key}={v!r}: must be {rng}{' or null' if optional else ''}{'; ' + fix if fix else ''}")


def _choice(cfg, key: str, choices: Iterable[str], out: list[str]) -> None:
    v = _get(cfg, key)
    choices = tuple(choices)
    if v not in choices:
        out.append(f"{key}={v!r} is unknown; use one of {list(choices)}")


def max_levels(height: int, width: int) -> int:
    """The most Laplacian-pyramid levels the sampler can use on an image of this size: every level
    halves it, and the coarsest keeps at least 2 pixels a side (the 5-tap blur of ``pyrup``
    reflects 2 pixels at each border: 96 px allow 6 levels, 720 px 9)."""
    return max(1, int(min(height, width)).bit_length() - 1)


def _scene(cfg: DictConfig, out: list[str]) -> None:
    _int_at_least(cfg, "seed", 0, out, " (random generators take no negative seed)", 0)
    _int_at_least(cfg, "scene.variation", 0, out, " (it seeds the scene and the sampling)", 0)
    _int_at_least(cfg, "scene.seed_offset", 0, out, "", 0)
    _choice(cfg, "scene.source", ("procedural", "image", "generated"), out)
    src = _get(cfg, "scene.source")
    mult = _get(cfg, "model.multiple")
    if not _is_int(mult) or mult < 1:
        out.append(f"model.multiple={mult!r}: must be an integer >= 1 (the generator's block size)")
        mult = 1
    if src in ("procedural", "generated"):
        for key in ("scene.width", "scene.height"):
            v = _get(cfg, key)
            if not _is_int(v) or v < mult:
                out.append(f"{key}={v!r}: must be a positive multiple of model.multiple={mult}; e.g. {key}={mult * 40}")
            elif v % mult:
                lo, hi = v // mult * mult, (v // mult + 1) * mult
                out.append(
                    f"{key}={v}: the generator (model={_get(cfg, 'model.name')}) needs multiples of "
                    f"model.multiple={mult}; use {key}={lo if lo else hi} or {key}={hi}"
                )
    if src == "procedural":
        _int_at_least(cfg, "scene.supersample", 1, out, "", 2)
    if src == "generated":
        _int_at_least(cfg, "scene.steps", 1, out, "", 28)
    _finite(cfg, "scene.fov_deg", out, positive=True, hi=179.0, optional=True, fix="e.g. scene.fov_deg=60")
    _finite(cfg, "scene.depth_scale", out, positive=True, optional=True, fix="e.g. 5000 (TUM) or 1000 (mm)")
    _choice(cfg, "scene.depth_kind", ("z", "range"), out)


def _object(cfg: DictConfig, out: list[str]) -> None:
    from snell_bench.scene.objects import resolve_ior

    fix = "object.size is in scene units (metres); null uses object.relative_size x the distance"
    _finite(cfg, "object.size", out, positive=True, optional=True, fix=fix)
    _finite(cfg, "object.relative_size", out, positive=True, fix="e.g. object.relative_size=0.25")
    _finite(cfg, "object.yaw_deg", out, fix="a rotation about the up axis in degrees, e.g. object.yaw_deg=30")
    _finite(cfg, "object.max_tilt_deg", out, lo=0.0, hi=90.0, fix="e.g. object.max_tilt_deg=30")
    ior = _get(cfg, "object.ior")
    try:
        resolve_ior(ior)
    except ValueError as e:
        out.append(f"object.ior={ior!r}: {e}")
    factory = _get(cfg, "object.factory")
    if isinstance(factory, DictConfig) and "path" in factory:
        from snell_bench.pipeline import data_path

        if not _get(cfg, "object.path"):
            out.append(f"object={_get(cfg, 'object.name')} reads a mesh file: set object.path")
        else:
            try:
                data_path(_get(cfg, "object.path"), "object.path", "mesh file (.ply/.obj/.glb/.stl)")
            except OSError as e:
                out.append(str(e))
    axis = _get(cfg, "object.up_axis")
    if str(axis).lstrip("+-").lower() not in ("x", "y", "z"):
        out.append(f"object.up_axis={axis!r}: use x, y or z, optionally signed (-z)")


def _files(cfg: DictConfig, out: list[str]) -> None:
    """The input files a config names: there, and files rather than folders."""
    from snell_bench.pipeline import data_path

    def need(key: str, what: str, why: str) -> None:
        value = _get(cfg, key)
        if not value:
            out.append(f"{why} needs {key}: set {key}=PATH ({what})")
            return
        try:
            data_path(value, key, what)
        except OSError as e:
            out.append(str(e))

    if _get(cfg, "scene.source") == "image":
        need("scene.image", "image file", "scene.source=image")
        if _get(cfg, "scene.depth"):
            need("scene.depth", "depth file", "scene.depth")
    for key, what in (
        ("metrics.lpips_weights", "torchvision VGG16 state dict"),
        ("metrics.clip_weights", "open_clip ViT-B-16 checkpoint file or folder"),
        ("metrics.image_reward_python", "python executable of an environment with image-reward"),
    ):
        value = _get(cfg, key)
        if value and not Path(str(value)).exists():
            out.append(
                f"{key}={str(value)!r}: no such file (the {what}); fix the path, or set {key}=null to report the "
                "metric as missing"
            )
    segmenter = _get(cfg, "segment.segmenter")
    if isinstance(segmenter, DictConfig) and str(segmenter.get("_target_", "")).endswith("MaskFileSegmenter"):
        need("segment.mask", "a PNG mask file, nonzero on the surface", f"segment={_get(cfg, 'segment.name')}")


def _sampler(cfg: DictConfig, out: list[str]) -> None:
    from snell_bench.sampler.settings import SamplerSettings

    node = OmegaConf.merge(cfg.sampler, _get(cfg, "method.sampler") or {})  # the method's switches applied
    try:
        s = SamplerSettings(**OmegaConf.to_container(node, resolve=True))
    except (ValueError, TypeError) as e:
        out.append(str(e))
        return
    limits = []  # (levels, what limits them)
    h, w = _get(cfg, "scene.height"), _get(cfg, "scene.width")
    if _get(cfg, "scene.source") in ("procedural", "generated") and _is_int(h) and _is_int(w) and h > 0 and w > 0:
        limits.append((max_levels(h, w), f"the {h}x{w} image (scene.height x scene.width)"))
    pano = _get(cfg, "warps.pano_height")
    if s.uses_panorama and _is_int(pano) and pano > 1:
        limits.append((max_levels(pano, 2 * pano), f"the {pano}x{2 * pano} panorama (warps.pano_height)"))
    if limits:
        most, what = min(limits)
        if s.effective_levels > most:
            out.append(
                f"sampler.levels={s.levels}: {what} has at most {most} pyramid levels (each halves it, the "
                f"coarsest keeps 2 pixels); use sampler.levels={min(5, most)} (1 to {most}) or a larger size"
            )


def _warps_and_reference(cfg: DictConfig, out: list[str]) -> None:
    from snell_bench.render.backend import SAMPLERS

    _int_at_least(cfg, "warps.pano_height", 2, out, "", 1024)
    _int_at_least(cfg, "warps.max_bounces", 1, out, "", 8)
    _choice(cfg, "warps.normals", ("interpolated", "face"), out)
    _finite(cfg, "warps.edge_threshold", out, positive=True, fix="e.g. warps.edge_threshold=0.05")
    _finite(cfg, "warps.infinity_tolerance_px", out, positive=True, optional=True, fix="e.g. 0.5")
    _int_at_least(cfg, "reference.spp", 1, out, "", 242)
    _choice(cfg, "reference.sampler", SAMPLERS, out)
    if _get(cfg, "reference.unobserved_spp") is not None:
        _int_at_least(cfg, "reference.unobserved_spp", 1, out, "", 25)
    _int_at_least(cfg, "reference.crop_margin_px", 0, out, "", 4)
    _int_at_least(cfg, "reference.true_spp", 1, out, "", 4)
    _finite(cfg, "reference.unobserved_threshold", out, lo=0.0, hi=1.0, fix="e.g. 0.05")
    _int_at_least(cfg, "relight.candidates", 1, out, "", 3)


def _devices(cfg: DictConfig, out: list[str]) -> None:
    """Devices named explicitly must exist here (``null`` / ``auto``: CUDA when available, which a
    method that needs it reports as skipped); dtypes must be known."""
    import torch

    from snell_bench.models.devices import parse_dtype

    for key in ("model.device", "depth.device", "segment.device"):
        value = _get(cfg, key)
        if value is None or str(value) == "auto":
            continue
        try:
            dev = torch.device(str(value))
        except (RuntimeError, ValueError):
            out.append(f"{key}={value!r} is not a device; use cpu, cuda, cuda:1 or null")
            continue
        if dev.type == "cuda" and not torch.cuda.is_available():
            out.append(f"{key}={value!r}: this machine has no CUDA device; use {key}=cpu (or null)")
        elif dev.type == "cuda" and dev.index is not None and dev.index >= torch.cuda.device_count():
            out.append(f"{key}={value!r}: there are {torch.cuda.device_count()} CUDA devices; use cuda:0 ...")
    dtype = _get(cfg, "model.dtype")
    if dtype is not None:
        try:
            parse_dtype(str(dtype))
        except (TypeError, ValueError) as e:
            out.append(str(e))


def _model_and_method(cfg: DictConfig, out: list[str]) -> None:
    from snell_bench.metrics.fidelity import PROTOCOLS
    from snell_bench.pipeline import METHOD_KINDS, PROMPT_KINDS
    from snell_bench.scene.sources import PANO_PRIORS

    _choice(cfg, "model.pano_prior", PANO_PRIORS, out)
    _devices(cfg, out)
    _choice(cfg, "method.kind", METHOD_KINDS, out)
    _choice(cfg, "method.prompt", PROMPT_KINDS, out)
    _choice(cfg, "method.mask", ("object", "box"), out)
    _int_at_least(cfg, "method.mask_dilate_px", 0, out, "", 0)
    _choice(cfg, "metrics.protocol", PROTOCOLS, out)
    _choice(cfg, "metrics.clip_text", PROMPT_KINDS, out)
    _choice(cfg, "grid.on_change", ("error", "recompute"), out)
    _choice(cfg, "tradeoff.on_change", ("error", "recompute"), out)


def check_grid_entries(cfg: DictConfig) -> list[str]:
    """Problems of ``grid.variations`` and ``grid.objects`` entries (integers >= 0; object specs
    ``name`` or ``name:ior`` with a number or a material name)."""
    from snell_bench.experiment.plan import parse_object_spec
    from snell_bench.scene.objects import MATERIALS, resolve_ior

    out: list[str] = []
    g = cfg.grid
    for key in ("scenes", "variations", "objects", "methods"):
        if not isinstance(g.get(key), ListConfig) or len(g.get(key)) == 0:
            out.append(f"grid.{key}={g.get(key)!r}: must be a non-empty list, e.g. grid.{key}=[...]")
    if out:
        return out
    from snell_bench.experiment.plan import check_names, check_unique, object_dir_name

    for group, key, names in (
        ("method", "grid.methods", list(g.methods)),
        ("scene", "grid.scenes", list(g.scenes)),
        ("object", "grid.objects", [parse_object_spec(o)[0] for o in g.objects]),
    ):
        try:
            check_names(group, names, key)
        except ValueError as e:
            out.append(str(e))
    for key, values, name in (
        ("grid.methods", list(g.methods), str),
        ("grid.scenes", list(g.scenes), str),
        ("grid.variations", list(g.variations), str),
        ("grid.objects", [str(o) for o in g.objects], object_dir_name),
    ):
        try:
            check_unique(values, key, name=name)
        except ValueError as e:
            out.append(str(e))
    for v in g.variations:
        if not _is_int(v) or v < 0:
            out.append(
                f"grid.variations: entry {v!r} is not an integer >= 0 (a variation seeds its scene); "
                "e.g. grid.variations=[0,1,2]"
            )
    for spec in g.objects:
        name, ior = parse_object_spec(spec)
        if ior is not None:
            try:
                resolve_ior(ior)
            except ValueError:
                out.append(
                    f"grid.objects: entry {str(spec)!r}: {ior!r} is neither a number (the IOR) nor a material; "
                    f"write {name}:1.45 or {name}:<material> with one of {sorted(MATERIALS)}"
                )
    return out


def check_tradeoff_entries(cfg: DictConfig) -> list[str]:
    """Problems of the ``tradeoff`` lists: scenes (non-empty, known, no repeats), the object spec,
    the method, the variation, ``only`` (names of ``axes``) and the presets."""
    from snell_bench.experiment.plan import check_names, check_unique, parse_object_spec
    from snell_bench.scene.objects import resolve_ior

    out: list[str] = []
    t = cfg.tradeoff
    scenes = [str(x) for x in (t.scenes or [])]
    if not scenes:
        out.append("tradeoff.scenes is empty; give at least one scene, e.g. tradeoff.scenes=[living_room]")
    name, ior = parse_object_spec(str(t.object))
    for group, key, names in (
        ("scene", "tradeoff.scenes", scenes),
        ("object", "tradeoff.object", [name]),
        ("method", "tradeoff.method", [str(t.method)]),
        ("preset", "tradeoff.presets", [str(x) for x in (t.presets or [])]),
    ):
        try:
            check_names(group, names, key)
        except ValueError as e:
            out.append(str(e))
    for key, values in (("tradeoff.scenes", scenes), ("tradeoff.presets", [str(x) for x in (t.presets or [])])):
        try:
            check_unique(values, key)
        except ValueError as e:
            out.append(str(e))
    if ior is not None:
        try:
            resolve_ior(ior)
        except ValueError as e:
            out.append(f"tradeoff.object={str(t.object)!r}: {e}")
    _int_at_least(cfg, "tradeoff.variation", 0, out, " (it seeds the scene and the sampling)", 0)
    if t.only is not None:
        unknown = [str(a) for a in t.only if str(a) not in (t.axes or {})]
        if unknown:
            out.append(f"tradeoff.only: unknown axes {unknown}; choose from {list(t.axes or {})}")
    return out


def check_config(cfg: DictConfig, *, grid: bool | None = None) -> DictConfig:
    """Raise :class:`ConfigError` listing every unknown key and unusable value of ``cfg``.

    Args:
        cfg: a composed config (the ``hydra`` node may be present).
        grid: also check the ``grid`` lists' entries (default: when ``job=grid``).

    Returns:
        ``cfg``, unchanged.
    """
    problems = unknown_keys(cfg)
    if problems:  # a value check may trip over an unknown key's node
        raise ConfigError(problems)
    from snell_bench.experiment import JOBS

    job = _get(cfg, "job")
    if job not in JOBS:
        problems.append(f"job={job!r} is unknown; use one of {sorted(JOBS)}")
    for check in (_scene, _object, _files, _sampler, _warps_and_reference, _model_and_method):
        check(cfg, problems)
    if grid if grid is not None else job == "grid":
        problems += check_grid_entries(cfg)
    if grid is None and job == "tradeoff":
        problems += check_tradeoff_entries(cfg)
    if problems:
        raise ConfigError(problems)
    return cfg
