"""Composing the cells of a sweep with Hydra.

A cell's config is composed like a command line: the run's own overrides (``cfg.overrides``)
followed by the cell's (``scene=kitchen scene.variation=2 object=sphere object.ior=1.333
method=no_dpa``, or a sweep setting's ``sampler.steps=8``), so defaults lists are honoured, the
schema is kept, and later overrides win. The method's switches are then applied
(:func:`snell_bench.pipeline.apply_method`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from omegaconf import DictConfig, OmegaConf

from snell_bench.config import ConfigError, check_config, compose, config_context
from snell_bench.config.grid import check_names, object_dir_name, object_overrides, parse_object_spec
from snell_bench.pipeline import apply_method
from snell_bench.utils.io import json_hash

__all__ = [
    "parse_object_spec",
    "object_overrides",
    "object_dir_name",
    "check_names",
    "check_reproducible",
    "compose_cell",
    "NOT_RESULT_KEYS",
    "RESULT_KEYS_WHERE_SET",
    "result_settings",
    "settings_hash",
    "settings_diff",
]

#: Keys that do not change a cell's result (left out when comparing configs).
_NOT_RESULTS = ("output_dir", "overrides")

#: Keys that do not change a cell's result, left out of its settings (:func:`result_settings`):
#: where it is written, which cells the sweep lists, how progress is shown, caches, labels.
NOT_RESULT_KEYS = (
    "hydra",
    "job",
    "output_dir",
    "overrides",
    "experiment_name",
    "runs_dir",
    "reports_dir",
    "grid",
    "tradeoff",
    "plan",
    "export",
    "sampler.progress",
    "sampler.dump_every",
    "warps.cache_dir",
    "scene.cache_dir",
    "method.label",
    "method.images",
    "method.images_column",
    "method.kit",
    "method.cost",
    "models",
    "tracker",
    "object.ior_range",
    "object.licence",
    "scene.licence",
    "object.allow_self_intersecting",
)

#: Keys under :data:`NOT_RESULT_KEYS` that do change a cell's result where they are set (not
#: null): ``grid.converged_spp`` adds the cell's ``*_converged`` scores.
RESULT_KEYS_WHERE_SET = ("grid.converged_spp",)


def result_settings(cfg: DictConfig) -> dict[str, Any]:
    """Every setting of ``cfg`` that can change a cell's result, resolved and flattened to
    ``{"sampler.steps": 20, "scene.width": 1280, ...}`` (lists kept as values); the keys of
    :data:`NOT_RESULT_KEYS` left out. A cell's identity is its folder; these are what it was
    computed with (:func:`settings_hash`).

    Each top-level node is resolved against the whole config (so a result setting that
    interpolates one that is not, such as ``object.factory``'s ``${object.allow_self_intersecting}``,
    resolves), then the keys of :data:`NOT_RESULT_KEYS` are dropped (but those of
    :data:`RESULT_KEYS_WHERE_SET` that are set); a node that cannot resolve is kept as written."""
    plain = OmegaConf.to_container(cfg, resolve=False, enum_to_str=True)
    c = OmegaConf.create(plain)  # untyped, every key kept: a result setting may interpolate any other
    values: dict[str, Any] = {}
    for key in plain:
        if key in NOT_RESULT_KEYS:
            continue  # never resolved (``output_dir`` reads Hydra's runtime)
        try:
            value = c[key]  # a subtree is resolved below, against the whole config
            values[key] = OmegaConf.to_container(value, resolve=True) if OmegaConf.is_config(value) else value
        except Exception:  # noqa: BLE001 - a value that cannot resolve fails its cell, which says why
            values[key] = plain[key]
    kept = {
        k: v for k, v in flatten(values).items() if not any(k == n or k.startswith(f"{n}.") for n in NOT_RESULT_KEYS)
    }
    for key in RESULT_KEYS_WHERE_SET:
        value = OmegaConf.select(cfg, key, default=None)
        if value is not None:
            kept[key] = value
    return kept


def flatten(d: dict, prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}, "c": []}`` -> ``{"a.b": 1, "c": []}`` (empty dicts and lists kept as values)."""
    flat: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict) and v:
            flat.update(flatten(v, f"{prefix}{k}."))
        else:
            flat[f"{prefix}{k}"] = v
    return flat


def settings_hash(settings: dict[str, Any]) -> str:
    """A short content hash of :func:`result_settings` (order-independent)."""
    return json_hash(settings)


#: What :func:`settings_diff` reports for a key only one side has.
ABSENT = "<absent>"


def settings_diff(old: dict[str, Any], new: dict[str, Any]) -> dict[str, tuple[Any, Any]]:
    """``{key: (old value, new value)}`` of every key whose value differs (:data:`ABSENT` for a
    key only one side has)."""
    return {
        k: (old.get(k, ABSENT), new.get(k, ABSENT))
        for k in sorted(set(old) | set(new), key=str)
        if old.get(k, ABSENT) != new.get(k, ABSENT)
    }


def _comparable(cfg: DictConfig) -> dict:
    d = OmegaConf.to_container(cfg, resolve=False, enum_to_str=True)
    for k in _NOT_RESULTS:
        d.pop(k, None)
    return _nan_equal(d)


#: What a NaN compares as in :func:`_comparable` (NaN != NaN, but the same setting is the same).
_NAN = "<nan>"


def _nan_equal(value: Any) -> Any:
    """``value`` with every float NaN replaced by :data:`_NAN`, so that two configs holding NaN at
    the same key compare equal (the value itself is checked by :func:`check_config`)."""
    if isinstance(value, dict):
        return {k: _nan_equal(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_nan_equal(v) for v in value]
    if isinstance(value, float) and math.isnan(value):
        return _NAN
    return value


def check_reproducible(cfg: DictConfig) -> None:
    """Raise ``ValueError`` unless composing ``cfg.overrides`` gives ``cfg`` again: the cells of a
    sweep are composed from the overrides, so a change made to the object afterwards would be
    lost silently.

    Any value compares (NaN equals NaN at the same key); overrides that no longer compose (a
    config file removed since) raise ``ValueError`` naming them, never another exception.
    """
    overrides = [str(o) for o in (cfg.get("overrides") or [])]
    try:
        again = compose(overrides)
    except Exception as e:  # noqa: BLE001 - Hydra's composition errors, reported with the overrides
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ValueError(
            f"the config's overrides {overrides} do not compose again ({first}); give every setting as an override "
            "that composes (snell_bench.config.compose([...]) or the command line)"
        ) from None
    a, b = _comparable(cfg), _comparable(again)
    if a != b:
        diff = list(settings_diff(flatten(a), flatten(b)))
        raise ValueError(
            f"the config differs from what its overrides {overrides} compose, at {diff}; give every "
            "setting as an override (snell_bench.config.compose([...]) or the command line)"
        )


def compose_cell(cfg: DictConfig, overrides: Sequence[str], *, method: bool = True) -> DictConfig:
    """The config of one cell: ``cfg.overrides`` then ``overrides``, composed; with ``method``
    the method's switches applied."""
    with config_context():
        c = compose([*cfg.overrides, *overrides])
    try:
        check_config(c, grid=False)  # every cell's settings checked before any work
    except ConfigError as e:
        raise ConfigError([f"cell {' '.join(map(str, overrides))}: {p}" for p in e.problems]) from None
    return apply_method(c) if method else c
