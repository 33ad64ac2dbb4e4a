"""Sampler settings: every knob of the synchronized sampler, the ablations as single switches.

The structured-config schema of the ``sampler`` node (``conf/``); it checks its own values.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

__all__ = ["LATENT_DTYPES", "SCHEDULES", "SamplerSettings", "SYNC_MODES"]

#: Noise schedules of the generators (:meth:`~snell_bench.models.base.Generator.sigmas`).
SCHEDULES = ("flux", "linear")
SYNC_MODES = ("snellcaster", "none")
LATENT_DTYPES = ("float32", "model")


@dataclass
class SamplerSettings:
    """Every knob of the sampler; the ablations are single switches."""

    #: Denoising steps T (the paper: 20).
    steps: int = 20
    #: ``flux`` (the generator's resolution-shifted schedule) or ``linear`` (see
    #: :meth:`~snell_bench.models.base.Generator.sigmas`).
    schedule: str = "flux"
    #: ``snellcaster`` (synchronized) or ``none`` (the generator alone from the full prompt).
    sync: str = "snellcaster"
    #: Stochastic steps (fresh noise each step, from the run's generator) instead of deterministic.
    stochastic: bool = False
    #: Share of fresh noise in a stochastic step (1: renoise fully).
    eta: float = 1.0
    #: Ablation switches.
    reflection: bool = True
    panorama: bool = True
    dpa: bool = True
    lpw: bool = True
    time_travel: bool = True
    #: Detail-preserving average weight lambda (0 = masked mean; ``dpa: false`` forces 0).
    lam: float = 0.5
    #: Laplacian pyramid levels (``lpw: false`` forces 1: a single-level remap).
    levels: int = 5
    #: Time-travel window as fractions of T, travel length in steps, repeats per branch.
    tt_window: list[float] = field(default_factory=lambda: [0.2, 0.8])
    tt_length: int = 1
    tt_repeats_main: int = 3
    tt_repeats_pano: int = 1
    #: Warp into a window around each warp's valid pixels only (the object in the main view, the part
    #: of the panorama the camera sees): the same images, less work; ``false`` warps whole frames.
    roi: bool = True
    #: Model only what the scene requires (each decision is reported in ``SampleResult.decisions``):
    #: no reflection at object pixels whose Fresnel reflectance is below this (none anywhere: no
    #: reflection warp at all); 0 keeps every pixel's reflection.
    reflection_min_fresnel: float = 0.0
    #: Skip the panorama branch when at least this share of object pixels sends its refracted ray
    #: (and its mirror ray, where reflection is kept) to surfaces I⁻ observes; ``null``: never skip.
    #: Without the panorama the reflection comes from I⁻ where the mirror ray reaches what it shows.
    skip_panorama_above: Optional[float] = None
    #: Synchronise the last step too (``false``: the last step uses each branch's own estimate, as
    #: the authors' code does).
    sync_last_step: bool = True
    #: ``float32``: latents stay float32 between steps whatever the model's precision; ``model``:
    #: they are rounded to the model's dtype after every step, as ``FluxPipeline`` does (bfloat16
    #: on a GPU: the pipeline's own numbers).
    latent_dtype: str = "float32"
    #: Keep the decoded estimates every k steps (0: never).
    dump_every: int = 0
    progress: bool = True

    def __post_init__(self) -> None:
        if self.sync not in SYNC_MODES:
            raise ValueError(f"sampler.sync={self.sync!r} is unknown; use one of {SYNC_MODES}")
        if self.latent_dtype not in LATENT_DTYPES:
            raise ValueError(f"sampler.latent_dtype={self.latent_dtype!r} is unknown; use one of {LATENT_DTYPES}")
        if self.schedule not in SCHEDULES:
            raise ValueError(f"sampler.schedule={self.schedule!r} is unknown; use one of {SCHEDULES}")
        for name in ("steps", "levels", "tt_length", "tt_repeats_main", "tt_repeats_pano"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"sampler.{name} must be an integer >= 1, got {v!r}")
        lo, hi = self.tt_window
        if not 0.0 <= lo <= hi <= 1.0:
            raise ValueError(f"sampler.tt_window must satisfy 0 <= start <= end <= 1, got {self.tt_window}")
        if not 0.0 <= self.reflection_min_fresnel <= 1.0:
            raise ValueError(f"sampler.reflection_min_fresnel must be in [0, 1], got {self.reflection_min_fresnel}")
        if self.skip_panorama_above is not None and not 0.0 <= self.skip_panorama_above <= 1.0:
            raise ValueError(
                f"sampler.skip_panorama_above must be in [0, 1] or null (never skip), got {self.skip_panorama_above}"
            )
        if not 0.0 <= self.lam <= 1.0:
            raise ValueError(f"sampler.lam must be in [0, 1], got {self.lam}")

    @property
    def effective_lam(self) -> float:
        return self.lam if self.dpa else 0.0

    @property
    def effective_levels(self) -> int:
        return self.levels if self.lpw else 1

    @property
    def uses_panorama(self) -> bool:
        return self.sync == "snellcaster" and self.panorama
