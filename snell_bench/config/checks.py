"""Checks of a composed config before any work: every key known, every value usable.

:func:`check_config` runs at the start of every job (and, on the command line, before Hydra
creates its output folder or configures logging: :class:`snell_bench.config.preflight.Preflight`), and
on every cell a sweep composes, so a bad setting fails in the first second, not after the scene
and the warps are built. Each problem names the key, the bad value and the fix; all of them are
reported together in one :class:`ConfigError`.

- **Unknown keys.** Hydra's ``+key=value`` adds a key even in struct mode; a key that no schema
  (:mod:`snell_bench.config`) knows would be ignored silently. Free-form nodes (``_target_``
  nodes such as ``object.factory``, ``grid.axes``) may hold anything; ``method.sampler`` and
  ``method.warps`` are checked against the ``sampler`` and ``warps`` schemas they override.
- **Values.** Choices are enums of the schema, checked when the config is composed; here each
  node's dataclass checks its ranges (``__post_init__``, the warps with ``method.warps`` applied,
  the sampler with ``method.sampler``: a bad value the method sets is named
  ``method.sampler.<key>``), then what depends on several nodes (the image's and the panorama's
  sizes against the generator's block, the pyramid's depth against both, the camera of a photo
  and the field of view the object fits in), the files a config names, the devices and dtypes,
  and the grid's and the sweep's lists (names of config files, IORs inside ``object.ior_range``,
  the sweep's axes).
- **Names.** ``experiment_name`` (and every other name that becomes a folder,
  :mod:`snell_bench.config.names`) is one folder name: nothing is written outside ``runs_dir``
  and ``reports_dir``. The folders themselves are checked writable by
  :func:`snell_bench.config.preflight.check_output_folders`.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import re
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import InterpolationResolutionError, OmegaConfBaseException

from snell_bench.config.camera import MAX_FOV_DEG, fov_problem, intrinsics_problem
from snell_bench.config.choices import DTYPE_NAMES, METHOD_KINDS, Job, Source, dtype_name
from snell_bench.config.compose import plugin_methods
from snell_bench.config.errors import ConfigError, Problems, is_int, is_number
from snell_bench.config.grid_checks import check_grid_entries
from snell_bench.config.names import folder_name_problem
from snell_bench.config.sampler import SamplerSettings
from snell_bench.config.schema import CHECKED_NODES, Config
from snell_bench.utils.paths import data_path

__all__ = [
    "ConfigError",
    "check_config",
    "unknown_keys",
    "max_levels",
    "check_grid_entries",
]

# ---------------------------------------------------------------------------- unknown keys
#: Nodes that override another node's schema: their keys must be keys of that node.
_OVERRIDE_NODES = {"method.sampler": "sampler", "method.warps": "warps"}
#: Keys outside the schema that a composed config may carry.
_RUNTIME_KEYS = {"hydra"}


def _is_structured(node: Any) -> bool:
    return isinstance(node, DictConfig) and dataclasses.is_dataclass(OmegaConf.get_type(node))


def _child(node: DictConfig, key: Any) -> Any:
    """``node[key]`` as written: ``None`` for a missing value or an interpolation (never resolved here)."""
    return None if OmegaConf.is_missing(node, key) or OmegaConf.is_interpolation(node, key) else node[key]


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
        sub_schema = root_schema[_OVERRIDE_NODES[path]] if path in _OVERRIDE_NODES else _child(schema, key)
        value = _child(node, key)
        if (path in _OVERRIDE_NODES or _is_structured(sub_schema)) and isinstance(value, DictConfig):
            _unknown(value, sub_schema, f"{path}.", out, root_schema)


def unknown_keys(cfg: DictConfig) -> list[str]:
    """One line per key of ``cfg`` that no schema knows (``+warps.max_bounce=1``: a typo), each
    naming the closest known key."""
    schema = OmegaConf.structured(Config)
    out: list[str] = []
    node = cfg
    if any(k in _RUNTIME_KEYS for k in cfg.keys()):
        node = OmegaConf.masked_copy(cfg, [k for k in cfg.keys() if k not in _RUNTIME_KEYS])
    _unknown(node, schema, "", out, schema)
    return out


# ---------------------------------------------------------------------------- values
def _get(cfg: DictConfig, key: str) -> Any:
    return OmegaConf.select(cfg, key, throw_on_missing=False)


def max_levels(height: int, width: int) -> int:
    """The most Laplacian-pyramid levels the sampler can use on an image of this size: every level
    halves it, and the coarsest keeps at least 2 pixels a side (the 5-tap blur of ``pyrup``
    reflects 2 pixels at each border: 96 px allow 6 levels, 720 px 9)."""
    return max(1, int(min(height, width)).bit_length() - 1)


def _with_method(cfg: DictConfig, name: str, out: list[str]) -> DictConfig | None:
    """The node ``name`` (``warps``, ``sampler``) with the method's overrides of it
    (``method.<name>``) merged in, as the method runs it; ``None`` (and a line naming
    ``method.<name>.<key>``) where an override does not fit the key's type."""
    try:
        return OmegaConf.merge(cfg[name], _get(cfg, f"method.{name}") or {})
    except OmegaConfBaseException as e:
        key = f"method.{name}.{e.key}" if getattr(e, "key", None) is not None else f"method.{name}"
        value = _get(cfg, key) if getattr(e, "key", None) is not None else None
        first = str(getattr(e, "msg", e)).splitlines()[0]
        out.append(
            f"{key}={value!r}: {first} (method={_get(cfg, 'method.name')} overrides {name}.{e.key} with it); give a "
            f"value of the type of {name}.{e.key}"
        )
        return None


