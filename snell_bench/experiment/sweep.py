"""The grid's settings axis (``grid.axes``, ``grid.presets``): what a cell of a named override set
records, which cells share their inputs, the totals of its timings, and the warm-up cell.

The speed/accuracy sweep (conf/experiment/tradeoff.yaml) is such a grid: every cost knob varied
on its own from the base setting, every stage timed (``timings_s``, seconds of wall time:
``scene``, ``warps``, ``reference``, ``true_render``, ``generator``, ``sampling``, ``metrics``;
``total`` = :data:`~snell_bench.reports.tradeoff.TOTAL_STAGES`, what producing and scoring one
image costs once the scene exists), scored against its own reference, the true render and a
converged one (:mod:`.converged`); its report (:func:`~snell_bench.reports.tradeoff.tradeoff_table`,
the Pareto front) is part of the grid's.

Reuse: a cell's inputs depend only on the resolved :data:`SHARED_SUBTREES`; their SHA-256 (16
hex digits) is its *inputs key*. The cells of a group with the group's first key share
``<group>/_inputs/`` as every grid does; a setting that changes them (``scene.width``,
``warps.max_bounces``, ``reference.spp``, ...) shares ``<group>/_shared/<key>/_inputs/`` with
the settings of the same key.
"""

from __future__ import annotations

import logging
from pathlib import Path

from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import DictConfig, OmegaConf

from snell_bench import pipeline
from snell_bench.config.grid import CellId
from snell_bench.experiment.plan import compose_cell
from snell_bench.pipeline.cell import plain
from snell_bench.reports.tradeoff import TOTAL_NOTE, TOTAL_STAGES
from snell_bench.utils.io import json_hash

log = logging.getLogger(__name__)

__all__ = ["KNOBS", "SHARED_SUBTREES", "inputs_key", "share_folder", "setting_record", "with_total", "warm_up"]

#: Knob name -> config key, recorded resolved with every setting's cell (``knobs``).
KNOBS: dict[str, str] = {
    "steps": "sampler.steps",
    "tt_repeats_main": "sampler.tt_repeats_main",
    "tt_repeats_pano": "sampler.tt_repeats_pano",
    "levels": "sampler.levels",
    "max_bounces": "warps.max_bounces",
    "width": "scene.width",
    "height": "scene.height",
    "supersample": "scene.supersample",
    "pano_height": "warps.pano_height",
    "spp": "reference.spp",
}

#: The config subtrees a group's inputs (scene, warps, references) depend on.
SHARED_SUBTREES = ("scene", "object", "warps", "reference", "seed", "model", "depth", "segment")

#: Tiny sizes of the warm-up cell.
_WARM_UP = (
    "scene.width=64",
    "scene.height=32",
    "scene.supersample=1",
    "warps.pano_height=32",
    "reference.spp=1",
    "reference.true_spp=1",
    "sampler.steps=2",
    "sampler.levels=2",
)


def inputs_key(c: DictConfig) -> str:
    """SHA-256 (16 hex digits) of the resolved :data:`SHARED_SUBTREES` of a cell's config."""
    return json_hash({k: plain(c[k]) for k in SHARED_SUBTREES})


def share_folder(group_dir: Path, key: str, first: dict[Path, str]) -> Path:
    """Where a cell of ``group_dir`` with inputs key ``key`` finds its inputs (``<folder>/_inputs``):
    the group's folder for the first key seen in it (``first`` remembers it), else
    ``<group>/_shared/<key>``."""
    first.setdefault(group_dir, key)
    return group_dir if first[group_dir] == key else group_dir / "_shared" / key


def setting_record(cell: CellId, c: DictConfig, order: int, key: str, share: Path, group_dir: Path) -> dict:
    """The fields a cell of a setting adds to its record: the setting (label, folder, order, axis,
    value, overrides as Hydra types them), the resolved :data:`KNOBS`, the inputs key and where
    its inputs are (relative to the group's folder)."""
    st = cell.setting
    overrides = OverridesParser.create().parse_overrides(list(st.overrides))
    return {
        "setting": st.label,
        "slug": st.slug,
        "order": order,
        "axis": st.axis,
        "value": st.value,
        "overrides": {o.key_or_group: o.value() for o in overrides},
        "setting_overrides": list(st.overrides),
        "method_name": cell.method,
        "knobs": {name: plain(OmegaConf.select(c, key_, default=None)) for name, key_ in KNOBS.items()},
        "inputs_key": key,
        "inputs_dir": (share / "_inputs").relative_to(group_dir).as_posix(),
        "timings_note": TOTAL_NOTE,
    }


def with_total(timings: dict) -> dict:
    """``timings`` with ``total``: the sum of :data:`~snell_bench.reports.tradeoff.TOTAL_STAGES`
    (a stage that did not run counts 0)."""
    return {**timings, "total": round(sum(float(timings.get(k) or 0.0) for k in TOTAL_STAGES), 4)}


def warm_up(cfg: DictConfig, cell_overrides: list[str]) -> None:
    """Run one tiny cell (imports, the renderer's variant probe, first-call costs) and discard it:
    nothing is written (``warps.cache_dir=null``)."""
    try:
        c = compose_cell(cfg, [*cell_overrides, "warps.cache_dir=null", *_WARM_UP])
        pipeline.run_method(c, pipeline.prepare_inputs(c))
    except Exception as e:  # noqa: BLE001 - the sweep itself reports real failures
        log.info(
            "warm-up cell failed (%s: %s); timings of the first cell include first-call costs", type(e).__name__, e
        )
