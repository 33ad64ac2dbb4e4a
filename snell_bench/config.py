"""Structured configs (the schema behind ``conf/``), registered with Hydra's ConfigStore."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING


@dataclass
class SceneConfig:
    """Where I⁻, its depth and K come from."""

    #: ``procedural`` (CPU, exact geometry); generated and photo sources come with the generators.
    source: str = "procedural"
    #: Procedural scene kind (``room``, ``outdoor``, ...).
    kind: str = "room"
    #: The variation: a seed of the procedural scene.
    variation: int = 0
    #: Image size of I⁻ (the paper uses 720 x 1280).
    width: int = 1280
    height: int = 720
    #: Sub-pixel samples per side when rendering procedural images (anti-aliasing).
    supersample: int = 2


@dataclass
class ObjectConfig:
    """The glass object and where it stands."""

    name: str = "sphere"
    #: ``sphere``, ``cylinder``, ``pyramid`` or ``mesh`` (then ``path`` names the file).
    shape: str = "sphere"
    path: Optional[str] = None
    #: The file's up axis (``y``, ``z``, ``-z``, ...), for ``shape: mesh``.
    up_axis: str = "y"
    #: A material name (glass, water, acrylic, diamond, ...) or a number.
    ior: Any = "glass"
    #: Largest bounding-box side in scene units; ``null``: ``relative_size`` x distance.
    size: Optional[float] = None
    relative_size: float = 0.25
    yaw_deg: float = 0.0


@dataclass
class WarpConfig:
    """Ray tracing settings of :func:`snell_bench.optics.compute_warps`."""

    pano_height: int = 1024
    max_bounces: int = 8
    #: ``interpolated`` (smooth, creased at sharp edges) or ``face``.
    normals: str = "interpolated"
    edge_threshold: float = 0.05
    #: Cache folder for warps (content-hashed); ``null`` disables caching.
    cache_dir: Optional[str] = "runs/cache/warps"


@dataclass
class Config:
    #: Which job ``python -m snell_bench`` runs.
    job: str = "preview"
    seed: int = 0
    scene: SceneConfig = field(default_factory=SceneConfig)
    object: ObjectConfig = field(default_factory=ObjectConfig)
    warps: WarpConfig = field(default_factory=WarpConfig)
    #: Where the job writes; defaults to Hydra's run directory.
    output_dir: str = MISSING


def register_configs() -> None:
    cs = ConfigStore.instance()
    cs.store(name="base_config", node=Config)
    cs.store(group="scene", name="base_scene", node=SceneConfig)
    cs.store(group="object", name="base_object", node=ObjectConfig)