def _nodes(cfg: DictConfig, out: list[str]) -> None:
    """Each node's own ranges (its dataclass's ``__post_init__``) and the root's settings: the
    seed, the experiment's name (a folder name: ``<runs_dir>/<experiment_name>/``, its log
    ``<experiment_name>.log``) and the output folders' names."""
    p = Problems()
    p.seed("seed", _get(cfg, "seed"))
    p.append_if(folder_name_problem(_get(cfg, "experiment_name"), "experiment_name", suffix=".log"))
    for key in ("runs_dir", "reports_dir"):
        value = _get(cfg, key)
        if not isinstance(value, str) or not value.strip():
            p.append(f"{key}={value!r}: must be a folder; e.g. {key}={key.removesuffix('_dir')}")
    out += p
    for name in CHECKED_NODES:
        node = cfg.get(name)
        if not isinstance(node, DictConfig):
            continue
        if name == "warps":  # with the method's switches applied, as the method traces them
            node = _with_method(cfg, "warps", out)
            if node is None:
                continue
        try:
            OmegaConf.to_object(node)
        except ConfigError as e:
            out += e.problems
        except InterpolationResolutionError as e:  # e.g. a prompt without its [[object phrase]]
            out.append(f"{e.full_key}: {e.__cause__ or e}")


def _sizes(cfg: DictConfig, out: list[str]) -> None:
    """The image and the panorama sizes against the generator's block (``model.multiple``): the
    generator samples the ``warps.pano_height x 2 warps.pano_height`` panorama too, so both of
    its sides must be multiples of the block (a preview only traces: any height)."""
    mult = _get(cfg, "model.multiple")
    if not is_int(mult) or mult < 1:
        return  # the model node's own check names it
    pano = _get(cfg, "warps.pano_height")
    method_pano = (_get(cfg, "method.warps") or {}).get("pano_height")
    key = "warps.pano_height" if method_pano is None else "method.warps.pano_height"
    pano = pano if method_pano is None else method_pano
    if _get(cfg, "job") != Job.preview and is_int(pano) and pano >= 2 and pano % mult:
        lo, hi = pano // mult * mult, (pano // mult + 1) * mult
        use = " or ".join(f"{key}={h} ({h}x{2 * h})" for h in (lo, hi) if h >= mult)
        out.append(
            f"{key}={pano}: the {pano}x{2 * pano} panorama ({key} x 2 {key}) must have sides that are multiples of "
            f"model.multiple={mult}, the block of the generator (model={_get(cfg, 'model.name')}) that samples it; "
            f"use {use}"
        )
    max_side = _get(cfg, "scene.max_side")
    if _get(cfg, "scene.source") == Source.image and is_int(max_side) and 1 <= max_side < mult:
        out.append(
            f"scene.max_side={max_side}: the photo's sides are cropped to multiples of model.multiple={mult} after "
            f"the resize, so its longer side needs at least {mult} pixels; e.g. scene.max_side={max(mult * 80, 1280)} "
            "or null"
        )
    if _get(cfg, "scene.source") in (Source.procedural, Source.generated):
        for key in ("scene.width", "scene.height"):
            v = _get(cfg, key)
            if not is_int(v) or v < mult:
                out.append(f"{key}={v!r}: must be a positive multiple of model.multiple={mult}; e.g. {key}={mult * 40}")
            elif v % mult:
                lo, hi = v // mult * mult, (v // mult + 1) * mult
                out.append(
                    f"{key}={v}: the generator (model={_get(cfg, 'model.name')}) needs multiples of "
                    f"model.multiple={mult}; use {key}={lo if lo else hi} or {key}={hi}"
                )


