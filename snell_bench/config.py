"""Structured configs (the schema behind ``conf/``), registered with Hydra's ConfigStore."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING

from snell_bench.sampler.settings import SamplerSettings


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
    #: The full prompt p (with the object phrase) and the panorama prompt p³⁶⁰.
    prompt: str = "A cozy living room with a polished wooden coffee table close to the camera, with a big glass sphere on top."
    pano_prompt: str = (
        "A high resolution equirectangular 360 degree panorama captured on top of a polished wooden coffee table "
        "in a cozy living room."
    )


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
class ModelConfig:
    """The generator backend."""

    #: ``analytic`` (CPU stand-in with an exact velocity), ``tiny_flux`` (random weights, tests),
    #: ``flux`` (FLUX.1-dev through diffusers, GPU).
    name: str = "analytic"
    #: analytic: std of the data distribution around its prior where the model is sure (the room).
    prior_std: float = 0.05
    #: analytic: the same inside the glass, the model's strength: smaller resists synchronisation more.
    glass_std: float = 0.1
    #: flux: a local folder with the diffusers layout, or a model id found in the Hugging Face cache.
    path: Optional[str] = None
    #: flux: ``cuda`` (default when available) or ``cpu``; dtype ``bfloat16`` on GPU by default.
    device: Optional[str] = None
    dtype: Optional[str] = None
    guidance: float = 3.5
    vae_tiling: bool = True
    #: Seed of the model's own construction (analytic latent transform, tiny random weights).
    seed: int = 0


@dataclass
class Config:
    #: Which job ``python -m snell_bench`` runs.
    job: str = "preview"
    seed: int = 0
    scene: SceneConfig = field(default_factory=SceneConfig)
    object: ObjectConfig = field(default_factory=ObjectConfig)
    warps: WarpConfig = field(default_factory=WarpConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    sampler: SamplerSettings = field(default_factory=SamplerSettings)
    #: Where the job writes; defaults to Hydra's run directory.
    output_dir: str = MISSING


def register_configs() -> None:
    cs = ConfigStore.instance()
    cs.store(name="base_config", node=Config)
    cs.store(group="scene", name="base_scene", node=SceneConfig)
    cs.store(group="object", name="base_object", node=ObjectConfig)
    cs.store(group="model", name="base_model", node=ModelConfig)
