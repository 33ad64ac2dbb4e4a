"""Composing configs from the package's config groups, as ``python -m snell_bench`` does.

The ``prompts`` resolver (``${prompts:${.text},minus,...}``) decomposes a scene's marked prompt into
p, p⁻, p³⁶⁰, the object phrase and the surface (:mod:`snell_bench.scene.prompt_rules`, or a local
language model, :mod:`snell_bench.scene.prompt_llm`): the one place where the config imports from
a stage package.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from importlib.metadata import entry_points
from typing import Any, Optional

from hydra import compose as hydra_compose
from hydra import initialize_config_module
from hydra.core.config_store import ConfigStore
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig, OmegaConf

from snell_bench.config.choices import METHOD_ENTRY_POINTS, METHOD_KINDS, SWEEP_JOBS
from snell_bench.config.schema import (
    Config,
    DepthConfig,
    MethodConfig,
    ModelConfig,
    ObjectConfig,
    SceneConfig,
    SegmentConfig,
)

log = logging.getLogger(__name__)

__all__ = [
    "CONFIG_MODULE",
    "config_context",
    "compose",
    "group_options",
    "plugin_methods",
    "register_configs",
    "searchpath_overrides",
]

CONFIG_MODULE = "snell_bench.conf"


@contextmanager
def config_context() -> Iterator[None]:
    """Hydra's global state for composing: the running application's when there is one, else
    the package's config groups (:data:`CONFIG_MODULE`) for the duration of the block."""
    register_configs()
    if GlobalHydra.instance().is_initialized():
        yield
    else:
        with initialize_config_module(config_module=CONFIG_MODULE, version_base="1.3"):
            yield


def compose(overrides: Sequence[str] = (), config_name: str = "config") -> DictConfig:
    """The config ``python -m snell_bench OVERRIDES`` would run, composed with Hydra from the
    config groups shipped in :mod:`snell_bench.conf` (defaults lists honoured, schema kept).

    Inside a running Hydra application its search path is used; elsewhere the package's. The
    overrides are recorded in ``cfg.overrides``.

    Args:
        overrides: Hydra override strings, e.g. ``["+experiment=smoke", "scene.width=320"]``.
        config_name: the primary config.

    Returns:
        The composed config (struct mode on).
    """
    overrides = [str(o) for o in overrides]
    with config_context():
        cfg = hydra_compose(config_name=config_name, overrides=overrides)
    cfg.overrides = overrides
    return cfg


def searchpath_overrides(overrides: Sequence[str]) -> list[str]:
    """The ``hydra.searchpath=[...]`` overrides among ``overrides``: a user's own config folders
    (``hydra.searchpath=[file://my_conf]``), which every composition of a run's cells needs."""
    return [str(o) for o in overrides if str(o).lstrip("+").startswith("hydra.searchpath=")]


def group_options(group: str, overrides: Sequence[str] = ()) -> list[str]:
    """The names a config group offers (``conf/<group>/*.yaml``, registered nodes, installed
    plugins' methods, and the group's files in the config folders of ``overrides``'
    ``hydra.searchpath``)."""
    with config_context():
        names = (
            GlobalHydra.instance()
            .config_loader()
            .get_group_options(group, config_name="config", overrides=searchpath_overrides(overrides))
        )
    return sorted(n for n in names if not n.startswith("base_"))


def _prompts(text: str, field: str, llm: Optional[str] = None) -> str:
    """The ``prompts`` resolver: one field of the decomposition of a marked prompt (or of one a
    local language model marks, ``scene.prompt_llm``)."""
    # imported on the first prompt resolved, so that importing the config does not load the
    # scene package (Open3D, trimesh) and the models package it imports
    from snell_bench.scene.prompt_llm import decompose_with_llm
    from snell_bench.scene.prompt_rules import decompose

    if llm and "[[" not in str(text):
        return getattr(decompose_with_llm(str(text), model_path=str(llm)), field)
    return getattr(decompose(str(text)), field)


def _run_dir(job: str, runs_dir: str, experiment: str, cell: str, now: str) -> str:
    """The ``run_dir`` resolver (``hydra.run.dir``): ``<runs_dir>/<experiment>/logs/<now>`` for a
    sweep, whose cells have folders of their own, else ``<runs_dir>/<job>/<scene>-<variation>/<object>``
    (a preview or a generation writes its files there)."""
    if str(job) in SWEEP_JOBS:
        return f"{runs_dir}/{experiment}/logs/{now}"
    return f"{runs_dir}/{job}/{cell}"


@functools.lru_cache(maxsize=1)
def plugin_methods() -> dict[str, MethodConfig]:
    """A method config for each method kind an installed package adds (an entry point of the group
    ``snell_bench.methods``): ``name``, ``kind`` and ``label`` (the class's ``default_label``, else
    the name), so that ``method=<name>`` and ``grid.methods=[..., <name>]`` select it with no YAML.
    A plugin that does not load is left out with a warning (``method.kind`` names it when asked)."""
    out = {}
    for ep in entry_points(group=METHOD_ENTRY_POINTS):
        if ep.name in METHOD_KINDS:
            continue
        try:
            label = getattr(ep.load(), "default_label", "") or ep.name
        except Exception as e:  # noqa: BLE001 - a broken plugin must not stop other runs
            log.warning("the method plugin %s (%s) does not load: %s: %s", ep.name, ep.value, type(e).__name__, e)
            continue
        out[ep.name] = MethodConfig(name=ep.name, label=str(label), kind=ep.name)
    return out


def _shard_sweep(shards: Any) -> str:
    """The sweep of ``grid.shard`` a multirun makes (``hydra.sweeper.params``): one job per shard
    when ``grid.shards`` is 2 or more, else the single unsharded job.

    Examples:
        >>> _shard_sweep(3), _shard_sweep(1)
        ('range(0,3)', 'null')
    """
    n = int(shards) if isinstance(shards, int) or str(shards).isdigit() else 1
    return f"range(0,{n})" if n >= 2 else "null"


def register_configs() -> None:
    """Register the schema with Hydra's ConfigStore and the ``prompts``, ``run_dir`` and
    ``shard_sweep`` resolvers (idempotent)."""
    if not OmegaConf.has_resolver("shard_sweep"):
        OmegaConf.register_new_resolver("shard_sweep", _shard_sweep)
    if not OmegaConf.has_resolver("run_dir"):
        OmegaConf.register_new_resolver("run_dir", _run_dir)
    if not OmegaConf.has_resolver("prompts"):
        OmegaConf.register_new_resolver("prompts", _prompts)
    cs = ConfigStore.instance()
    for name, node in plugin_methods().items():  # a method YAML of the same name on the search path wins
        cs.store(group="method", name=name, node=node)
    cs.store(name="base_config", node=Config)
    cs.store(group="scene", name="base_scene", node=SceneConfig)
    cs.store(group="object", name="base_object", node=ObjectConfig)
    cs.store(group="model", name="base_model", node=ModelConfig)
    cs.store(group="method", name="base_method", node=MethodConfig)
    cs.store(group="depth", name="base_depth", node=DepthConfig)
    cs.store(group="segment", name="base_segment", node=SegmentConfig)
