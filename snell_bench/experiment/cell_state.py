"""A cell's identity (:class:`Cell`) and state (:func:`cell_state`): its record, the files the record
lists, the settings it was computed with; the one rule by which the runner, ``job=plan`` and
``job=status`` decide whether a cell is done (:mod:`snell_bench.experiment.cells` has the loop)."""

from __future__ import annotations

import functools
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from snell_bench.config import Config
from snell_bench.config.recipes import BEFORE_SWITCHES
from snell_bench.experiment.input_content import CONTENT
from snell_bench.experiment.plan import ABSENT, flatten, result_settings, settings_diff
from snell_bench.reports.records import files_problem, load_record
from snell_bench.utils.io import file_sha256
from snell_bench.utils.trust import load_yaml

__all__ = [
    "DONE",
    "Cell",
    "record_done",
    "read_record",
    "cell_files",
    "files_problem",
    "ChangedCell",
    "SettingsChanged",
    "changed_settings",
    "State",
    "cell_state",
]

DONE = ("ok", "skipped", "degenerate")


@dataclass
class Cell:
    """One planned unit of work."""

    name: str  #: shown in progress and failure lists, e.g. ``living_room-0/sphere/t2i``
    folder: Path  #: the cell's own folder
    config: DictConfig  #: its composed config (written as ``config.yaml``)
    record: dict  #: identity fields of its record (scene, method, ...)
    shares: Hashable | None = None  #: key of the shared value it needs (see :class:`SharedCache`)
    extra: dict = field(default_factory=dict)  #: anything the job's ``fn`` needs


def record_done(path: Path) -> bool:
    """Whether a record file exists and says ``ok`` or ``skipped``."""
    return (read_record(path) or {}).get("status") in DONE


def read_record(path: Path, schema: dict | None = None) -> dict | None:
    """A record file as a dict, or ``None`` when it is missing or not a record (unreadable, not
    UTF-8 JSON, not an object, or against ``schema``, e.g.
    :data:`~snell_bench.reports.records.GRID_RECORD`:
    :func:`~snell_bench.reports.records.load_record`)."""
    return load_record(path, schema)[0]


# ---------------------------------------------------------------------------- files of a cell
def cell_files(folder: Path, record_name: str) -> dict[str, dict]:
    """``{relative path: {"bytes": size, "sha256": hash}}`` of every file of a cell folder (hidden
    files, such as the lock and temporaries, the record itself and symbolic links left out)."""
    out = {}
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder)
        if path.is_symlink() or rel.as_posix() == record_name or any(p.startswith(".") for p in rel.parts):
            continue  # a link is not the cell's (snell_bench writes none): never followed nor hashed
        if path.is_file():
            out[rel.as_posix()] = {"bytes": path.stat().st_size, "sha256": file_sha256(path)}
    return out


# ---------------------------------------------------------------------------- settings of a cell
def _saved_settings(folder: Path) -> dict | None:
    saved, problem = load_yaml(folder / "config.yaml")  # bounded: an alias bomb is refused
    if problem is not None or not isinstance(saved, dict):
        return None  # missing or unreadable: the settings are unknown
    try:
        return result_settings(OmegaConf.create(saved))
    except Exception:  # noqa: BLE001 - not a config: the settings are unknown
        return None


@dataclass
class ChangedCell:
    """A finished cell whose recorded settings differ from the run's."""

    cell: Cell
    diff: dict  #: ``{key: (recorded value, this run's value)}``; empty if the old ones are unknown


class SettingsChanged(ValueError):
    """Finished cells were computed with other settings than the run's (see :func:`run_cells`)."""

    def __init__(self, changed: Sequence[ChangedCell], *, on_change_key: str, recompute_key: str) -> None:
        self.changed = list(changed)
        keys: dict[str, list] = {}
        unknown = 0
        for c in self.changed:
            if not c.diff:
                unknown += 1
            for k, (old, new) in c.diff.items():
                keys.setdefault(k, [old, new, 0])[2] += 1
        lines = [
            f"  {k}: {old!r} -> {new!r} ({n} cell{'s' if n > 1 else ''})"
            for k, (old, new, n) in list(keys.items())[:12]
        ]
        if len(keys) > 12:
            lines.append(f"  ... and {len(keys) - 12} more keys")
        if unknown:
            lines.append(f"  {unknown} cell(s) without a readable config.yaml: their settings are unknown")
        names = ", ".join(c.cell.name for c in self.changed[:4]) + (" ..." if len(self.changed) > 4 else "")
        super().__init__(
            f"{len(self.changed)} finished cell(s) ({names}) were computed with other settings than this run's:\n"
            + "\n".join(lines)
            + f"\nNothing was run. Choose: {on_change_key}=recompute (redo these cells with this run's settings), "
            f"{recompute_key}=true (redo every cell), or another experiment_name=... (keep both)"
        )


