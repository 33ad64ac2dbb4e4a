"""The one cell loop of every sweep: plan, resume, shared inputs, failures, atomic records, summary.

A *cell* is one unit of work with its own folder (a grid cell: scene x variation x object x
method; a sweep setting: scene x setting). :func:`run_cells` runs a list of them:

- a cell is identified by its folder (a grid cell by scene, variation, object and method); it is
  done, and skipped, when its record file (``metrics.json`` or ``result.json``) is a record
  (:func:`~snell_bench.experiment.reports.records.load_record`: a UTF-8 JSON object matching the
  sweep's ``schema``; any other file is warned about, naming it and the problem, and the cell
  computed again), says ``ok`` or ``skipped``, every file the record lists (``files``: size and SHA-256) is there unchanged, and
  the record's ``settings_hash`` (of :func:`~snell_bench.experiment.plan.result_settings`: every
  resolved key that can change the result) equals the hash of the cell's config now; a missing or
  changed file makes it unfinished again; other settings stop the run before any work with an
  error naming the changed keys (:class:`SettingsChanged`), or, with ``on_change="recompute"``,
  redo it; ``recompute`` redoes every cell;
- a process claims a cell (:func:`~snell_bench.experiment.locks.claim`) before computing it, so
  sweeps running at once into one folder compute each cell once: with ``fcntl.flock`` on
  ``.lock`` (the kernel frees the lock of a process that dies) or, where flock is missing or holds
  on one machine only, with a lease ``.lease`` (flufl.lock) renewed by a heartbeat and broken once
  it expires (``lock``: ``auto``, ``flock`` or ``lease``; :mod:`snell_bench.experiment.locks`);
- ``fn(cell, shared)`` computes one cell and returns its record's fields; it raises
  :class:`~snell_bench.pipeline.Skip` for a method that cannot run here (``skipped`` with the
  reason) and any other exception for a failure (``failed`` with the reason and traceback); the
  loop goes on either way;
- ``shared`` (:class:`SharedCache`) computes a value once per key for all cells that need it
  (the inputs of a scene and object) and drops it after the last of them; a value whose
  computation failed fails every cell that needs it, with that error;
- each cell's ``config.yaml`` and then its record are written atomically, the record last, so a
  cell with a record is complete and an interrupted sweep loses no finished cell; a cell whose
  folder cannot be written fails alone;
- ``summary.json`` of the run and a progress bar (tqdm) report the counts and the failures;
  :func:`failures_verdict` turns the count of failed cells into the run's exit status
  (:data:`CELLS_FAILED_EXIT` unless the sweep allows failures; skipped cells never count).
"""

from __future__ import annotations

import functools
import logging
import traceback
from collections import Counter
from collections.abc import Callable, Hashable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from tqdm.auto import tqdm

from snell_bench.config import Config, OnChange
from snell_bench.config.recipes import BEFORE_SWITCHES
from snell_bench.experiment.locks import CLAIM_NAMES, DEFAULT_TTL_S, LOCK_NAME, check_ttl, choose_lock, claim
from snell_bench.experiment.plan import ABSENT, flatten, result_settings, settings_diff, settings_hash
from snell_bench.experiment.reports.records import load_record
from snell_bench.pipeline import Skip
from snell_bench.utils.io import file_sha256, write_json, write_text

log = logging.getLogger(__name__)

__all__ = [
    "Cell",
    "SharedCache",
    "run_cells",
    "record_done",
    "read_record",
    "changed_settings",
    "State",
    "cell_state",
    "claim",
    "LOCK_NAME",
    "cell_files",
    "files_problem",
    "SettingsChanged",
    "CELLS_FAILED_EXIT",
    "failures_verdict",
]

DONE = ("ok", "skipped")

#: The exit status of ``python -m snell_bench`` when cells of its sweep failed (and the sweep does
#: not allow failures): distinct from 1 (an error stopped the run) and 2 (a command line that
#: cannot be parsed); see :mod:`snell_bench.__main__`.
CELLS_FAILED_EXIT = 3


