"""The one cell loop of every sweep: plan, resume, shared inputs, failures, atomic records, summary.

A *cell* is one unit of work with its own folder (a grid cell: scene x variation x object x
method; a sweep setting: scene x setting). :func:`run_cells` runs a list of them:

- a cell whose record file (``metrics.json`` or ``result.json``) says ``ok`` or ``skipped`` is
  done and skipped, unless ``recompute``;
- ``fn(cell, shared)`` computes one cell and returns its record's fields; it raises
  :class:`~snell_bench.pipeline.Skip` for a method that cannot run here (``skipped`` with the
  reason) and any other exception for a failure (``failed`` with the reason and traceback); the
  loop goes on either way;
- ``shared`` (:class:`SharedCache`) computes a value once per key for all cells that need it
  (the inputs of a scene and object) and drops it after the last of them; a value whose
  computation failed fails every cell that needs it, with that error;
- each cell's ``config.yaml`` and then its record are written atomically, the record last, so a
  cell with a record is complete and an interrupted sweep loses no finished cell;
- ``summary.json`` of the run and a progress bar (tqdm) report the counts and the failures.
"""

from __future__ import annotations

import json
import logging
import traceback
from collections import Counter
from collections.abc import Callable, Hashable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from tqdm.auto import tqdm

from snell_bench.pipeline import Skip
from snell_bench.utils.io import write_json, write_text

log = logging.getLogger(__name__)

__all__ = ["Cell", "SharedCache", "run_cells", "record_done"]

DONE = ("ok", "skipped")


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
    try:
        return json.loads(path.read_text()).get("status") in DONE
    except (OSError, ValueError, AttributeError):
        return False


def run_cells(
    cells: Sequence[Cell],
    fn: Callable[[Cell, SharedCache], dict],
    *,
    root: Path,
    record_name: str = "metrics.json",
    recompute: bool = False,
    desc: str = "",
    after: Callable[[Cell], None] | None = None,
) -> dict:
    """Run ``cells`` (see the module docs) and write ``root/summary.json``.

    Args:
        cells: the plan, in order; cells that share a value should be consecutive.
        fn: computes one cell: returns the record's fields (merged over ``cell.record``).
        root: the run folder (``summary.json`` goes there).
        record_name: the record file of a cell, written last.
        recompute: redo cells that are done.
        desc: the progress bar's label.
        after: called after each cell's record is written (also for failed cells).

    Returns:
        The summary: ``cells``, counts of ``ok``, ``failed``, ``skipped``, ``cached``, and
        ``failures`` as ``[cell folder, reason]`` pairs.
    """
    todo = [c for c in cells if recompute or not record_done(c.folder / record_name)]
    counts = Counter({"ok": 0, "failed": 0, "skipped": 0, "cached": len(cells) - len(todo)})
    failures: list[tuple[str, str]] = []
    shared = SharedCache(c.shares for c in todo)
    root.mkdir(parents=True, exist_ok=True)
    bar = tqdm(total=len(cells), desc=desc, unit="cell", initial=counts["cached"])
    for cell in todo:
        bar.set_postfix_str(cell.name)
        cell.folder.mkdir(parents=True, exist_ok=True)
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
        finally:
            shared.release(cell.shares)
        cfg = cell.config.copy()
        cfg.output_dir = str(cell.folder)
        try:
            text = OmegaConf.to_yaml(cfg, resolve=True)
        except Exception:  # noqa: BLE001 - a value that cannot resolve (the cell's failure says why)
            text = OmegaConf.to_yaml(cfg, resolve=False)
        write_text(cell.folder / "config.yaml", text)
        write_json(cell.folder / record_name, record)  # last: marks the cell complete
        counts[record["status"]] += 1
        bar.update(1)
        if after is not None:
            after(cell)
    bar.close()
    summary = {"cells": len(cells), **counts, "failures": failures}
    write_json(root / "summary.json", summary)
    return summary
