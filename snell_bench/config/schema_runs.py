"""The schema of the sweeps (``grid``, ``tracker``, ``plan``, ``export``): which cells run, where they are logged, the kit.

Part of :mod:`snell_bench.config.schema` (its conventions hold here).
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field
from typing import Any, Optional

from snell_bench.config.choices import (
    OnChange,
)
from snell_bench.config.errors import Problems

__all__ = ["GridConfig", "TrackerConfig", "PlanConfig", "ExportConfig", "TRACKER_MODES"]


@dataclass
class GridConfig:
    """The cells of an experiment: scenes x variations x objects x methods."""

    scenes: list = field(default_factory=lambda: ["living_room"])
    variations: list = field(default_factory=lambda: [0])
    objects: list = field(default_factory=lambda: ["sphere"])
    methods: list = field(default_factory=lambda: ["snellcaster", "t2i"])
    #: Recompute cells that already finished (else they are skipped).
    recompute: bool = False
    #: A finished cell whose recorded settings differ from this run's (``sampler.steps``,
    #: ``scene.width``, ...): ``error`` (stop before any work, naming the changed keys) or
    #: ``recompute`` (redo those cells with this run's settings).
    on_change: OnChange = OnChange.error
    #: Build the report tables after the sweep.
    report: bool = True
    #: Groups (scene x variation x object) whose inputs worker processes prepare ahead of the group
    #: being sampled: their scene, placement and warps before their cells sample, their references
    #: while they sample, so a grid takes about as long as the slower of sampling and preparing
    #: (benchmarks/bench_overlap.py; snell_bench/experiment/prefetch.py). ``null``: automatic, 2
    #: when the generator samples on CUDA (``model.from_scene`` false, ``model.device`` unset,
    #: ``auto`` or ``cuda[:i]``, and CUDA present), else 0: on a CPU-only machine sampling and
    #: preparation share the cores. 0: every stage in this process, in order. Stages that need a
    #: model (a generated I⁻, a depth estimator, SAM 3) always run in this process. The results are
    #: the same either way (not a result setting).
    prefetch: Optional[int] = None
    #: Worker processes that prepare those inputs (each loads no model; the reference renderer
    #: uses every core in each, so more than one pays only where one worker leaves cores idle).
    workers: int = 1
    #: Split the grid's (scene, variation, object) groups between this many jobs (a Slurm job
    #: array with ``-m hydra/launcher=slurm``): each job computes its own groups, so every group's
    #: shared inputs are computed once in the whole cluster. With ``-m``, ``grid.shards=N`` sweeps
    #: ``grid.shard=range(0,N)`` (Hydra's ``hydra.sweeper.params``, conf/config.yaml).
    shards: int = 1
    #: Which shard this job is (0 .. shards - 1); ``null``: every group.
    shard: Optional[int] = None
    #: How a process claims a cell before computing it: ``flock`` (filelock's ``fcntl.flock`` on
    #: ``<cell>/.lock``; the kernel frees the lock of a dead process), ``lease`` (flufl.lock's
    #: hard-link lease ``<cell>/.lease``, renewed every ``lease_ttl_s / 3`` s and broken 10 s after
    #: it expires: for Lustre without ``flock``, NFS with ``local_lock``, BeeGFS) or ``auto`` (``lease`` where flock raises or the mount keeps it
    #: local to one machine, else ``flock``; snell_bench/utils/locks.py). Every job sharing a
    #: run folder must claim the same way. Not a result setting.
    lock: str = "auto"
    #: Seconds a lease lives without renewal: a cell whose process died on another machine is
    #: free again this long (plus 10 s) after its last renewal (at once on the same machine).
    #: Leases are stamped to the second: keep it >= 3, e.g. >= 30.
    lease_ttl_s: float = 120.0
    #: Exit with status 0 even when cells failed (for sweeps that expect some to fail); else the
    #: run's exit status is non-zero when any cell failed.
    allow_failures: bool = False
    #: Named override sets crossed with every method (the speed/accuracy sweep,
    #: conf/experiment/tradeoff.yaml): axis name -> a Hydra sweep override
    #: (``"sampler.steps=4,8,12"``: one setting per value, labelled ``steps=4``, ...) or a mapping
    #: ``label -> [override, ...]`` for knobs that change together (labelled ``<axis>=<label>``).
    #: With axes or presets every method runs at ``baseline`` (as configured) and at each setting,
    #: in the folder ``<method>@<setting>`` (:class:`~snell_bench.config.grid.CellId`).
    axes: dict = field(default_factory=dict)
    #: The axes to run (names of ``axes``); ``null``: all of them.
    only: Optional[list] = None
    #: Presets (conf/preset/) added as settings, labelled ``preset:<name>``.
    presets: list = field(default_factory=list)
    #: Also score every cell against a converged reference rendered with this many samples per
    #: pixel (one per scene, object and resolution, shared: ``<group>/_shared/converged-<key>/``):
    #: fidelity that does not move with ``reference.spp`` (``psnr_converged``, ``mae_converged``,
    #: ``lpips_converged``; 1058: the paper preset's count); the sweep's Pareto front uses it.
    #: ``null``: off.
    converged_spp: Optional[int] = None
    #: Before the first cell, run one tiny cell and discard it (imports, the renderer's variant
    #: probe, first-call costs), so that the first cell's timings are not charged for them.
    warm_up: bool = False

    def __post_init__(self) -> None:
        p = Problems("grid")
        if self.converged_spp is not None:
            # at most MAX_SPP (config/errors.py: what the renderers take), far past 1058, the paper's count
            p.spp("converged_spp", self.converged_spp, 1058, why="null: no converged reference; ")
        p.int_at_least("shards", self.shards, 1, " (jobs the groups are split between)", 2)
        if self.shard is not None:
            p.int_at_least("shard", self.shard, 0, " (this job's shard; null: every group)", 0)
            if isinstance(self.shard, int) and isinstance(self.shards, int) and self.shard >= self.shards:
                p.append(
                    f"grid.shard={self.shard!r}: must be below grid.shards={self.shards}; e.g. grid.shard=0 "
                    "(with -m, grid.shards=N alone runs every shard)"
                )
        if self.lock not in ("auto", "flock", "lease"):
            p.append(f"grid.lock={self.lock!r}: must be one of auto, flock, lease; e.g. grid.lock=lease")
        p.finite("lease_ttl_s", self.lease_ttl_s, positive=True, fix="e.g. grid.lease_ttl_s=120")
        if self.prefetch is not None:
            p.int_at_least("prefetch", self.prefetch, 0, " (groups prepared ahead; null: automatic)", 2)
        p.int_at_least("workers", self.workers, 1, " (worker processes)", 1)
        p.raise_if_any()


#: ``tracker.mode`` values (W&B's run modes).
TRACKER_MODES = ("offline", "online", "shared", "disabled")


@dataclass
class TrackerConfig:
    """Where each finished grid cell's settings, metrics and images are also logged (conf/tracker/):
    ``none`` (nothing), ``mlflow`` (a local MLflow file store), ``tensorboard`` (event files),
    ``wandb`` (Weights & Biases, offline unless ``mode`` says otherwise). One run per cell, grouped
    by ``experiment``; the cell's own files stay the record (snell_bench/experiment/tracking/).
    Not a result setting."""

    name: str = "none"
    #: The name the runs are grouped under (the MLflow experiment, the W&B group).
    experiment: str = "${experiment_name}"
    #: Also log image.png, reference.png, mask.png and panorama.png (where a cell has them).
    log_images: bool = True
    #: ``mlflow``: the tracking URI (``file:PATH`` or a plain path: a local file store; or a
    #: tracking server's ``http(s)://`` address).
    uri: Optional[str] = None
    #: ``tensorboard``: the log folder (a run folder per cell under it); ``wandb``: the folder
    #: W&B writes its ``wandb/`` folder into.
    dir: Optional[str] = None
    #: ``wandb``: the project and the entity (``null``: the account's default entity).
    project: Optional[str] = None
    entity: Optional[str] = None
    #: ``wandb``: ``offline`` (files only, nothing sent; ``wandb sync`` uploads them later),
    #: ``online``, ``shared`` or ``disabled``.
    mode: Optional[str] = None
    #: The Python modules the back-end imports, checked before any work.
    requires: list = field(default_factory=list)
    #: What logs: a ``_target_`` node (a :class:`~snell_bench.experiment.tracking.Tracker`;
    #: ``null``: no tracking).
    backend: Any = None

    def __post_init__(self) -> None:
        p = Problems("tracker")
        # a module that is not installed stops the run here, before any cell is computed (a
        # tracker that fails later only warns: the cells' results are kept either way)
        missing = [str(m) for m in self.requires if importlib.util.find_spec(str(m)) is None]
        if missing:
            p.append(
                f"tracker={self.name} needs {', '.join(missing)}: pip install 'snell_bench[track]' or set tracker=none"
            )
        if self.mode is not None and self.mode not in TRACKER_MODES:
            p.append(
                f"tracker.mode={self.mode!r}: must be one of {', '.join(TRACKER_MODES)}; e.g. tracker.mode=offline"
            )
        if self.backend is not None and not str(self.experiment).strip():
            p.append(
                f"tracker.experiment={self.experiment!r}: the runs of tracker={self.name} are grouped under this name: "
                "it cannot be empty; e.g. tracker.experiment=my_run (default: experiment_name)"
            )
        p.nonempty_or_null("dir", self.dir, "the log folder, or null for the tracker's default")
        p.nonempty_or_null("uri", self.uri, "a folder, a file: or http(s):// URI, or null")
        p.raise_if_any()


@dataclass
class PlanConfig:
    """``job=plan``: what a grid will do on this machine, before doing it."""

    #: A ``benchmarks/bench_gpu.py --json`` file whose measured times and GPU memory the plan uses
    #: (the pipeline baselines keep the documented figures); ``null``: the documented basis (docs/gpu.md) (the
    #: paper's A100 time scaled), labelled as such.
    bench: Optional[str] = None


@dataclass
class ExportConfig:
    """``job=export``: the benchmark kit of an experiment's grid (``<dir>/<experiment_name>/``): per
    (scene, variation, object) group the inputs a method needs and the truth it is scored against,
    a manifest (Parquet and JSON Lines) and a dataset card (snell_bench/kit/)."""

    #: Where kits are written: ``<dir>/<experiment_name>/``.
    dir: str = "kits"
    #: Also write each group's warps (π^R, π⁻¹, π^-R, π, their masks and the Fresnel reflectance),
    #: for methods that want Snell's law for free (about 60 bytes a pixel).
    warps: bool = False
    #: Export every group again (else a group exported with the same settings, its files unchanged,
    #: is kept; one exported with other settings is exported again).
    recompute: bool = False

    def __post_init__(self) -> None:
        p = Problems("export")
        if not isinstance(self.dir, str) or not self.dir.strip():
            p.append(f"export.dir={self.dir!r}: must be a folder; e.g. export.dir=kits")
        p.raise_if_any()