@functools.lru_cache(maxsize=1)
def _schema_defaults() -> dict:
    """What a cell recorded before a key existed was computed with: the schema's default, or for a
    recipe switch whose default is not what the code did before it existed, that behaviour
    (:data:`~snell_bench.config.recipes.BEFORE_SWITCHES`)."""
    defaults = flatten(OmegaConf.to_container(OmegaConf.structured(Config), resolve=False, enum_to_str=True))
    return {**defaults, **BEFORE_SWITCHES}


def changed_settings(cell: Cell, record: dict, current: dict, current_hash: str) -> ChangedCell | None:
    """The :class:`ChangedCell` of a finished cell whose recorded settings differ from ``current``
    (keys added to the schema since, at their default, do not count), or ``None``."""
    if record.get("settings_hash") == current_hash:
        return None
    old = _saved_settings(cell.folder)
    if old is None:
        return ChangedCell(cell, {})
    old = {**old, **(record.get("input_sha256") or {})}  # the input files' content when it finished
    defaults = _schema_defaults()
    diff = {
        k: (a, b)
        for k, (a, b) in settings_diff(old, current).items()
        # a setting added to the schema since the cell finished, at its default: the cell had that
        # behaviour; an input file's content not recorded (a cell of before): taken as unchanged
        if not (a == ABSENT and ((k in defaults and defaults[k] == b) or k.endswith(CONTENT)))
    }
    return ChangedCell(cell, diff) if diff else None


# ---------------------------------------------------------------------------- a cell's state
@dataclass(frozen=True)
class State:
    """What a run does with one cell (:func:`cell_state`): ``kind`` is ``new`` (no record),
    ``recompute`` (asked for), ``damaged`` (the record file is not a cell record), ``failed``
    (recorded as failed), ``files`` (a listed file is missing or changed, or an input the method
    read has), ``changed`` (finished with other settings: ``diff`` names them), ``done`` (``ok``)
    or ``skipped`` (recorded as skipped). The last two are done; the others are computed."""

    kind: str
    reason: str = ""
    diff: dict = field(default_factory=dict)

    @property
    def done(self) -> bool:
        return self.kind in ("done", "skipped", "degenerate")


def cell_state(
    cell: Cell,
    current: Callable[[], tuple[dict, str]],
    *,
    record_name: str = "metrics.json",
    schema: dict | None = None,
    recompute: bool = False,
    stale: Callable[[Cell, dict], str | None] | None = None,
) -> State:
    """The :class:`State` of ``cell``, decided from its folder alone: the one rule of the runner
    (:func:`run_cells`), ``job=plan`` and ``job=status``. ``current()`` gives this run's result
    settings of the cell and their hash (asked only for a finished cell); ``stale`` says why a
    finished cell no longer holds though its files are unchanged (:meth:`snell_bench.methods.Method.stale`)."""
    path = cell.folder / record_name
    if recompute:
        return State("recompute")
    if not path.exists():
        return State("new")
    record, problem = load_record(path, schema)
    if problem is not None:
        return State("damaged", f"{path} is not a cell record ({problem})")
    if record.get("status") not in DONE:
        return State("failed", str(record.get("reason") or record.get("status")))
    problem = files_problem(cell.folder, record) or (stale(cell, record) if stale is not None else None)
    if problem is not None:
        return State("files", problem)
    changed = changed_settings(cell, record, *current())
    if changed is not None:
        return State("changed", diff=changed.diff)
    status = str(record["status"])
    return State("done" if status == "ok" else status, str(record.get("reason") or ""))