def _files(cfg: DictConfig, out: list[str]) -> None:
    """The input files a config names: there, and files rather than folders."""

    def need(key: str, what: str, why: str) -> None:
        value = _get(cfg, key)
        if not value:
            out.append(f"{why} needs {key}: set {key}=PATH ({what})")
            return
        try:
            data_path(value, key, what)
        except OSError as e:
            out.append(str(e))

    factory = _get(cfg, "object.factory")
    if isinstance(factory, DictConfig) and "path" in factory:
        need("object.path", "mesh file (.ply/.obj/.glb/.stl)", f"object={_get(cfg, 'object.name')} reads a mesh file:")
    if _get(cfg, "scene.source") == Source.image:
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
    blender = _get(cfg, "reference.blender_python")
    if blender and str(_get(cfg, "reference.renderer")) == "cycles" and not os.access(str(blender), os.X_OK):
        out.append(
            f"reference.blender_python={str(blender)!r}: not an executable (the Python with Blender's bpy that renders "
            "the Cycles reference); fix the path, or set it to null for the one `make setup-cycles` installs"
        )
    color = _get(cfg, "object.absorption.color")
    tinted = color is not None and any(v != 1 for v in color)
    if tinted and str(_get(cfg, "reference.renderer")) == "cycles" and _get(cfg, "reference.enabled"):
        out.append(
            f"object.absorption.color={list(color)}: the Cycles reference (the authors' scene) has no absorbing glass; "
            "use reference.renderer=mitsuba (an absorbing interior medium), or a clear object.absorption.color=[1,1,1]"
        )
    target = str(factory.get("_target_", "")) if isinstance(factory, DictConfig) else ""
    if target.startswith("snell_bench.scene.vessels.") and str(_get(cfg, "reference.renderer")) == "cycles":
        if _get(cfg, "reference.enabled"):
            out.append(
                f"object={_get(cfg, 'object.name')} is made of several media ({target}): the Cycles reference (the "
                "authors' scene) has one glass; use reference.renderer=mitsuba (one surface per interface)"
            )
    bench = _get(cfg, "plan.bench")
    if bench and not Path(str(bench)).is_file():
        out.append(
            f"plan.bench={str(bench)!r}: no such file (the figures of benchmarks/bench_gpu.py --json); fix the path, "
            "or set plan.bench=null for the documented basis (docs/gpu.md)"
        )
    segmenter = _get(cfg, "segment.segmenter")
    if isinstance(segmenter, DictConfig) and str(segmenter.get("_target_", "")).endswith("MaskFileSegmenter"):
        need("segment.mask", "a PNG mask file, nonzero on the surface", f"segment={_get(cfg, 'segment.name')}")


def _scene_models(cfg: DictConfig, out: list[str]) -> None:
    """A generated scene's models: a text-to-image generator (not one built from a scene) and a
    depth estimator (what ``model=tiny_flux`` or ``model=flux_dev`` selects for the paper's prompts)."""
    if _get(cfg, "scene.source") != Source.generated:
        return
    model = _get(cfg, "model.name")
    if _get(cfg, "model.from_scene"):
        out.append(
            f"scene.source=generated needs a text-to-image generator; model={model} is built from the scene itself: "
            "use model=tiny_flux (CPU, random weights) or model=flux_dev (GPU), or scene.source=procedural"
        )
    if not _get(cfg, "depth.estimator") and not _get(cfg, "scene.depth"):
        out.append(
            f"scene.source=generated (the paper's scene pipeline, which model={model} selects) needs a depth "
            "estimator for I⁻: set depth=moge2 (GPU, weights), or depth=tiny_depth_pro segment=tiny_sam3 (CPU, "
            "random weights); or name the procedural stand-in with scene.source=procedural"
        )


def _image_width(cfg: DictConfig) -> tuple[int, str] | None:
    """The width in pixels that ``scene.intrinsics`` are given in, and how to name it: the photo
    file's as stored (its header, no pixel decoded) or ``scene.width``; ``None`` where the photo
    cannot be read (:func:`_files` and the photo's own checks say why)."""
    if _get(cfg, "scene.source") != Source.image:
        width = _get(cfg, "scene.width")
        return (width, "scene.width") if is_int(width) and width >= 1 else None
    from PIL import Image

    image = _get(cfg, "scene.image")
    try:
        with Image.open(data_path(image, "scene.image", "image file")) as im:
            return int(im.size[0]), f"scene.image={str(image)!r}"
    except (OSError, ValueError, TypeError, SyntaxError, Image.DecompressionBombError):
        return None


