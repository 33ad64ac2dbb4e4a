"""The configuration: the structured schema behind ``conf/``, its choices, composing, and the
checks every config passes before any work.

Modules: :mod:`.schema` (one dataclass per node, ranges checked in ``__post_init__``),
:mod:`.choices` (the enums of string settings), :mod:`.sampler` (the ``sampler`` node),
:mod:`.materials` (``object.ior`` and ``object.ior_range``), :mod:`.camera` (the range of
``scene.fov_deg``), :mod:`.names` (names that become folder names), :mod:`.grid` (the entries of
the grid's lists and the sweep's axes),
:mod:`.compose` (Hydra composition, the ``prompts`` resolver), :mod:`.checks` (unknown keys,
values across nodes, files, devices), :mod:`.preflight` (the checks as a Hydra callback, before
any folder is created). Nothing here imports a stage package except the ``prompts`` resolver.
"""

from snell_bench.config.checks import check_config, check_grid_entries, max_levels, unknown_keys
from snell_bench.config.choices import (
    METHOD_ENTRY_POINTS,
    METHOD_KINDS,
    DepthKind,
    InpaintMask,
    Job,
    Normals,
    OnChange,
    PanoPrior,
    PromptKind,
    Protocol,
    RefSampler,
    Source,
)
from snell_bench.config.compose import CONFIG_MODULE, compose, config_context, group_options, register_configs
from snell_bench.config.errors import ConfigError
from snell_bench.config.sampler import SamplerSettings
from snell_bench.config.schema import (
    Config,
    DepthConfig,
    GridConfig,
    MethodConfig,
    MetricsConfig,
    ModelConfig,
    ModelsConfig,
    ObjectConfig,
    ReferenceConfig,
    RelightConfig,
    SceneConfig,
    SegmentConfig,
    TrackerConfig,
    WarpConfig,
)

__all__ = [
    "CONFIG_MODULE",
    "Config",
    "ConfigError",
    "DepthConfig",
    "DepthKind",
    "GridConfig",
    "InpaintMask",
    "Job",
    "METHOD_ENTRY_POINTS",
    "METHOD_KINDS",
    "MethodConfig",
    "MetricsConfig",
    "ModelConfig",
    "ModelsConfig",
    "Normals",
    "ObjectConfig",
    "OnChange",
    "PanoPrior",
    "PromptKind",
    "Protocol",
    "RefSampler",
    "ReferenceConfig",
    "RelightConfig",
    "SamplerSettings",
    "SceneConfig",
    "SegmentConfig",
    "Source",
    "TrackerConfig",
    "WarpConfig",
    "check_config",
    "check_grid_entries",
    "compose",
    "config_context",
    "group_options",
    "max_levels",
    "register_configs",
    "unknown_keys",
]
