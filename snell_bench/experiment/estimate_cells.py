"""``job=plan``'s grid: each scene, object and method composed once (:class:`GridParts`), the
models a cell of them loads, and every cell's state by the runner's own test of "done"
(:func:`cell_states`); nothing is written.

Convention:
    Cells are not composed one by one (a Hydra composition costs ~0.1 s, the main grid has 1800
    cells): each scene, object and method is composed once with the run's overrides, and a cell's
    settings are the union of its parts' (a scene's config group touches only the ``scene`` node,
    an object's only ``object``, a method's only ``method``, and its switches only the ``sampler``
    / ``warps`` keys it names), the same as composing the cell (``tests/experiment/test_job_plan.py``
    holds them equal to :func:`~snell_bench.experiment.runner.plan_grid`). Objects are composed
    only when a cell has a record to compare with.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from snell_bench.config import Source, compose
from snell_bench.config.grid import CellId
from snell_bench.experiment.cells import Cell, cell_state
from snell_bench.experiment.order import cell_models
from snell_bench.experiment.plan import (
    NOT_RESULT_KEYS,
    flatten,
    object_overrides,
    result_settings,
    settings_hash,
)
from snell_bench.methods import method_of
from snell_bench.pipeline import apply_method
from snell_bench.pipeline.cell import node_key
from snell_bench.reports.records import GRID_RECORD

__all__ = ["RECORD", "CellState", "GridParts", "cell_states", "group_models"]

RECORD = "metrics.json"


def group_models(c: DictConfig) -> list[tuple[str, str]]:
    """``(kind, key)`` of the pool's models the inputs of a group load (stages 1-2 of
    :func:`snell_bench.pipeline.prepare_inputs`): the generator that makes a generated I⁻ (unless
    cached), the depth estimator of a photo without depth or of a generated I⁻, the segmenter."""
    out = []
    source = c.scene.source
    if source is Source.generated and not c.model.from_scene:
        out.append(("generator", node_key(c.model)))
    if ((source is Source.image and not c.scene.depth) or source is Source.generated) and c.depth.get("estimator"):
        out.append(("depth", node_key(c.depth)))
    if c.segment.get("segmenter"):
        out.append(("segmenter", node_key(c.segment)))
    return out


def _node_settings(c: DictConfig, node: str) -> dict[str, Any]:
    """:func:`~snell_bench.experiment.plan.result_settings` of one top-level node of ``c``,
    resolved against the whole config."""
    values = OmegaConf.to_container(c[node], resolve=True, enum_to_str=True)
    flat = flatten(values, f"{node}.") if isinstance(values, dict) and values else {node: values}
    return {k: v for k, v in flat.items() if not any(k == n or k.startswith(n + ".") for n in NOT_RESULT_KEYS)}


class GridParts:
    """The configs of a grid's scenes, objects and methods, each composed once with the run's
    overrides, and the cells' settings put together from them (see the module's convention).

    Args:
        cfg: the run's config (composed from ``cfg.overrides``).
        compose_fn: composes a list of overrides (:func:`snell_bench.config.compose`).
    """

    def __init__(self, cfg: DictConfig, compose_fn: Callable[[list[str]], DictConfig] = compose) -> None:
        self.cfg = cfg
        self._compose = compose_fn
        self._run = [str(o) for o in cfg.overrides]
        self._cache: dict[tuple, Any] = {}
        self.compositions = 0

    def _get(self, key: tuple, make: Callable[[], Any]) -> Any:
        if key not in self._cache:
            self._cache[key] = make()
        return self._cache[key]

    def _composed(self, overrides: list[str]) -> DictConfig:
        self.compositions += 1
        return self._compose([*self._run, *overrides])

    def scene(self, name: str) -> DictConfig:
        """The run's config with ``scene=name`` (the group inputs' models, the image size)."""
        return self._get(("scene", name), lambda: self._composed([f"scene={name}"]))

    def method(self, name: str) -> DictConfig:
        """The run's config with ``method=name``, its switches applied."""
        return self._get(("method", name), lambda: apply_method(self._composed([f"method={name}"])))

    def object(self, spec: str) -> DictConfig:
        """The run's config with the object of ``spec``."""
        return self._get(("object", spec), lambda: self._composed(object_overrides(spec)))

    def settings(self, scene: str, variation: int, spec: str, method: str) -> dict[str, Any]:
        """``result_settings`` of the cell, from its parts."""

        def rest():
            return {
                k: v for k, v in result_settings(self.cfg).items() if not k.startswith(("scene.", "object.", "method."))
            }

        def scene_part():
            c = self.scene(scene).copy()
            c.scene.variation = int(variation)  # as the override scene.variation=N after scene=NAME
            return _node_settings(c, "scene")

        def method_part():
            c = self.method(method)
            own = [f"sampler.{n}" for n in (c.method.sampler or {})] + [f"warps.{n}" for n in (c.method.warps or {})]
            switched = {
                k: v
                for node in ("sampler", "warps")
                for k, v in _node_settings(c, node).items()
                if any(k == o or k.startswith(o + ".") for o in own)
            }
            return {**_node_settings(c, "method"), **switched}

        return {
            **self._get(("rest",), rest),
            **self._get(("scene-settings", scene, int(variation)), scene_part),
            **self._get(("object-settings", spec), lambda: _node_settings(self.object(spec), "object")),
            **self._get(("method-settings", method), method_part),
        }

    def models(self, scene: str, method: str) -> list[tuple[str, str]]:
        """``(kind, key)`` of the pool's models a cell of ``scene`` and ``method`` needs, as
        :func:`group_models` of its inputs and :func:`~snell_bench.experiment.order.cell_models`."""
        return self._get(
            ("models", scene, method), lambda: group_models(self.scene(scene)) + cell_models(self.method(method))
        )