def _implied_fov(cfg: DictConfig, intrinsics: Any, out: list[str]) -> None:
    """The horizontal field of view that ``scene.intrinsics`` imply over the image's width, in
    the range of ``scene.fov_deg`` (:func:`~snell_bench.config.camera.intrinsics_problem`)."""
    k = list(intrinsics) if isinstance(intrinsics, (list, tuple)) or OmegaConf.is_list(intrinsics) else None
    if k is None or len(k) != 4 or not all(is_number(v) and math.isfinite(v) for v in k) or not k[0] > 0:
        return  # the scene node's own check names it
    width = _image_width(cfg)
    if width is None:
        return
    size, rel = _get(cfg, "object.size"), _get(cfg, "object.relative_size")
    rel = rel if size is None and is_number(rel) and math.isfinite(rel) and rel > 0 else None
    problem = intrinsics_problem(k, width[0], rel, width[1])
    if problem:
        out.append(problem)


def _camera(cfg: DictConfig, out: list[str]) -> None:
    """The camera of a photo or a generated scene: one of ``scene.intrinsics`` and
    ``scene.fov_deg`` (a photo with a depth file needs one), and a field of view in which the
    object at its default size fits, given or implied by the intrinsics over the image's width
    (:mod:`snell_bench.config.camera`). A procedural scene has
    its camera: a preview or a generation of one would ignore either setting, so neither may be
    set (a sweep's settings apply to all its scenes, photos among them)."""
    source = _get(cfg, "scene.source")
    fov, intrinsics = _get(cfg, "scene.fov_deg"), _get(cfg, "scene.intrinsics")
    if source not in (Source.image, Source.generated):  # a procedural scene has its own camera
        if _get(cfg, "job") not in (Job.preview, Job.generate):
            return  # a sweep's cells have scenes of their own, each checked when it is composed
        for key, value in (("scene.fov_deg", fov), ("scene.intrinsics", intrinsics)):
            if value is not None and not any(line.startswith(f"{key}=") for line in out):  # once per key
                out.append(
                    f"{key}={value!r}: scene.source={source} renders with its own camera and would ignore it; it is "
                    f"for a photo or a generated scene (scene.source=image or generated): set {key}=null"
                )
        return
    if fov is not None and intrinsics is not None:
        out.append(
            f"scene.fov_deg={fov!r} and scene.intrinsics={list(intrinsics)!r} are both set: the camera takes one; "
            "set scene.fov_deg=null (the intrinsics) or scene.intrinsics=null (the field of view)"
        )
    elif source == Source.image and _get(cfg, "scene.depth") and fov is None and intrinsics is None:
        out.append(
            "scene.source=image with scene.depth needs the camera: set scene.intrinsics=[fx,fy,cx,cy] (pixels of the "
            "image file) or scene.fov_deg (the horizontal field of view in degrees, e.g. scene.fov_deg=60)"
        )
    elif intrinsics is not None:
        _implied_fov(cfg, intrinsics, out)
    size, rel = _get(cfg, "object.size"), _get(cfg, "object.relative_size")
    if is_number(fov) and 0 < fov <= MAX_FOV_DEG and size is None and is_number(rel) and math.isfinite(rel) and rel > 0:
        problem = fov_problem(fov, rel)
        if problem:
            out.append(problem)


#: A line of :class:`SamplerSettings` about one key: ``sampler.<key>...``.
_SAMPLER_LINE = re.compile(r"^sampler\.(\w+)")


