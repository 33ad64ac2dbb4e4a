"""The structured schema behind ``conf/``: one dataclass per config node, registered with Hydra;
the root (:class:`Config`) here, its nodes by topic in :mod:`.schema_scene` (scene, object,
warps), :mod:`.schema_models` (model, models, method, depth, segment, relight),
:mod:`.schema_eval` (metrics, baselines, reference) and :mod:`.schema_runs` (grid, tracker, plan,
export), all importable from here.

Convention:
    - A string setting with a closed set of values is a :mod:`~snell_bench.config.choices` enum:
      OmegaConf rejects any other value when the config is composed, naming the key and the choices.
    - Each dataclass checks the ranges of its own values in ``__post_init__`` (all lines at once, a
      :class:`~snell_bench.config.errors.ConfigError`); OmegaConf runs it when a node is turned
      into its dataclass (``OmegaConf.to_object``), which :func:`~snell_bench.config.checks.check_config`
      does for every node. Checks across nodes and of files and devices live in
      :mod:`snell_bench.config.checks`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from omegaconf import MISSING

from snell_bench.config.choices import Job
from snell_bench.config.sampler import SamplerSettings
from snell_bench.config.schema_eval import BaselinesConfig, MetricsConfig, ReferenceConfig
from snell_bench.config.schema_models import (
    DepthConfig,
    MethodConfig,
    MethodCostConfig,
    ModelConfig,
    ModelsConfig,
    RelightConfig,
    SegmentConfig,
)
from snell_bench.config.schema_runs import ExportConfig, GridConfig, PlanConfig, TrackerConfig
from snell_bench.config.schema_scene import ObjectConfig, SceneConfig, WarpConfig

__all__ = [
    "Config",
    "SceneConfig",
    "ObjectConfig",
    "WarpConfig",
    "ModelConfig",
    "ModelsConfig",
    "MethodConfig",
    "MethodCostConfig",
    "DepthConfig",
    "SegmentConfig",
    "MetricsConfig",
    "BaselinesConfig",
    "ReferenceConfig",
    "RelightConfig",
    "GridConfig",
    "TrackerConfig",
    "ExportConfig",
    "SamplerSettings",
    "CHECKED_NODES",
]


@dataclass
class Config:
    #: Which job ``python -m snell_bench`` runs.
    job: Job = Job.preview
    seed: int = 0
    scene: SceneConfig = field(default_factory=SceneConfig)
    object: ObjectConfig = field(default_factory=ObjectConfig)
    warps: WarpConfig = field(default_factory=WarpConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    models: ModelsConfig = field(default_factory=ModelsConfig)
    sampler: SamplerSettings = field(default_factory=SamplerSettings)
    method: MethodConfig = field(default_factory=MethodConfig)
    metrics: MetricsConfig = field(default_factory=MetricsConfig)
    baselines: BaselinesConfig = field(default_factory=BaselinesConfig)
    depth: DepthConfig = field(default_factory=DepthConfig)
    segment: SegmentConfig = field(default_factory=SegmentConfig)
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)
    relight: RelightConfig = field(default_factory=RelightConfig)
    grid: GridConfig = field(default_factory=GridConfig)
    plan: PlanConfig = field(default_factory=PlanConfig)
    #: ``job=export``: the benchmark kit.
    export: ExportConfig = field(default_factory=ExportConfig)
    #: Where each finished cell is also logged (conf/tracker/: none, mlflow, tensorboard, wandb).
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    #: The recipe (conf/recipe/) the switches come from: ``paper`` (what the paper's text says) or
    #: ``authors`` (what the authors' released code does); set by the recipe file, recorded with
    #: every cell.
    recipe: str = "paper"
    #: The experiment's name (its folder under runs/ and reports/).
    experiment_name: str = "default"
    runs_dir: str = "runs"
    reports_dir: str = "reports"
    #: Where the job writes; defaults to Hydra's run directory.
    output_dir: str = MISSING
    #: The overrides this config was composed from (set by ``python -m snell_bench`` and by
    #: :func:`compose`): a sweep composes each of its cells from them and the cell's own choices.
    overrides: list = field(default_factory=list)


#: The nodes whose dataclass checks its own ranges (``sampler`` is checked with the method's
#: switches applied, the root's ``seed`` by :func:`~snell_bench.config.checks.check_config`).
CHECKED_NODES = (
    "scene",
    "object",
    "warps",
    "model",
    "models",
    "method",
    "metrics",
    "baselines",
    "reference",
    "relight",
    "segment",
    "grid",
    "tracker",
    "export",
)