def failures_verdict(failed: int, allow: bool, key: str) -> tuple[int, str]:
    """The exit status of a sweep with ``failed`` failed cells, and what it means for its summary line.

    Args:
        failed: the cells this run computed that failed (skipped cells are not failures).
        allow: the sweep's ``<key>`` setting (exit 0 anyway).
        key: the config key that allows failures (``grid.allow_failures``).

    Returns:
        ``(status, text)``: ``(0, "")`` without failures; else :data:`CELLS_FAILED_EXIT` (0 when
        ``allow``) and the words to append to the count of failed cells.

    Examples:
        >>> failures_verdict(0, False, "grid.allow_failures")
        (0, '')
        >>> failures_verdict(2, False, "grid.allow_failures")
        (3, ' (exit status 3: cells failed; grid.allow_failures=true exits 0)')
        >>> failures_verdict(2, True, "grid.allow_failures")
        (0, ' (exit status 0: grid.allow_failures=true)')
    """
    if failed <= 0:
        return 0, ""
    if allow:
        return 0, f" (exit status 0: {key}=true)"
    return CELLS_FAILED_EXIT, f" (exit status {CELLS_FAILED_EXIT}: cells failed; {key}=true exits 0)"


@dataclass
class Cell:
    """One planned unit of work."""

    name: str  #: shown in progress and failure lists, e.g. ``living_room-0/sphere/t2i``
    folder: Path  #: the cell's own folder
    config: DictConfig  #: its composed config (written as ``config.yaml``)
    record: dict  #: identity fields of its record (scene, method, ...)
    shares: Hashable | None = None  #: key of the shared value it needs (see :class:`SharedCache`)
    extra: dict = field(default_factory=dict)  #: anything the job's ``fn`` needs


class SharedCache:
    """Values computed once per key for the cells that need them, dropped after the last one."""

    def __init__(self, keys: Iterable[Hashable]) -> None:
        self._uses = Counter(k for k in keys if k is not None)
        self._values: dict[Hashable, Any] = {}
        self.computed_by: dict[Hashable, str] = {}

    def get(self, key: Hashable, compute: Callable[[], Any], by: str = "") -> Any:
        """The value of ``key``, computed by ``compute()`` the first time (an exception it raises
        is kept and raised again for every later cell of that key)."""
        if key not in self._values:
            try:
                self._values[key] = compute()
            except (KeyboardInterrupt, Skip):
                raise
            except Exception as e:  # noqa: BLE001 - every cell of the key fails with it
                self._values[key] = e
            self.computed_by[key] = by
        value = self._values[key]
        if isinstance(value, Exception):
            raise value
        return value

    def release(self, key: Hashable | None) -> None:
        """One cell of ``key`` is finished; drop the value after the last one."""
        if key is None:
            return
        self._uses[key] -= 1
        if self._uses[key] <= 0:
            self._values.pop(key, None)


def record_done(path: Path) -> bool:
    """Whether a record file exists and says ``ok`` or ``skipped``."""
    return (read_record(path) or {}).get("status") in DONE


def read_record(path: Path, schema: dict | None = None) -> dict | None:
    """A record file as a dict, or ``None`` when it is missing or not a record (unreadable, not
    UTF-8 JSON, not an object, or against ``schema``, e.g.
    :data:`~snell_bench.experiment.reports.records.GRID_RECORD`:
    :func:`~snell_bench.experiment.reports.records.load_record`)."""
    return load_record(path, schema)[0]


# ---------------------------------------------------------------------------- files of a cell
def cell_files(folder: Path, record_name: str) -> dict[str, dict]:
    """``{relative path: {"bytes": size, "sha256": hash}}`` of every file of a cell folder (hidden
    files, such as the lock and temporaries, and the record itself left out)."""
    out = {}
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder)
        if path.is_file() and rel.as_posix() != record_name and not any(p.startswith(".") for p in rel.parts):
            out[rel.as_posix()] = {"bytes": path.stat().st_size, "sha256": file_sha256(path)}
    return out


def files_problem(folder: Path, record: dict) -> str | None:
    """Why the files ``record["files"]`` lists do not match the folder (a file missing, or of
    another size or content), or ``None``."""
    for rel, want in (record.get("files") or {}).items():
        path = folder / rel
        if not path.is_file():
            return f"{rel} is missing"
        if path.stat().st_size != want.get("bytes") or file_sha256(path) != want.get("sha256"):
            return f"{rel} has changed since the cell finished"
    return None