# ---------------------------------------------------------------------------- the cells
@dataclass(frozen=True)
class CellState:
    """One cell of the grid and what a run would do with it.

    ``state``: ``done`` (``ok``), ``skipped`` (recorded as skipped: done, not run again), ``changed``
    (finished with other settings: ``diff`` names them), ``files`` (a listed file is missing or
    changed, or an input the method read has: computed again), ``failed`` (recorded as failed: computed again), ``new`` (no record),
    ``recompute`` (``grid.recompute=true``)."""

    scene: str
    variation: int
    object: str
    method: str
    folder: Path
    state: str
    reason: str = ""
    diff: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return "/".join(self.folder.parts[-3:])  # <scene>-<variation>/<object>/<method or method@setting>

    @property
    def done(self) -> bool:
        return self.state in ("done", "skipped", "degenerate")


def cell_states(cfg: DictConfig, parts: GridParts) -> list[CellState]:
    """Every cell of ``cfg.grid`` in the runner's order, with its state (:class:`CellState`, by
    :func:`snell_bench.experiment.cells.cell_state`, the runner's own rule); nothing is written."""
    root = Path(cfg.runs_dir) / cfg.experiment_name
    return [_state(cell, root, parts, cfg.grid.recompute) for cell in CellId.grid(cfg.grid)]


def _state(cell_id: CellId, root: Path, parts: GridParts, recompute: bool) -> CellState:
    ident = (cell_id.scene, cell_id.variation, cell_id.object, cell_id.method)
    folder = cell_id.folder(root)
    c = parts.method(cell_id.method)
    group = cell_id.group

    def current() -> tuple[dict, str]:
        if cell_id.setting is None:
            settings = parts.settings(*ident)
        else:  # a named override set may change any key: the cell composed whole
            own = [*cell_id.overrides()]
            settings = result_settings(apply_method(parts._compose([*parts.cfg.overrides, *own])))
        return settings, settings_hash(settings)

    cell = Cell(name=folder.name, folder=folder, config=None, record={})  # the identity the state reads
    st = cell_state(
        cell,
        current,
        record_name=RECORD,
        schema=GRID_RECORD,
        recompute=recompute,
        stale=lambda cell, record: method_of(c).stale(c, record, folder, group),
    )
    kind = "new" if st.kind == "damaged" else st.kind
    return CellState(*ident, folder, kind, st.reason, st.diff)
