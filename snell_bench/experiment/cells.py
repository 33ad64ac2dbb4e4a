"""The one cell loop of every sweep: plan, resume, shared inputs, failures, atomic records, summary.

A *cell* is one unit of work with its own folder (a grid cell: scene x variation x object x
method, or x a setting of the grid's axes; a group of the benchmark kit). :func:`run_cells` runs a list of them:

- a cell is identified by its folder (a grid cell by scene, variation, object and method); it is
  done, and skipped, when its record file (``metrics.json``) is a record
  (:func:`~snell_bench.reports.records.load_record`: a UTF-8 JSON object matching the
  sweep's ``schema``; any other file is warned about, naming it and the problem, and the cell
  computed again), says ``ok`` or ``skipped``, every file the record lists (``files``: size and SHA-256) is there unchanged, and
  the record's ``settings_hash`` (of :func:`~snell_bench.experiment.plan.result_settings`: every
  resolved key that can change the result) equals the hash of the cell's config now; a missing or
  changed file makes it unfinished again; other settings stop the run before any work with an
  error naming the changed keys (:class:`SettingsChanged`), or, with ``on_change="recompute"``,
  redo it; ``recompute`` redoes every cell;
- a process claims a cell (:func:`~snell_bench.utils.locks.claim`) before computing it, so
  sweeps running at once into one folder compute each cell once: with ``fcntl.flock`` on
  ``.lock`` (the kernel frees the lock of a process that dies) or, where flock is missing or holds
  on one machine only, with a lease ``.lease`` (flufl.lock) renewed by a heartbeat and broken once
  it expires (``lock``: ``auto``, ``flock`` or ``lease``; :mod:`snell_bench.utils.locks`);
- ``fn(cell, shared)`` computes one cell and returns its record's fields; it raises
  :class:`~snell_bench.pipeline.Skip` for a method that cannot run here (``skipped`` with the
  reason), :class:`~snell_bench.pipeline.Degenerate` for a result that could not mean anything
  (``degenerate`` with the reason; done, in no mean) and any other exception for a failure
  (``failed`` with the reason and traceback); the loop goes on either way;
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

import logging
import traceback
from collections import Counter
from collections.abc import Callable, Hashable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf
from tqdm.auto import tqdm

from snell_bench.config import OnChange
from snell_bench.experiment.cell_state import (
    Cell,
    ChangedCell,
    SettingsChanged,
    State,
    cell_files,
    cell_state,
    changed_settings,
    files_problem,
    read_record,
    record_done,
)
from snell_bench.experiment.input_content import CONTENT, input_content
from snell_bench.experiment.plan import result_settings, settings_hash
from snell_bench.pipeline import Degenerate, Skip
from snell_bench.utils.io import write_json, write_text
from snell_bench.utils.locks import CLAIM_NAMES, DEFAULT_TTL_S, LOCK_NAME, check_ttl, choose_lock, claim

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
    "Policy",
    "Hooks",
    "claim",
    "LOCK_NAME",
    "cell_files",
    "files_problem",
    "SettingsChanged",
    "CELLS_FAILED_EXIT",
    "failures_verdict",
]


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


class SharedCache:
    """Values computed once per key for the cells that need them, dropped after the last one."""

    def __init__(self, keys: Iterable[Hashable]) -> None:
        self._uses = Counter(k for k in keys if k is not None)
        self._values: dict[Hashable, Any] = {}

    def get(self, key: Hashable, compute: Callable[[], Any]) -> Any:
        """The value of ``key``, computed by ``compute()`` the first time (an exception it raises
        is kept and raised again for every later cell of that key)."""
        if key not in self._values:
            try:
                self._values[key] = compute()
            except (KeyboardInterrupt, Skip):
                raise
            except Exception as e:  # noqa: BLE001 - every cell of the key fails with it
                self._values[key] = e
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


@dataclass(frozen=True)
class Policy:
    """What :func:`run_cells` does with finished cells and how it claims cells, as a config node sets
    it (:meth:`of`); the keys are those its errors name.

    Attributes:
        recompute: redo cells that are done.
        on_change: a finished cell whose recorded settings differ from its config's: ``error``
            (raise :class:`SettingsChanged` before any work) or ``recompute`` (redo it).
        lock: how a cell is claimed: ``flock``, ``lease`` or ``auto`` (decided once for the run
            folder's file system; :func:`~snell_bench.utils.locks.choose_lock`).
        lease_ttl_s: a lease's lifetime without renewal (``lease``).
    """

    recompute: bool = False
    on_change: OnChange = OnChange.error
    lock: str = "auto"
    lease_ttl_s: float = DEFAULT_TTL_S
    recompute_key: str = "grid.recompute"
    on_change_key: str = "grid.on_change"
    lock_key: str = "grid.lock"

    def __post_init__(self) -> None:
        object.__setattr__(self, "on_change", OnChange.of(self.on_change, self.on_change_key))
        ttl_key = self.lock_key.rpartition(".")[0] + ".lease_ttl_s" if "." in self.lock_key else "lease_ttl_s"
        object.__setattr__(self, "lease_ttl_s", check_ttl(self.lease_ttl_s, ttl_key))

    @classmethod
    def of(cls, node: Any, name: str, claims: Any = None, **fixed: Any) -> Policy:
        """The policy of the config node ``node`` named ``name`` (``grid``, ``export``):
        its ``recompute`` and ``on_change``, the claims (``lock``, ``lease_ttl_s``) of ``claims``
        (the ``grid`` node; ``node`` itself when None), and ``fixed`` values over them."""
        claims = node if claims is None else claims
        got = {
            "recompute": bool(node.get("recompute", False)),
            "on_change": node.get("on_change", OnChange.error),
            "lock": str(claims.get("lock", "auto")),
            "lease_ttl_s": float(claims.get("lease_ttl_s", DEFAULT_TTL_S)),
            "recompute_key": f"{name}.recompute",
            "on_change_key": f"{name}.on_change",
            "lock_key": "grid.lock" if claims is not node else f"{name}.lock",
        }
        return cls(**{**got, **fixed})


@dataclass(frozen=True)
class Hooks:
    """What a sweep adds to :func:`run_cells`'s loop (each optional).

    Attributes:
        before: called with the cells left to compute, before the first one (work that serves
            several cells and must come first, such as model-major passes).
        after: called after each cell's record is written (also for failed cells).
        recorded: called with each cell this process computed (``ok``, ``failed`` or ``skipped``)
            and its record, once the record is written: not for cells finished before, nor for
            cells left to another process (such as an experiment tracker's logging,
            :mod:`snell_bench.experiment.tracking`; it must not raise).
        stale: why a finished cell whose files and settings are unchanged no longer holds (an input it
            read has changed: :meth:`snell_bench.methods.Method.stale`), or None; such a cell is
            computed again, with a warning naming the reason.
    """

    before: Callable[[list[Cell]], None] | None = None
    after: Callable[[Cell], None] | None = None
    recorded: Callable[[Cell, dict], None] | None = None
    stale: Callable[[Cell, dict], str | None] | None = None


def run_cells(
    cells: Sequence[Cell],
    fn: Callable[[Cell, SharedCache], dict],
    *,
    root: Path,
    policy: Policy = Policy(),
    record_name: str = "metrics.json",
    schema: dict | None = None,
    desc: str = "",
    hooks: Hooks = Hooks(),
) -> dict:
    """Run ``cells`` (see the module docs) and write ``root/summary.json``.

    Args:
        cells: the plan, in order; cells that share a value should be consecutive.
        fn: computes one cell: returns the record's fields (merged over ``cell.record``).
        root: the run folder (``summary.json`` goes there).
        policy: finished cells and claims (:class:`Policy`).
        record_name: the record file of a cell, written last.
        schema: the JSON Schema a finished cell's record matches (a record that does not is
            warned about and its cell computed again); ``None``: any JSON object.
        desc: the progress bar's label.
        hooks: the sweep's additions to the loop (:class:`Hooks`).

    Returns:
        The summary: ``cells``; the counts ``ok``, ``failed``, ``skipped``, ``cached`` (finished before),
        ``busy`` (claimed by another process); ``failures`` as ``[cell folder, reason]`` pairs.
    """
    settings, hashes = _settings_of(cells)

    def status(cell: Cell, warn: bool = True) -> str | ChangedCell:  # todo, done, or changed (warn: why todo)
        current = lambda: (settings[id(cell)], hashes[id(cell)])
        st = cell_state(
            cell, current, record_name=record_name, schema=schema, recompute=policy.recompute, stale=hooks.stale
        )
        if warn and st.kind in ("damaged", "files"):
            log.warning("cell %s: %s; computing it again", cell.name, st.reason)
        return "done" if st.done else ChangedCell(cell, st.diff) if st.kind == "changed" else "todo"

    states = {id(c): status(c) for c in cells}
    todo = _todo(cells, states, policy)
    counts = Counter({"ok": 0, "failed": 0, "skipped": 0, "degenerate": 0, "busy": 0, "cached": len(cells) - len(todo)})
    failures: list[tuple[str, str]] = []
    root.mkdir(parents=True, exist_ok=True)
    lock = choose_lock(policy.lock, root, key=policy.lock_key)
    if hooks.before is not None and todo:
        hooks.before(todo)
    shared = SharedCache(c.shares for c in todo)
    bar = tqdm(total=len(cells), desc=desc, unit="cell", initial=counts["cached"])
    for cell in todo:
        bar.set_postfix_str(cell.name)
        try:
            cell.folder.mkdir(parents=True, exist_ok=True)
            with claim(cell.folder, kind=lock, ttl_s=policy.lease_ttl_s) as mine:
                if not mine:
                    counts["busy"] += 1
                    log.info("cell %s is being computed by another process; left to it", cell.name)
                elif states[id(cell)] == "todo" and status(cell, warn=False) == "done" and not policy.recompute:
                    counts["cached"] += 1  # another process finished it meanwhile
                else:
                    _remove_leftovers(cell.folder)
                    record = _run_one(cell, fn, shared, record_name, hashes[id(cell)], failures)
                    counts[record["status"]] += 1
                    if hooks.recorded is not None:
                        hooks.recorded(cell, record)
        except OSError as e:  # the cell's folder cannot be written: it fails alone
            failures.append((str(cell.folder), f"{type(e).__name__}: {e} (the cell's folder cannot be written)"))
            counts["failed"] += 1
            log.error("cell %s failed: %s", cell.folder, failures[-1][1])
        finally:
            shared.release(cell.shares)
        bar.update(1)
        if hooks.after is not None:
            hooks.after(cell)
    bar.close()
    summary = {"cells": len(cells), **counts, "failures": failures}
    write_json(root / "summary.json", summary)
    return summary


def _todo(cells: Sequence[Cell], states: dict, policy: Policy) -> list[Cell]:
    """The cells left to compute; :class:`SettingsChanged` before any work when finished cells have
    other settings and ``policy.on_change`` is ``error``."""
    changed = [s for s in states.values() if isinstance(s, ChangedCell)]
    if changed and policy.on_change is OnChange.error:
        raise SettingsChanged(changed, on_change_key=policy.on_change_key, recompute_key=policy.recompute_key)
    for c in changed:
        log.info("cell %s: settings changed; computing it again (%s=recompute)", c.cell.name, policy.on_change_key)
    return [c for c in cells if states[id(c)] != "done"]


def _settings_of(cells: list[Cell]) -> tuple[dict, dict]:
    """``({id: result settings with the input files' content}, {id: their hash})``; each cell's
    record keeps its input files' hashes (``input_sha256``), to compare with on the next run."""
    settings = {id(c): {**result_settings(c.config), **input_content(c.config)} for c in cells}
    for c in cells:
        if contents := {k: v for k, v in settings[id(c)].items() if k.endswith(CONTENT)}:
            c.record = {**c.record, "input_sha256": contents}
    return settings, {k: settings_hash(v) for k, v in settings.items()}


def _run_one(cell, fn, shared, record_name, settings_hash, failures) -> dict:
    """Compute one claimed cell and write its config and record: the record (``status`` ``ok``,
    ``skipped`` or ``failed``, with the reason and traceback)."""
    record = {**cell.record, "status": "ok", "reason": None}
    try:
        record.update(fn(cell, shared))
    except Skip as e:
        record.update(status="skipped", reason=str(e))
    except Degenerate as e:  # a result that could not mean anything: recorded, in no mean
        record.update(status="degenerate", reason=str(e))
        log.warning("cell %s is degenerate: %s", cell.folder, e)
    except KeyboardInterrupt:
        raise
    except Exception as e:  # noqa: BLE001 - recorded; the sweep goes on
        record.update(status="failed", reason=f"{type(e).__name__}: {e}", traceback=traceback.format_exc())
        failures.append((str(cell.folder), record["reason"]))
        log.error("cell %s failed: %s", cell.folder, record["reason"])
    record["settings_hash"] = settings_hash
    _write_record(cell, record, record_name)
    return record
