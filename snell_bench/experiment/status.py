"""``job=status``: where a grid stands across all the jobs that work on it, read from the files
alone (nothing is written, no lock is taken, no model is loaded).

Convention:
    - A cell is ``done`` (recorded ``ok`` or ``skipped``, its files unchanged, its settings the
      run's: the runner's own test, :func:`~snell_bench.experiment.estimate.cell_states`),
      ``failed`` (recorded as failed), ``running`` (no finished record and a claim file in its
      folder: a ``.lock`` holding its owner's line or a ``.lease``, with its owner), ``changed`` (finished
      with other settings, or its files changed since) or ``left``.
    - A claim file left by a killed process reads as ``running`` until the next claimant removes
      it; its owner (host and pid) is shown so it can be checked.
    - Jobs: every ``runs/<experiment>/jobs/<job id>/summary.json`` (a shard's last summary: its
      counts, restarts and failures) and the experiment's own ``summary.json``.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from omegaconf import DictConfig

from snell_bench.experiment.estimate import GridParts, cell_states
from snell_bench.experiment.runner import shard_cells
from snell_bench.utils.locks import CLAIM_NAMES

__all__ = ["GridStatus", "grid_status", "format_status", "run_status"]


@dataclass
class GridStatus:
    """The cells by state and the jobs' summaries."""

    experiment: str
    counts: Counter
    by_method: dict[str, Counter]
    running: list[tuple[str, str]]  #: ``(cell, owner)``
    failed: list[tuple[str, str]]  #: ``(cell, reason)``
    jobs: list[dict] = field(default_factory=list)
    shards: dict[int, Counter] = field(default_factory=dict)


def _claim_owner(folder: Path) -> str | None:
    """``<pid> <host>`` of the process that claims ``folder`` (a ``.lock`` holding its owner's
    line, or a ``.lease`` naming its claim file ``.lease|<host>|<pid>|<n>``), or ``None``."""
    for name in CLAIM_NAMES:
        try:
            text = (folder / name).read_text(errors="replace").strip()
        except OSError:
            continue
        parts = text.rsplit("|", 3)
        if len(parts) == 4:
            return f"{parts[2]} {parts[1]}"
        if text:
            return text.splitlines()[0]
    return None


def grid_status(cfg: DictConfig) -> GridStatus:
    """Where the grid of ``cfg`` stands (see the module docs)."""
    root = Path(cfg.runs_dir) / cfg.experiment_name
    states = cell_states(cfg, GridParts(cfg))
    counts: Counter = Counter()
    by_method: dict[str, Counter] = {}
    running, failed = [], []
    shard_of: dict[str, int] = {}
    shards = cfg.grid.shards
    if shards > 1:
        from snell_bench.experiment.cells import Cell

        fake = [Cell(s.name, s.folder, None, {}, shares=s.folder.parent) for s in states]
        for k in range(shards):
            for c in shard_cells(fake, shards, k):
                shard_of[c.name] = k
    per_shard: dict[int, Counter] = {}
    for s in states:
        if s.done:
            state = "done"
        elif s.state == "failed":
            state, reason = "failed", s.reason
        elif s.state in ("changed", "files"):
            state = "changed"
        else:
            state = "left"
        owner = None if state == "done" else _claim_owner(s.folder)
        if owner is not None:
            state = "running"
            running.append((s.name, owner))
        elif state == "failed":
            failed.append((s.name, reason))
        counts[state] += 1
        by_method.setdefault(s.folder.name, Counter())[state] += 1
        if s.name in shard_of:
            per_shard.setdefault(shard_of[s.name], Counter())[state] += 1
    jobs = []
    for path in sorted((root / "jobs").glob("*/summary.json")) + [root / "summary.json"]:
        try:
            rec = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        jobs.append({"id": path.parent.name if path.parent != root else "(this folder)", **rec})
    return GridStatus(cfg.experiment_name, counts, by_method, running, failed, jobs, per_shard)


def format_status(st: GridStatus, limit: int = 12) -> str:
    """The status as text: totals, per method, per shard, the jobs, running and failed cells."""
    order = ("done", "running", "failed", "changed", "left")
    total = sum(st.counts.values())
    lines = [f"experiment {st.experiment}: {total} cells: " + ", ".join(f"{st.counts[k]} {k}" for k in order)]
    width = max([len(m) for m in st.by_method] + [6])
    lines.append("  " + "method".ljust(width) + "".join(f"{k:>9s}" for k in order))
    for method, c in st.by_method.items():
        lines.append("  " + method.ljust(width) + "".join(f"{c[k]:9d}" for k in order))
    for k, c in sorted(st.shards.items()):
        lines.append(f"  shard {k}: " + ", ".join(f"{c[s]} {s}" for s in order if c[s]))
    if st.jobs:
        lines.append("jobs (their last summaries):")
        for j in st.jobs:
            job = j.get("job") or {}
            extra = f", shard {job['shard']}/{job['shards']}, {job.get('restarts', 0)} restarts" if job else ""
            lines.append(
                f"  {j['id']}: {j.get('ok', 0)} ok, {j.get('cached', 0)} already done, {j.get('skipped', 0)} skipped, "
                f"{j.get('failed', 0)} failed, {j.get('busy', 0)} busy{extra}"
            )
    for title, rows in (("running", st.running), ("failed", st.failed)):
        if rows:
            lines.append(f"{title}:")
            lines += [f"  {name}: {why}" for name, why in rows[:limit]]
            if len(rows) > limit:
                lines.append(f"  ... and {len(rows) - limit} more")
    left = st.counts["left"] + st.counts["failed"] + st.counts["changed"]
    if left:
        lines.append(
            "to finish: run the same command again (finished cells are skipped; failed ones are computed again; "
            "changed ones need grid.on_change=recompute)"
        )
    return "\n".join(lines)


def run_status(cfg: DictConfig) -> GridStatus:
    """``job=status``: print :func:`format_status` of :func:`grid_status`."""
    st = grid_status(cfg)
    print(format_status(st))
    return st