# ---------------------------------------------------------------------------- settings of a cell
def _saved_settings(folder: Path) -> dict | None:
    try:
        return result_settings(OmegaConf.load(folder / "config.yaml"))
    except Exception:  # noqa: BLE001 - missing or unreadable: the settings are unknown
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
    defaults = _schema_defaults()
    diff = {
        k: (a, b)
        for k, (a, b) in settings_diff(old, current).items()
        # a setting added to the schema since the cell finished, at its default: the cell had that behaviour
        if not (a == ABSENT and k in defaults and defaults[k] == b)
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
        return self.kind in ("done", "skipped")


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


# ---------------------------------------------------------------------------- claiming a cell
def _remove_leftovers(folder: Path) -> None:
    """Remove the temporaries (``.<name>.<random>.tmp`` / ``.link``) a killed process left in a
    cell folder this process has claimed: no other writer can be using them. The claim files
    (``.lock``, ``.lease``, ``.lease|...``) stay."""
    for path in folder.glob(".*"):
        if not path.name.startswith(CLAIM_NAMES) and path.suffix in (".tmp", ".link") and path.is_file():
            log.info("removing %s, left by an interrupted run", path)
            path.unlink(missing_ok=True)


# ---------------------------------------------------------------------------- the loop
def _write_record(cell: Cell, record: dict, record_name: str) -> None:
    cfg = cell.config.copy()
    cfg.output_dir = str(cell.folder)
    try:
        text = OmegaConf.to_yaml(cfg, resolve=True)
    except Exception:  # noqa: BLE001 - a value that cannot resolve (the cell's failure says why)
        text = OmegaConf.to_yaml(cfg, resolve=False)
    write_text(cell.folder / "config.yaml", text)
    record["files"] = cell_files(cell.folder, record_name)
    write_json(cell.folder / record_name, record)  # last: marks the cell complete


def run_cells(
    cells: Sequence[Cell],
    fn: Callable[[Cell, SharedCache], dict],
    *,
    root: Path,
    record_name: str = "metrics.json",
    schema: dict | None = None,
    recompute: bool = False,
    on_change: OnChange | str = OnChange.error,
    on_change_key: str = "grid.on_change",
    recompute_key: str = "grid.recompute",
    desc: str = "",
    before: Callable[[list[Cell]], None] | None = None,
    after: Callable[[Cell], None] | None = None,
    recorded: Callable[[Cell, dict], None] | None = None,
    lock: str = "auto",
    lease_ttl_s: float = DEFAULT_TTL_S,
    lock_key: str = "grid.lock",
    stale: Callable[[Cell, dict], str | None] | None = None,
) -> dict:
    """Run ``cells`` (see the module docs) and write ``root/summary.json``.

    Args:
        cells: the plan, in order; cells that share a value should be consecutive.
        fn: computes one cell: returns the record's fields (merged over ``cell.record``).
        root: the run folder (``summary.json`` goes there).
        record_name: the record file of a cell, written last.
        schema: the JSON Schema a finished cell's record matches (a record that does not is
            warned about and its cell computed again); ``None``: any JSON object.
        recompute: redo cells that are done.
        on_change: a finished cell whose recorded settings differ from its config's: ``error``
            (raise :class:`SettingsChanged` before any work) or ``recompute`` (redo it).
        on_change_key, recompute_key: the config keys named in that error.
        desc: the progress bar's label.
        before: called with the cells left to compute, before the first one (work that serves
            several cells and must come first, such as model-major passes).
        after: called after each cell's record is written (also for failed cells).
        recorded: called with each cell this process computed (``ok``, ``failed`` or ``skipped``)
            and its record, once the record is written: not for cells finished before, nor for
            cells left to another process (such as an experiment tracker's logging,
            :mod:`snell_bench.experiment.tracking`; it must not raise).
        lock: how a cell is claimed: ``flock``, ``lease`` or ``auto`` (decided once for ``root``'s
            file system; :func:`~snell_bench.experiment.locks.choose_lock`).
        lease_ttl_s: a lease's lifetime without renewal (``lease``): a lease left by a killed
            process elsewhere is broken this long after its last renewal.
        lock_key: the config key of ``lock`` named in its errors (``lease_ttl_s``'s is
            ``<its parent>.lease_ttl_s``).
        stale: why a finished cell whose files and settings are unchanged no longer holds (an input it
            read has changed: :meth:`snell_bench.methods.Method.stale`), or None; such a cell is
            computed again, with a warning naming the reason.

    Returns:
        The summary: ``cells``, counts of ``ok``, ``failed``, ``skipped``, ``cached`` (finished
        before), ``busy`` (claimed by another process running at the same time), and
        ``failures`` as ``[cell folder, reason]`` pairs.
    """
    on_change = OnChange.of(on_change, on_change_key)
    ttl_key = lock_key.rpartition(".")[0] + ".lease_ttl_s" if "." in lock_key else "lease_ttl_s"
    lease_ttl_s = check_ttl(lease_ttl_s, ttl_key)
    settings = {id(c): result_settings(c.config) for c in cells}
    hashes = {k: settings_hash(v) for k, v in settings.items()}

    def status(cell: Cell, warn: bool = True) -> str | ChangedCell:
        """``todo``, ``done``, or the :class:`ChangedCell` of a cell finished with other settings
        (``warn``: say why a recorded cell is computed again)."""
        st = cell_state(
            cell,
            lambda: (settings[id(cell)], hashes[id(cell)]),
            record_name=record_name,
            schema=schema,
            recompute=recompute,
            stale=stale,
        )
        if st.done:
            return "done"
        if st.kind == "changed":
            return ChangedCell(cell, st.diff)
        if warn and st.kind in ("damaged", "files"):
            log.warning("cell %s: %s; computing it again", cell.name, st.reason)
        return "todo"

    states = {id(c): status(c) for c in cells}
    changed = [s for s in states.values() if isinstance(s, ChangedCell)]
    if changed and on_change is OnChange.error:
        raise SettingsChanged(changed, on_change_key=on_change_key, recompute_key=recompute_key)
    for c in changed:
        log.info("cell %s: settings changed; computing it again (%s=recompute)", c.cell.name, on_change_key)
    todo = [c for c in cells if states[id(c)] != "done"]
    counts = Counter({"ok": 0, "failed": 0, "skipped": 0, "busy": 0, "cached": len(cells) - len(todo)})
    failures: list[tuple[str, str]] = []
    shared = SharedCache(c.shares for c in todo)
    root.mkdir(parents=True, exist_ok=True)
    lock = choose_lock(lock, root, key=lock_key)
    if before is not None and todo:
        before(todo)
    bar = tqdm(total=len(cells), desc=desc, unit="cell", initial=counts["cached"])
    for cell in todo:
        bar.set_postfix_str(cell.name)
        try:
            cell.folder.mkdir(parents=True, exist_ok=True)
            with claim(cell.folder, kind=lock, ttl_s=lease_ttl_s) as mine:
                if not mine:
                    counts["busy"] += 1
                    log.info("cell %s is being computed by another process; left to it", cell.name)
                elif states[id(cell)] == "todo" and status(cell, warn=False) == "done" and not recompute:
                    counts["cached"] += 1  # another process finished it meanwhile
                else:
                    _remove_leftovers(cell.folder)
                    counts[_run_one(cell, fn, shared, record_name, settings, hashes, failures, recorded)] += 1
        except OSError as e:  # the cell's folder cannot be written: it fails alone
            reason = f"{type(e).__name__}: {e} (the cell's folder {cell.folder} cannot be written)"
            failures.append((str(cell.folder), reason))
            counts["failed"] += 1
            log.error("cell %s failed: %s", cell.folder, reason)
        finally:
            shared.release(cell.shares)
        bar.update(1)
        if after is not None:
            after(cell)
    bar.close()
    summary = {"cells": len(cells), **counts, "failures": failures}
    write_json(root / "summary.json", summary)
    return summary


def _run_one(cell, fn, shared, record_name, settings, hashes, failures, recorded=None) -> str:
    record = {**cell.record, "status": "ok", "reason": None}
    try:
        record.update(fn(cell, shared))
    except Skip as e:
        record.update(status="skipped", reason=str(e))
    except KeyboardInterrupt:
        raise
    except Exception as e:  # noqa: BLE001 - recorded; the sweep goes on
        record.update(status="failed", reason=f"{type(e).__name__}: {e}", traceback=traceback.format_exc())
        failures.append((str(cell.folder), record["reason"]))
        log.error("cell %s failed: %s", cell.folder, record["reason"])
    record["settings_hash"] = hashes[id(cell)]
    _write_record(cell, record, record_name)
    if recorded is not None:
        recorded(cell, record)
    return record["status"]
