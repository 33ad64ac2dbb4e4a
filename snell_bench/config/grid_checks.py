"""Checks of the grid's lists (``grid.scenes``, ``grid.variations``, ``grid.objects``,
``grid.methods``) and of its named override sets (``grid.axes``, ``grid.only``,
``grid.presets``): names of config files, no repeats, variations that seed, IORs inside
``object.ior_range``, folder names a file system takes. Part of
:func:`snell_bench.config.checks.check_config`, which runs them for ``job=grid``.
"""

from __future__ import annotations

from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf

from snell_bench.config.compose import searchpath_overrides
from snell_bench.config.errors import MAX_SEED, is_int
from snell_bench.config.grid import (
    axis_settings,
    check_names,
    check_unique,
    grid_settings,
    object_dir_name,
    parse_object_spec,
)
from snell_bench.config.materials import MATERIALS, ior_out_of_range, ior_range_problem, resolve_ior
from snell_bench.config.names import NAME_MAX, folder_name_problem, setting_slug

__all__ = ["check_grid_entries"]


def _get(cfg: DictConfig, key: str) -> Any:
    return OmegaConf.select(cfg, key, throw_on_missing=False)


def check_grid_entries(cfg: DictConfig) -> list[str]:
    """Problems of ``grid.variations`` and ``grid.objects`` entries (integers >= 0; object specs
    ``name`` or ``name:ior`` with a number or a material name)."""
    out: list[str] = []
    g = cfg.grid
    for key in ("scenes", "variations", "objects", "methods"):
        if not isinstance(g.get(key), ListConfig) or len(g.get(key)) == 0:
            out.append(f"grid.{key}={g.get(key)!r}: must be a non-empty list, e.g. grid.{key}=[...]")
    if out:
        return out
    for group, key, names in (
        ("method", "grid.methods", list(g.methods)),
        ("scene", "grid.scenes", list(g.scenes)),
        ("object", "grid.objects", [parse_object_spec(o)[0] for o in g.objects]),
    ):
        try:
            check_names(group, names, key, _searchpath(cfg))
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
        if not is_int(v) or not 0 <= v <= MAX_SEED:
            out.append(
                f"grid.variations: entry {v!r} is not an integer >= 0 (a variation seeds its scene; at most 2**63 - 1); "
                "e.g. grid.variations=[0,1,2]"
            )
    ior_range = _get(cfg, "object.ior_range")
    for spec in g.objects:
        name, ior = parse_object_spec(spec)
        if ior is not None:
            try:
                value = resolve_ior(ior)
            except ValueError:
                out.append(
                    f"grid.objects: entry {str(spec)!r}: {ior!r} is neither a number (the IOR) nor a material; "
                    f"write {name}:1.45 or {name}:<material> with one of {sorted(MATERIALS)}"
                )
                continue
            if ior_range_problem(ior_range) is None:
                problem = ior_out_of_range(value, ior_range)
                if problem:
                    out.append(f"grid.objects: entry {str(spec)!r}: IOR {value:g} is {problem}")
        folder = folder_name_problem(object_dir_name(str(spec)), f"grid.objects entry {str(spec)!r}", example=name)
        if folder:
            out.append(folder)
    return out + _settings_problems(cfg)


def _settings_problems(cfg: DictConfig) -> list[str]:
    """Problems of the grid's named override sets: ``only`` (names of ``axes``), each axis
    (:func:`_axis_problems`), the presets (known, no repeats) and the settings as a whole
    (:func:`~snell_bench.config.grid.grid_settings`: reserved names, repeated labels)."""
    g, out = cfg.grid, []
    presets = [str(x) for x in (g.get("presets") or [])]
    try:
        check_names("preset", presets, "grid.presets", _searchpath(cfg))
        check_unique(presets, "grid.presets")
    except ValueError as e:
        out.append(str(e))
    axes = OmegaConf.to_container(g.axes, resolve=True) if isinstance(g.get("axes"), DictConfig) else {}
    if g.get("only") is not None:
        unknown = [str(a) for a in g.only if str(a) not in axes]
        if unknown:
            return [*out, f"grid.only: unknown axes {unknown}; choose from {list(axes)}"]
    ior_range = _get(cfg, "object.ior_range") if ior_range_problem(_get(cfg, "object.ior_range")) is None else None
    for name in [str(a) for a in g.only] if g.get("only") is not None else list(axes):
        out += _axis_problems(name, axes[name], ior_range)
    if not out:
        try:
            grid_settings(g)
        except ValueError as e:
            out.append(str(e))
    return out


def _axis_problems(name: str, spec: Any, ior_range) -> list[str]:
    """Problems of one axis of the grid (``grid.axes``): its form (:func:`~snell_bench.config.grid.axis_settings`),
    its settings' folder names (``<axis>=<value>``, at most :data:`~snell_bench.config.names.NAME_MAX`
    bytes) and any IOR it sweeps (``object.ior=...``, inside ``object.ior_range``)."""
    try:
        settings = axis_settings(name, spec)
    except ValueError as e:
        return [str(e)]
    out = []
    for label, overrides in settings:
        slug = setting_slug(label)
        if len(slug.encode()) > NAME_MAX:
            out.append(
                f"grid.axes.{name}: the setting {label[:40]!r}... names a folder of {len(slug.encode())} bytes, "
                f"longer than the {NAME_MAX} a file system takes; give it a shorter label (a mapping label -> "
                "[override, ...])"
            )
        for override in overrides:
            key, _, value = override.partition("=")
            if key.lstrip("+~") != "object.ior":
                continue
            try:
                ior = resolve_ior(value.strip().strip("'\""))
            except ValueError as e:
                out.append(f"grid.axes.{name}: {override!r}: {e}")
                continue
            problem = ior_out_of_range(ior, ior_range) if ior_range is not None else None
            if problem:
                out.append(f"grid.axes.{name}: {override!r}: IOR {ior:g} is {problem}")
    return out


def _searchpath(cfg: DictConfig) -> list[str]:
    """The run's ``hydra.searchpath`` as an override: from its recorded ``overrides`` (a composed
    config), else from its ``hydra`` node (the config Hydra's callbacks see)."""
    found = searchpath_overrides(cfg.get("overrides") or [])
    paths = OmegaConf.select(cfg, "hydra.searchpath", default=None) if "hydra" in cfg else None
    if not found and paths:
        found = ["hydra.searchpath=[" + ",".join(str(p) for p in paths) + "]"]
    return found
