"""The synchronized two-branch sampler (Snellcaster), its ablations, and the plain baseline.

Per denoising step (the paper's §4):

1. the generator's velocity for the main view and the panorama (one batched call when both latents
   have the same size) gives Euler estimates ``x0_hat = z - sigma v``;
2. both estimates are decoded to images;
3. main view: ``phi((x0, x0_pano, I⁻), (identity, π⁻¹, π^R), lambda)`` per Laplacian level, then the
   reflection ``π^-R(x0_pano)`` mixed in by Fresnel in linear RGB inside the object;
   panorama: ``phi((x0_pano, x0, I⁻), (identity, π, π))`` (the main estimate only where the
   perspective pixel does not show the object itself);
4. the synchronized images are encoded and each branch steps with its synchronized estimate.

Time travel (window ``[0.2 T, 0.8 T)``): a block of ``tt_length`` steps is run, renoised back with
the exact forward kernel and run again, ``tt_repeats_main`` times for the main view and
``tt_repeats_pano`` times for the panorama; a branch that stops repeating early keeps its latest
latent and lends its latest estimates to the other's blends, so every model call's output is used.

Convention:
    - Images ``(1, 3, H, W)`` (main view) and ``(1, 3, Hp, Wp)`` (panorama, ``Wp = 2 Hp``), float32
      sRGB in [0, 1]; warps as in :class:`~snell_bench.optics.WarpSet` (backward maps ``(H', W', 2)``
      in pixels, order x, y, NaN where invalid).
    - Latents ``(1, C, h, w)`` float32, unpacked (:class:`~snell_bench.models.base.LatentGeometry`);
      ``z_sigma = (1 - sigma) x0 + sigma eps`` (:mod:`snell_bench.sampler.steps`).
    - Every random draw (initial noise, stochastic steps, time travel) comes from one
      ``torch.Generator`` on the generator's device, seeded with ``seed``, in loop order: the main
      view's draw before the panorama's at every point where both draw.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from tqdm.auto import tqdm

from snell_bench.config.sampler import SamplerSettings
from snell_bench.models.base import Condition, Generator, generator_device
from snell_bench.optics.warps import WarpSet
from snell_bench.sampler.adaptive import decide
from snell_bench.sampler.steps import (
    euler_estimate,
    latent_rounding,
    pipeline_step,
    renoise,
    rounding_dtype,
    stochastic_step,
    sync_step,
)
from snell_bench.sampler.views import Views

log = logging.getLogger(__name__)

__all__ = ["SampleResult", "sample"]


@dataclass
class SampleResult:
    """What :func:`sample` returns.

    Attributes:
        image: ``(1, 3, H, W)`` float32 sRGB in [0, 1], on the CPU.
        panorama: ``(1, 3, Hp, Wp)`` float32 sRGB in [0, 1] on the CPU, or ``None`` without the
            panorama branch.
        model_calls: velocity evaluations per branch, ``{"main": n, "pano": n}``.
        timings: seconds per stage: ``setup`` (warps to the device, I⁻'s pyramids), ``model``,
            ``codec`` (decode and encode), ``warp_blend``, ``step``.
        dumps: every ``dump_every`` steps, the decoded estimates before (``*_x0``) and after
            (``*_sync``) synchronisation, on the CPU.
        decisions: what the run modelled and why (:func:`snell_bench.sampler.adaptive.decide`).
    """

    image: torch.Tensor
    panorama: torch.Tensor | None
    model_calls: dict[str, int] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    dumps: list[dict] = field(default_factory=list)
    decisions: dict = field(default_factory=dict)


class _Clock:
    """Wall-clock seconds accumulated per stage (the keys of :attr:`SampleResult.timings`)."""

    def __init__(self) -> None:
        self.t: dict[str, float] = {"setup": 0.0, "model": 0.0, "codec": 0.0, "warp_blend": 0.0, "step": 0.0}

    def add(self, key: str, t0: float) -> None:
        """Add the time since ``t0`` (a :func:`time.perf_counter` reading) to ``key``."""
        self.t[key] += time.perf_counter() - t0


@dataclass
class _Prompts:
    """The text conditioning of both branches.

    Attributes:
        main: the main view's prompt, batch 1.
        pano: the panorama's prompt, batch 1 (``None`` without the panorama branch).
        both: both prompts, batch 2 in the order (main, panorama), for one model call on both
            latents when they have the same size; ``None`` otherwise.
    """

    main: Condition
    pano: Condition | None
    both: Condition | None


# ---------------------------------------------------------------------------- stages of the loop


def _check_i_minus(i_minus: torch.Tensor, height: int, width: int) -> None:
    """Raise ``ValueError`` unless ``i_minus`` is a finite ``(1, 3, height, width)`` image."""
    if tuple(i_minus.shape) != (1, 3, height, width):
        raise ValueError(f"i_minus must be (1, 3, {height}, {width}) for these warps, got {tuple(i_minus.shape)}")
    if not torch.isfinite(i_minus).all():
        raise ValueError("i_minus holds NaN or inf")


def _noise_schedule(gen: Generator, s: SamplerSettings, height: int, width: int) -> torch.Tensor:
    """The generator's ``T + 1`` noise levels for the main view's size (``ValueError`` otherwise)."""
    sigmas = gen.sigmas(s.steps, height, width, kind=s.schedule)
    T = s.steps
    if tuple(sigmas.shape) != (T + 1,):
        raise ValueError(
            f"{gen.name}.sigmas gave {tuple(sigmas.shape)} noise levels for {T} steps, expected ({T + 1},)"
        )
    return sigmas


def _encode_prompts(gen: Generator, prompt: str, pano_prompt: str, use_pano: bool, same_size: bool) -> _Prompts:
    """The conditioning of the main view, the panorama (with ``use_pano``) and both in one batch
    (with ``use_pano`` and ``same_size``: both latents have the same shape)."""
    main = gen.condition([prompt], ["main"])
    pano = gen.condition([pano_prompt], ["pano"]) if use_pano else None
    both = gen.condition([prompt, pano_prompt], ["main", "pano"]) if use_pano and same_size else None
    return _Prompts(main=main, pano=pano, both=both)


def _block(i: int, s: SamplerSettings) -> tuple[int, int, int]:
    """The block of steps that starts at step ``i``: its length and how often each branch runs it.

    Inside the time-travel window ``[tt_window[0] T, tt_window[1] T)`` a block is ``tt_length`` steps
    (fewer at the end) run ``tt_repeats_main`` / ``tt_repeats_pano`` times; elsewhere one step, run
    once. Without the panorama branch its repeat count is 0.

    Returns:
        ``(length, repeats_main, repeats_pano)``.
    """
    T = s.steps
    travel = s.sync == "snellcaster" and s.time_travel and s.tt_window[0] * T <= i < s.tt_window[1] * T
    length = min(s.tt_length, T - i) if travel else 1
    repeats_main = s.tt_repeats_main if travel else 1
    repeats_pano = (s.tt_repeats_pano if travel else 1) if s.uses_panorama else 0
    return length, repeats_main, repeats_pano


def _estimate_x0(
    gen: Generator,
    z_main: torch.Tensor,
    z_pano: torch.Tensor | None,
    sigma: float,
    prompts: _Prompts,
    run_main: bool,
    run_pano: bool,
    calls: dict[str, int],
    clock: _Clock,
) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """The model calls of one step and the clean latent estimates ``x0_hat = z - sigma v``.

    Both branches go through one batched call when both run and :attr:`_Prompts.both` exists.
    ``calls`` and ``clock`` (``model``) are updated in place.

    Args:
        z_main: ``(1, C, h, w)`` the main view's latent at ``sigma``.
        z_pano: ``(1, C, hp, wp)`` the panorama's latent at ``sigma``, or ``None``.
        sigma: the noise level.
        run_main: the main view runs this step.
        run_pano: the panorama runs this step.

    Returns:
        ``(x0_main, x0_pano)``, latents of the shapes of ``z``; ``None`` for a branch that does not run.
    """
    t0 = time.perf_counter()
    v_main = v_pano = None
    if run_main and run_pano and prompts.both is not None:
        v = gen.velocity(torch.cat([z_main, z_pano]), sigma, prompts.both)
        v_main, v_pano = v[:1], v[1:]
    else:
        if run_main:
            v_main = gen.velocity(z_main, sigma, prompts.main)
        if run_pano:
            v_pano = gen.velocity(z_pano, sigma, prompts.pano)
    calls["main"] += int(run_main)
    calls["pano"] += int(run_pano)
    clock.add("model", t0)
    x0_main = euler_estimate(z_main, v_main, sigma) if run_main else None
    x0_pano = euler_estimate(z_pano, v_pano, sigma) if run_pano else None
    return x0_main, x0_pano


def _decode(gen: Generator, latent: torch.Tensor | None, clock: _Clock) -> torch.Tensor | None:
    """``(1, C, h, w)`` latent -> ``(1, 3, H, W)`` sRGB image in [0, 1] (``None`` -> ``None``);
    the time counts as ``codec``."""
    t0 = time.perf_counter()
    out = gen.decode(latent) if latent is not None else None
    clock.add("codec", t0)
    return out


def _warp_and_blend(
    views: Views,
    x0_main: torch.Tensor | None,
    x0_pano: torch.Tensor | None,
    run_main: bool,
    run_pano: bool,
    clock: _Clock,
) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """The synchronized estimates of the branches that run (:meth:`Views.blend_main`,
    :meth:`Views.blend_pano`), each reading the other's latest decoded estimate; the time counts as
    ``warp_blend``.

    Args:
        x0_main: ``(1, 3, H, W)`` sRGB in [0, 1], the main view's latest decoded estimate.
        x0_pano: ``(1, 3, Hp, Wp)`` sRGB in [0, 1], the panorama's, or ``None``.

    Returns:
        ``(sync_main, sync_pano)`` sRGB images, ``None`` for a branch that does not run.
    """
    t0 = time.perf_counter()
    g_main, g_pano = views.gauss(x0_main), views.gauss(x0_pano, wrap_x=True)
    sync_main = views.blend_main(x0_main, x0_pano, g_main, g_pano) if run_main else None
    sync_pano = views.blend_pano(x0_pano, x0_main, g_pano, g_main) if run_pano else None
    clock.add("warp_blend", t0)
    return sync_main, sync_pano


def _encode(
    gen: Generator,
    sync_main: torch.Tensor | None,
    sync_pano: torch.Tensor | None,
    run_main: bool,
    run_pano: bool,
    clock: _Clock,
) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """The synchronized images ``(1, 3, ., .)`` sRGB in [0, 1] of the branches that run as clean
    latents ``(1, C, ., .)`` (``None`` for the others); the time counts as ``codec``."""
    t0 = time.perf_counter()
    x0_main = gen.encode(sync_main) if run_main else None
    x0_pano = gen.encode(sync_pano) if run_pano else None
    clock.add("codec", t0)
    return x0_main, x0_pano


def _step(
    z: torch.Tensor,
    x0: torch.Tensor,
    sigma: float,
    sigma_next: float,
    s: SamplerSettings,
    rng: torch.Generator,
    keep: Callable[[torch.Tensor], torch.Tensor],
    model_dtype: torch.dtype | None,
) -> torch.Tensor:
    """One branch's step from ``sigma`` to ``sigma_next`` with the clean estimate ``x0``.

    Stochastic (``s.stochastic``: fresh noise from ``rng``, then rounded by ``keep``), else
    deterministic: the scheduler's step with latents held in ``model_dtype`` when the latents are
    rounded to the model's dtype (:func:`~snell_bench.sampler.steps.pipeline_step`), else
    :func:`~snell_bench.sampler.steps.sync_step`.

    Args:
        z: ``(1, C, h, w)`` float32 latent at ``sigma``.
        x0: ``(1, C, h, w)`` clean latent estimate.
        keep: :func:`~snell_bench.sampler.steps.latent_rounding` of the run.
        model_dtype: :func:`~snell_bench.sampler.steps.rounding_dtype` of the run.

    Returns:
        ``(1, C, h, w)`` float32 latent at ``sigma_next``.
    """
    if s.stochastic:
        return keep(stochastic_step(z, x0, sigma, sigma_next, rng, s.eta))
    if model_dtype is not None:
        return pipeline_step(z, x0, sigma, sigma_next, model_dtype)
    return sync_step(z, x0, sigma, sigma_next)


def _to_host(x: torch.Tensor | None) -> torch.Tensor | None:
    return None if x is None else x.cpu()


# ---------------------------------------------------------------------------- the sampler


def sample(
    gen: Generator,
    warps: WarpSet,
    i_minus: torch.Tensor,
    prompt: str,
    pano_prompt: str,
    settings: SamplerSettings,
    seed: int = 0,
) -> SampleResult:
    """Generate the main image (and the panorama) for one scene. Deterministic for a given seed.

    With ``settings.sync == "none"`` the generator runs alone on ``prompt`` (the text-to-image
    baseline). Without the panorama branch, the reflection comes from I⁻ where the mirror ray
    reaches a surface it shows, and is left out elsewhere. Both branches step through the
    generator's schedule for the main view, ``gen.sigmas(settings.steps, H, W, kind=settings.schedule)``
    (their noise levels must match to be blended).

    Args:
        gen: the generator (any backend of :class:`~snell_bench.models.base.Generator`).
        warps: the scene's warps; their camera fixes the image size ``H x W``.
        i_minus: ``(1, 3, H, W)`` sRGB object-free image of the warps' camera.
        prompt: the main view's prompt.
        pano_prompt: the panorama's prompt.
        settings: the sampler's knobs.
        seed: seeds the initial noise and every stochastic step.

    Returns:
        The main image ``(1, 3, H, W)``, the panorama (or ``None``), model-call counts, timings,
        dumps and the run's decisions.

    Raises:
        ValueError: if ``i_minus`` has the wrong shape or is not finite, or the generator's
            schedule does not have ``settings.steps + 1`` levels.
    """
    # 1. check inputs; decide what the scene needs modelled; the noise schedule
    H, W = warps.camera.shape
    _check_i_minus(i_minus, H, W)
    s, decisions, reflection_mask = decide(warps, settings)
    if decisions.get("panorama", {}).get("used") is False and "observed_share" in decisions["panorama"]:
        log.info(
            "panorama branch skipped: %.1f %% of object pixels observed in I⁻",
            100 * decisions["panorama"]["observed_share"],
        )
    T = s.steps
    use_pano = s.uses_panorama
    synchronised = s.sync == "snellcaster"
    shape_main = gen.geometry.latent_shape(H, W)
    shape_pano = gen.geometry.latent_shape(*warps.pano.shape) if use_pano else None
    sigmas = _noise_schedule(gen, s, H, W)
    dev = generator_device(gen)
    clock = _Clock()

    # 2. encode prompts
    prompts = _encode_prompts(gen, prompt, pano_prompt, use_pano, shape_main == shape_pano)

    # 3. prepare latents: initial noise from the run's generator, main view first
    rng = torch.Generator(dev).manual_seed(int(seed))
    keep = latent_rounding(gen, s.latent_dtype)
    model_dtype = rounding_dtype(gen, s.latent_dtype)
    z_main = keep(torch.randn((1,) + shape_main, generator=rng, device=dev))
    z_pano = keep(torch.randn((1,) + shape_pano, generator=rng, device=dev)) if use_pano else None

    # 4. prepare warps: maps on the device, I⁻'s warped pyramids
    t0 = time.perf_counter()
    views = Views(warps, i_minus.float(), s, reflection_mask, device=dev) if synchronised else None
    clock.add("setup", t0)

    # 5. denoising loop, in blocks (one step, or a time-travel block run several times per branch)
    calls = {"main": 0, "pano": 0}
    dumps: list[dict] = []
    bar = tqdm(total=T, desc=f"sampling ({s.sync})", disable=not s.progress, leave=False)
    i = 0
    with torch.inference_mode():
        while i < T:
            length, repeats_main, repeats_pano = _block(i, s)
            repeats = max(repeats_main, repeats_pano)
            # each branch's latest decoded estimate per step of the block, lent to the other's blends
            latest_main: list[torch.Tensor | None] = [None] * length
            latest_pano: list[torch.Tensor | None] = [None] * length
            for r in range(repeats):
                run_main, run_pano = r < repeats_main, r < repeats_pano
                for j in range(length):
                    k = i + j
                    sigma, sigma_next = float(sigmas[k]), float(sigmas[k + 1])
                    dump = bool(s.dump_every) and k % s.dump_every == 0 and r == repeats - 1
                    # the synchronised blends need the decoded estimates; the generator alone (and an
                    # unsynchronised last step) decodes nothing before the final image
                    sync = views is not None and (s.sync_last_step or k < T - 1)

                    # 5a. estimate x0 (clean latents)
                    x0_main, x0_pano = _estimate_x0(
                        gen, z_main, z_pano, sigma, prompts, run_main, run_pano, calls, clock
                    )

                    # 5b. decode the estimates
                    img_main = _decode(gen, x0_main, clock) if sync or dump else None
                    img_pano = _decode(gen, x0_pano, clock) if sync or dump else None
                    if run_main:
                        latest_main[j] = img_main
                    if run_pano:
                        latest_pano[j] = img_pano
                    img_main, img_pano = latest_main[j], latest_pano[j]

                    # 5c. warp and blend; 5d. encode the synchronised images
                    sync_main = sync_pano = None
                    if sync:
                        sync_main, sync_pano = _warp_and_blend(views, img_main, img_pano, run_main, run_pano, clock)
                        x0_main, x0_pano = _encode(gen, sync_main, sync_pano, run_main, run_pano, clock)

                    # 5e. step each running branch with its (synchronised) estimate
                    t0 = time.perf_counter()
                    if run_main:
                        z_main = _step(z_main, x0_main, sigma, sigma_next, s, rng, keep, model_dtype)
                    if run_pano:
                        z_pano = _step(z_pano, x0_pano, sigma, sigma_next, s, rng, keep, model_dtype)
                    clock.add("step", t0)

                    if dump:
                        dumps.append(
                            {
                                "step": k,
                                "sigma": sigma,
                                "main_x0": _to_host(img_main),
                                "main_sync": _to_host(sync_main if sync else img_main) if run_main else None,
                                "pano_x0": _to_host(img_pano),
                                "pano_sync": _to_host(sync_pano if sync else img_pano) if run_pano else None,
                            }
                        )

                # 5f. time travel: renoise to the block's start each branch that repeats again
                if r + 1 < repeats_main:
                    z_main = keep(renoise(z_main, float(sigmas[i + length]), float(sigmas[i]), rng))
                if r + 1 < repeats_pano:
                    z_pano = keep(renoise(z_pano, float(sigmas[i + length]), float(sigmas[i]), rng))
            i += length
            bar.update(length)
        bar.close()

        # 6. decode the final latents (only the final images and the dumps leave the device)
        image = _decode(gen, z_main, clock).cpu()
        pano = _decode(gen, z_pano, clock).cpu() if use_pano else None
    return SampleResult(
        image=image, panorama=pano, model_calls=calls, timings=dict(clock.t), dumps=dumps, decisions=decisions
    )
