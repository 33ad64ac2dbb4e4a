"""Sampler settings: every knob of the synchronized sampler, the ablations as single switches.

The structured-config schema of the ``sampler`` node (``conf/``); it checks its own values. The
defaults are what the paper's text says; where the authors' released code differs, a switch names
the difference (``tt_mode``, ``tt_renoise``, ``sde``, ``encode``, ``quantize``, ``dpa_domain``,
``pano_to_main``, ``sync_last_step``, ``schedule``, ``tt_repeats_pano``) and the recipes set it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

from snell_bench.config.errors import Problems, is_number

__all__ = [
    "DPA_DOMAINS",
    "ENCODE_MODES",
    "LATENT_DTYPES",
    "PANO_TO_MAIN",
    "SCHEDULES",
    "SYNC_MODES",
    "SamplerSettings",
    "TT_MODES",
    "TT_RENOISE",
]

#: Noise schedules of the generators (:meth:`~snell_bench.models.base.Generator.sigmas`).
SCHEDULES = ("flux", "linear")
SYNC_MODES = ("snellcaster", "none")
LATENT_DTYPES = ("float32", "model", "float16")
#: Time travel: ``guided`` (the paper and the authors' code) or ``repaint`` (re-predict every level).
TT_MODES = ("guided", "repaint")
#: How time travel renoises: the exact forward kernel, or the authors' Euler-Maruyama step.
TT_RENOISE = ("exact", "euler_maruyama")
#: VAE encoding of the synchronised images: posterior mean, or a draw from the posterior.
ENCODE_MODES = ("mean", "sample")
#: Where the detail-preserving average acts: whole images, or Laplacian bands.
DPA_DOMAINS = ("image", "bands")
#: Which main-view pixels receive the panorama's estimate: every pixel of the frame, or the object's.
PANO_TO_MAIN = ("frame", "object")


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
    #: The authors' Euler-Maruyama step ``z' = z + (sigma' - sigma) v + |sigma' - sigma| n`` with
    #: ``v = (z - x0_sync) / sigma`` and ``n`` from the run's generator (``x0_sync`` at ``sigma' = 0``)
    #: instead of the deterministic step; excludes ``stochastic``.
    sde: bool = False
    #: Ablation switches.
    reflection: bool = True
    panorama: bool = True
    dpa: bool = True
    lpw: bool = True
    #: Laplacian pyramid warping also for the warps INTO the panorama (π of the main estimate and of
    #: I⁻); ``false``: those two are single-level remaps, as in the authors' code (their pyramid warps
    #: only into the main view). No effect without ``lpw``.
    lpw_pano: bool = True
    time_travel: bool = True
    #: Detail-preserving average weight lambda (0 = masked mean; ``dpa: false`` forces 0).
    lam: float = 0.5
    #: Laplacian pyramid levels: of the warps (``lpw: false``: a single-level remap) and, with
    #: ``dpa_domain: bands``, of the blends.
    levels: int = 5
    #: Where phi acts: ``image`` (whole images in FLUX's [-1, 1] image space, ``x -> 2x - 1``; the
    #: pyramid serves the warps only) or ``bands`` (per Laplacian band, the low-pass level in [-1, 1]).
    dpa_domain: str = "image"
    #: Which main-view pixels receive ``π⁻¹(x0_pano)``: ``frame`` (every pixel, through
    #: ``WarpSet.pano_refraction_frame``) or ``object`` (the object's pixels only).
    pano_to_main: str = "frame"
    #: Time-travel window as fractions of T, travel length in steps, repeats per branch.
    tt_window: list[float] = field(default_factory=lambda: [0.2, 0.8])
    #: The window's step indices: ``tt_window[0] T <= i < tt_window[1] T`` (``false``), or with both
    #: bounds rounded down, ``int(tt_window[0] T) <= i < int(tt_window[1] T)``, as the authors' code
    #: does (``true``); the same when ``tt_window`` T are integers (T = 20).
    tt_window_floor: bool = False
    tt_length: int = 1
    tt_repeats_main: int = 3
    tt_repeats_pano: int = 1
    #: ``guided``: at every step of the window, renoise ``tt_length`` levels back and step down again
    #: with the same synchronised estimate (no model call at the noisier level), ``repeats - 1``
    #: times, then re-predict once; ``repaint``: run blocks of ``tt_length`` steps ``repeats`` times,
    #: re-predicting at every level.
    tt_mode: str = "guided"
    #: ``exact`` (the forward kernel ``a z + sqrt(s^2 - a^2 sigma^2) n``) or ``euler_maruyama``
    #: (``z + (s - sigma) (n - z) / (1 - sigma) + |s - sigma| n``).
    tt_renoise: str = "exact"
    #: VAE encoding of the synchronised images: ``mean`` (the posterior mean) or ``sample`` (a draw
    #: from the run's generator; generators without a posterior return the mean).
    encode: str = "mean"
    #: Round the decoded estimates (to nearest) and the synchronised images (down) to 8 bits every
    #: step, as an 8-bit image round trip does.
    quantize: bool = False
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
    #: on a GPU: the pipeline's own numbers); ``float16``: rounded to float16 after every step
    #: whatever the model (the authors' pipeline runs in float16; with ``model.dtype=float16`` this
    #: is ``model``; on a float32 stand-in it rounds all the same).
    latent_dtype: str = "float32"
    #: Keep the decoded estimates every k steps (0: never).
    dump_every: int = 0
    progress: bool = True

    def __post_init__(self) -> None:
        """Check every value; all problems at once in one :class:`~snell_bench.config.errors.ConfigError`
        (a ``ValueError``), each line naming its key ``sampler.<name>``, the value and the fix."""
        p = Problems("sampler")
        for name, choices in (
            ("sync", SYNC_MODES),
            ("latent_dtype", LATENT_DTYPES),
            ("schedule", SCHEDULES),
            ("tt_mode", TT_MODES),
            ("tt_renoise", TT_RENOISE),
            ("encode", ENCODE_MODES),
            ("dpa_domain", DPA_DOMAINS),
            ("pano_to_main", PANO_TO_MAIN),
        ):
            if getattr(self, name) not in choices:
                p.append(f"sampler.{name}={getattr(self, name)!r} is unknown; use one of {choices}")
        if self.sde and self.stochastic:
            p.append(
                "sampler.sde=true and sampler.stochastic=true are two different noisy steps; set one of them to false"
            )
        for name, lo, example in (
            ("steps", 1, 20),
            ("levels", 1, 5),
            ("tt_length", 1, 1),
            ("tt_repeats_main", 1, 3),
            ("tt_repeats_pano", 1, 1),
            ("dump_every", 0, 0),
        ):
            v = getattr(self, name)
            if not (is_number(v) and math.isfinite(v) and float(v).is_integer() and v >= lo):
                p.append(f"sampler.{name} must be an integer >= {lo}, got {v!r}; e.g. sampler.{name}={example}")
        window = p.numbers("tt_window", self.tt_window, 2, fix="e.g. sampler.tt_window=[0.2,0.8]")
        if window is not None and not 0.0 <= window[0] <= window[1] <= 1.0:
            p.append(
                f"sampler.tt_window must be [start, end] with 0 <= start <= end <= 1 (fractions of the steps), got "
                f"{list(self.tt_window)}; e.g. sampler.tt_window=[0.2,0.8]"
            )
        for name, fix in (
            ("eta", "the share of fresh noise in a stochastic step, e.g. sampler.eta=1"),
            ("lam", "the detail-preserving weight, e.g. sampler.lam=0.5"),
            ("reflection_min_fresnel", "e.g. sampler.reflection_min_fresnel=0 (keep every reflection)"),
        ):
            v = getattr(self, name)
            if not (is_number(v) and 0.0 <= v <= 1.0):
                p.append(f"sampler.{name} must be in [0, 1], got {v!r}; {fix}")
        v = self.skip_panorama_above
        if v is not None and not (is_number(v) and 0.0 <= v <= 1.0):
            p.append(f"sampler.skip_panorama_above must be in [0, 1] or null (never skip), got {v!r}; e.g. 0.95")
        p.raise_if_any()

    @property
    def effective_lam(self) -> float:
        return self.lam if self.dpa else 0.0

    @property
    def warp_levels(self) -> int:
        """Pyramid levels of the warps: ``levels`` with ``lpw``, else 1 (a single-level remap)."""
        return self.levels if self.lpw else 1

    @property
    def blend_levels(self) -> int:
        """Levels phi acts on: ``levels`` with ``dpa_domain: bands``, else 1 (whole images)."""
        return self.levels if self.dpa_domain == "bands" else 1

    @property
    def effective_levels(self) -> int:
        """The deepest pyramid a run builds (warps or blends): ``max(warp_levels, blend_levels)``."""
        return max(self.warp_levels, self.blend_levels)

    @property
    def uses_panorama(self) -> bool:
        return self.sync == "snellcaster" and self.panorama