def _sampler(cfg: DictConfig, out: list[str]) -> None:
    """The sampler with the method's switches applied (its own ranges), and its pyramid against
    the image and the panorama. A bad value the method sets is named ``method.sampler.<key>``."""
    node = _with_method(cfg, "sampler", out)
    if node is None:
        return
    by_method = set(map(str, (_get(cfg, "method.sampler") or {}).keys()))
    try:
        s = SamplerSettings(**OmegaConf.to_container(node, resolve=True))
    except ConfigError as e:
        for line in e.problems:
            m = _SAMPLER_LINE.match(line)
            if m and m.group(1) in by_method:
                line = f"method.{line} (method={_get(cfg, 'method.name')} sets it)"
            out.append(line)
        return
    except (ValueError, TypeError) as e:
        out.append(str(e))
        return
    limits = []  # (levels, what limits them)
    h, w = _get(cfg, "scene.height"), _get(cfg, "scene.width")
    if (
        _get(cfg, "scene.source") in (Source.procedural, Source.generated)
        and is_int(h)
        and is_int(w)
        and h > 0
        and w > 0
    ):
        limits.append((max_levels(h, w), f"the {h}x{w} image (scene.height x scene.width)"))
    pano = (_get(cfg, "method.warps") or {}).get("pano_height", _get(cfg, "warps.pano_height"))
    if s.uses_panorama and is_int(pano) and pano > 1:
        limits.append((max_levels(pano, 2 * pano), f"the {pano}x{2 * pano} panorama (warps.pano_height)"))
    if limits:
        most, what = min(limits)
        if s.effective_levels > most:
            out.append(
                f"sampler.levels={s.levels}: {what} has at most {most} pyramid levels (each halves it, the "
                f"coarsest keeps 2 pixels); use sampler.levels={min(5, most)} (1 to {most}) or a larger size"
            )


def _devices(cfg: DictConfig, out: list[str]) -> None:
    """Devices named explicitly must exist here (``null`` / ``auto``: CUDA when available, which a
    method that needs it reports as skipped); dtypes must be known."""
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
            dtype_name(dtype)
        except KeyError:
            out.append(
                f"model.dtype={dtype!r} is unknown; use one of {list(DTYPE_NAMES)} (or null: the device's default)"
            )


def _method(cfg: DictConfig, out: list[str]) -> None:
    """``method.kind`` names a built-in kind or an installed plugin's (the ``snell_bench.methods``
    entry points), unless ``method._target_`` names the class; ``method._target_`` imports. (The
    class itself is checked when the grid is planned, :func:`snell_bench.methods.method_of`.)"""
    kind, target = _get(cfg, "method.kind"), _get(cfg, "method._target_")
    if target:
        from hydra.utils import get_class

        try:
            get_class(str(target))
        except Exception as e:  # noqa: BLE001 - an import error of the user's package, said with the key
            first = str(e).splitlines()[0] if str(e) else type(e).__name__
            out.append(
                f"method._target_={target!r} cannot be imported ({first}); give the dotted path of a "
                "snell_bench.methods.Method subclass in an installed package (my_pkg.methods.MyMethod)"
            )
        return
    installed = sorted(plugin_methods())  # the installed plugins' kinds (read once per process)
    if str(kind) not in (*METHOD_KINDS, *installed):
        out.append(
            f"method.kind={kind!r} is unknown; use one of {[*METHOD_KINDS, *installed]} (installed plugins add "
            "theirs), or set method._target_ to a snell_bench.methods.Method subclass"
        )


def _metrics(cfg: DictConfig, out: list[str]) -> None:
    """``metrics.extra`` lists names (installed metrics, the ``snell_bench.metrics`` entry points) or
    dotted paths. (Each is loaded when the grid is planned.)"""
    extra = _get(cfg, "metrics.extra") or []
    for i, entry in enumerate(extra):
        if not isinstance(entry, str) or not entry.strip():
            out.append(f"metrics.extra[{i}]={entry!r}: name an installed metric or a dotted path (my_pkg.metrics:SSIM)")


def check_config(cfg: DictConfig, *, grid: bool | None = None) -> DictConfig:
    """Raise :class:`ConfigError` listing every unknown key and unusable value of ``cfg``.

    The choices (``scene.source``, ``job``, ...) were checked when ``cfg`` was composed (they are
    enums of the schema); this checks each node's ranges (its dataclass), the values that depend on
    other nodes, the files the config names, the devices, and the grid's and the sweep's lists.

    Args:
        cfg: a composed config (the ``hydra`` node may be present).
        grid: also check the ``grid`` lists' entries (default: when ``job=grid``).

    Returns:
        ``cfg``, unchanged.
    """
    problems = unknown_keys(cfg)
    if problems:  # a value check may trip over an unknown key's node
        raise ConfigError(problems)
    for check in (_nodes, _sizes, _camera, _scene_models, _files, _sampler, _devices, _method, _metrics):
        check(cfg, problems)
    job = _get(cfg, "job")
    if grid if grid is not None else job == Job.grid:
        problems += check_grid_entries(cfg)
    if problems:
        raise ConfigError(problems)
    return cfg
