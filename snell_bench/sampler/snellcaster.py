"""The synchronized two-branch sampler (Snellcaster), its ablations, and the plain baseline.

Per denoising step ``i`` (the paper's §4; stage numbers as in :func:`sample`):

5a. the generator's velocity for the main view and the panorama (one batched call when both latents
    have the same size) gives Euler estimates ``x0_hat = z - sigma_i v``;
5b. both estimates are decoded to images (``quantize``: rounded to 8 bits);
5c. main view: ``phi((x0, x0_pano, I⁻), (identity, π⁻¹, π^R), lambda)`` (``dpa_domain``: on whole
    images in [-1, 1], or per Laplacian band; π⁻¹ over the object or the whole frame,
    ``pano_to_main``), then the reflection ``π^-R(x0_pano)`` mixed in by Fresnel in linear RGB
    inside the object; panorama: ``phi((x0_pano, x0, I⁻), (identity, π, π))`` (the main estimate only
    where the perspective pixel does not show the object itself); ``quantize``: the synchronised
    images truncated to 8 bits;
5d. the synchronised images are encoded (``encode``: posterior mean or a draw);
5e. guided time travel (``tt_mode: guided``, steps ``i`` in the window ``[0.2 T, 0.8 T)``): each
    branch with ``R > 1`` repeats (``tt_repeats_main`` / ``tt_repeats_pano``) ``R - 1`` times
    {renoise ``z`` from ``sigma_i`` to ``sigma_{i - tt_length}`` (``tt_renoise``; no repeat would go
    before the first level), step back to ``sigma_i`` with the same synchronised estimate}; no model
    call at the noisier level. The branches that moved are re-predicted at ``sigma_i`` (5a, one
    call), and both branches are decoded and synchronised again (5b-5d), the panorama with the main
    view's post-travel estimate;
5f. each branch steps to ``sigma_{i+1}`` with its synchronised estimate (deterministic, ``sde``:
    the Euler-Maruyama step, or ``stochastic``).

Time travel ``tt_mode: repaint``: a block of ``tt_length`` steps is run (5a-5d, 5f at every level),
renoised back to its start (5g) and run again, ``tt_repeats_main`` times for the main view and
``tt_repeats_pano`` times for the panorama; a branch that stops repeating early keeps its latest
latent and lends its latest estimates to the other's blends, so every model call's output is used.

Model calls per branch: one per step, plus in ``guided`` mode one per window step (from step
``tt_length`` on) for a branch that travelled (``R > 1``), plus in ``repaint`` mode ``R - 1`` per
step of the blocks that start in the window (:attr:`SampleResult.model_calls`,
:func:`expected_model_calls`).

Convention:
    - Images ``(1, 3, H, W)`` (main view) and ``(1, 3, Hp, Wp)`` (panorama, ``Wp = 2 Hp``), float32
      sRGB in [0, 1]; warps as in :class:`~snell_bench.optics.WarpSet` (backward maps ``(H', W', 2)``
      in pixels, order x, y, NaN where invalid).
    - Latents ``(1, C, h, w)`` float32, unpacked (:class:`~snell_bench.models.base.LatentGeometry`);
      ``z_sigma = (1 - sigma) x0 + sigma eps`` (:mod:`snell_bench.sampler.steps`).
    - Every random draw (initial noise, noisy steps, time travel, posterior samples of ``encode``)
      comes from one ``torch.Generator`` on the generator's device, seeded with ``seed``, in loop
      order: the main view's draw before the panorama's at every point where both draw (in guided
      time travel, all of the main view's repeats before the panorama's).
    - A generator on ``meta`` (shapes, no data; :func:`~snell_bench.utils.tensors.is_meta`) runs the
      whole loop at any size without arithmetic: every stage that reads values on the host takes
      its general path (the same shapes), the warps and blends run once per shape
      (:func:`~snell_bench.utils.tensors.meta_shape_cache`), the random draws have no data (the
      run's generator is then a CPU one) and the images stay on ``meta``. It checks shapes, dtypes
      and the model calls (:func:`expected_model_calls`), not numbers.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from tqdm.auto import tqdm

from snell_bench.config.sampler import SamplerSettings
from snell_bench.models.base import Condition, Generator, generator_device, has_posterior
from snell_bench.optics.warps import WarpSet
from snell_bench.sampler.adaptive import decide
from snell_bench.sampler.eight_bit import to_8bit_floor, to_8bit_round
from snell_bench.sampler.steps import (
    euler_estimate,
    latent_rounding,
    pipeline_step,
    renoise,
    renoise_euler_maruyama,
    rounding_dtype,
    sde_step,
    seeded_generator,
    stochastic_step,
    sync_step,
)
from snell_bench.sampler.views import Views
from snell_bench.utils.tensors import digest, is_meta, to_host

log = logging.getLogger(__name__)

__all__ = ["SampleResult", "expected_model_calls", "sample"]


@dataclass
class SampleResult:
    """What :func:`sample` returns.

    Attributes:
        image: ``(1, 3, H, W)`` float32 sRGB in [0, 1], on the CPU (on ``meta`` for a generator
            there: no data to copy).
        panorama: ``(1, 3, Hp, Wp)`` float32 sRGB in [0, 1] on the CPU (likewise), or ``None``
            without the panorama branch.
        model_calls: velocity evaluations per branch actually made, ``{"main": n, "pano": n}`` (a
            batched call on both latents counts once for each).
        timings: seconds per stage: ``setup`` (warps to the device, I⁻'s pyramids), ``model``,
            ``codec`` (decode and encode), ``warp_blend``, ``step``.
        dumps: every ``dump_every`` steps, the decoded estimates before (``*_x0``) and after
            (``*_sync``) synchronisation, on the CPU (likewise).
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
    """Raise ``ValueError`` unless ``i_minus`` is a finite ``(1, 3, height, width)`` image (on
    ``meta``, the shape alone)."""
    if tuple(i_minus.shape) != (1, 3, height, width):
        raise ValueError(f"i_minus must be (1, 3, {height}, {width}) for these warps, got {tuple(i_minus.shape)}")
    if not is_meta(i_minus) and not torch.isfinite(i_minus).all():
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


def _in_window(i: int, s: SamplerSettings) -> bool:
    """Step ``i`` lies in the time-travel window ``[tt_window[0] T, tt_window[1] T)`` of a
    synchronised run with time travel (both bounds rounded down with ``tt_window_floor``)."""
    T = s.steps
    lo, hi = T * s.tt_window[0], T * s.tt_window[1]
    if s.tt_window_floor:
        lo, hi = int(lo), int(hi)
    return s.sync == "snellcaster" and s.time_travel and lo <= i < hi


def _block(i: int, s: SamplerSettings) -> tuple[int, int, int]:
    """The block of steps that starts at step ``i``: its length and how often each branch runs it.

    With ``tt_mode: repaint``, inside the time-travel window a block is ``tt_length`` steps (fewer at
    the end) run ``tt_repeats_main`` / ``tt_repeats_pano`` times; otherwise (and always with
    ``guided``, whose travel happens inside the step) one step, run once. Without the panorama
    branch its repeat count is 0.

    Returns:
        ``(length, repeats_main, repeats_pano)``.
    """
    travel = s.tt_mode == "repaint" and _in_window(i, s)
    length = min(s.tt_length, s.steps - i) if travel else 1
    repeats_main = s.tt_repeats_main if travel else 1
    repeats_pano = (s.tt_repeats_pano if travel else 1) if s.uses_panorama else 0
    return length, repeats_main, repeats_pano


def _guided_repeats(i: int, s: SamplerSettings) -> tuple[int, int]:
    """How many times each branch runs step ``i`` with guided time travel (``(1, 1)`` outside the
    window or with ``repaint``; the panorama's count without the panorama branch is 0)."""
    travel = s.tt_mode == "guided" and _in_window(i, s)
    main = s.tt_repeats_main if travel else 1
    pano = (s.tt_repeats_pano if travel else 1) if s.uses_panorama else 0
    return main, pano


def expected_model_calls(s: SamplerSettings) -> dict[str, int]:
    """The velocity calls per branch that :func:`sample` makes with settings ``s``, in closed form.

    With ``T`` steps, the time-travel window's steps ``a <= i < b`` (``a = ceil(tt_window[0] T)``,
    ``b = ceil(tt_window[1] T)``; ``floor`` of both with ``tt_window_floor``), ``n = b - a`` of them,
    the travel length ``l`` and ``R`` repeats of a branch (``tt_repeats_main`` / ``tt_repeats_pano``):

    - no time travel (``time_travel: false``, ``sync: none``, or ``R = 1``): ``T``;
    - ``guided``: ``T + [R > 1] max(0, b - max(a, l))``: one re-prediction per window step that
      has a level ``l`` steps back to travel to, however many repeats;
    - ``repaint``: ``T + (R - 1) min(T - a, ceil(n / l) l)``: every step of the ``ceil(n / l)``
      blocks of ``l`` steps that start in the window (the last one cut at ``T``) runs ``R`` times.

    The panorama's count is 0 without its branch (``sync: none`` or ``panorama: false``). A batched
    call on both latents counts once for each branch, as :attr:`SampleResult.model_calls` does.

    Args:
        s: the settings the run uses (with ``skip_panorama_above``, the panorama's decision is the
            scene's: pass the settings with ``panorama`` as the run's ``decisions`` record it).

    Returns:
        ``{"main": n_main, "pano": n_pano}``.

    Examples:
        The paper's settings (T = 20, window [0.2 T, 0.8 T), main view x3, panorama x1):

        >>> expected_model_calls(SamplerSettings())
        {'main': 32, 'pano': 20}
        >>> expected_model_calls(SamplerSettings(tt_mode="repaint"))
        {'main': 44, 'pano': 20}
    """
    T, length = s.steps, s.tt_length
    rnd = math.floor if s.tt_window_floor else math.ceil
    a, b = (min(max(rnd(T * w), 0), T) for w in s.tt_window)
    travels = s.sync == "snellcaster" and s.time_travel and b > a

    def calls(repeats: int) -> int:
        if not travels or repeats == 1:
            return T
        if s.tt_mode == "guided":
            return T + max(0, b - max(a, length))
        return T + (repeats - 1) * min(T - a, -(-(b - a) // length) * length)

    return {"main": calls(s.tt_repeats_main), "pano": calls(s.tt_repeats_pano) if s.uses_panorama else 0}


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


def _decode_estimate(gen: Generator, latent: torch.Tensor | None, quantize: bool, clock: _Clock):
    """:func:`_decode` of a clean-latent estimate, rounded to 8 bits with ``quantize``
    (:func:`~snell_bench.sampler.eight_bit.to_8bit_round`)."""
    img = _decode(gen, latent, clock)
    return to_8bit_round(img) if quantize and img is not None else img


def _warp_and_blend(
    views: Views,
    x0_main: torch.Tensor | None,
    x0_pano: torch.Tensor | None,
    run_main: bool,
    run_pano: bool,
    quantize: bool,
    clock: _Clock,
) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """The synchronized estimates of the branches that run (:meth:`Views.blend_main`,
    :meth:`Views.blend_pano`), each reading the other's latest decoded estimate, truncated to 8 bits
    with ``quantize`` (:func:`~snell_bench.sampler.eight_bit.to_8bit_floor`); the time counts as
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
    if quantize:
        sync_main = to_8bit_floor(sync_main) if sync_main is not None else None
        sync_pano = to_8bit_floor(sync_pano) if sync_pano is not None else None
    clock.add("warp_blend", t0)
    return sync_main, sync_pano


def _encode(
    gen: Generator,
    sync_main: torch.Tensor | None,
    sync_pano: torch.Tensor | None,
    run_main: bool,
    run_pano: bool,
    rng: torch.Generator | None,
    clock: _Clock,
) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """The synchronized images ``(1, 3, ., .)`` sRGB in [0, 1] of the branches that run as clean
    latents ``(1, C, ., .)`` (``None`` for the others): the posterior mean, or with ``rng`` a draw
    from the posterior (main view first); the time counts as ``codec``."""
    t0 = time.perf_counter()
    x0_main = gen.encode(sync_main, generator=rng) if run_main else None
    x0_pano = gen.encode(sync_pano, generator=rng) if run_pano else None
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

    Euler-Maruyama (``s.sde``, :func:`~snell_bench.sampler.steps.sde_step`) or stochastic
    (``s.stochastic``), each with fresh noise from ``rng`` and rounded by ``keep``, else
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
    if s.sde:
        return keep(sde_step(z, x0, sigma, sigma_next, rng))
    if s.stochastic:
        return keep(stochastic_step(z, x0, sigma, sigma_next, rng, s.eta))
    if model_dtype is not None:
        return pipeline_step(z, x0, sigma, sigma_next, model_dtype)
    return sync_step(z, x0, sigma, sigma_next)


def _renoise(z: torch.Tensor, sigma: float, s_to: float, s: SamplerSettings, rng: torch.Generator) -> torch.Tensor:
    """Time travel from ``sigma`` to the noisier ``s_to`` with the run's kernel (``tt_renoise``:
    :func:`~snell_bench.sampler.steps.renoise` or
    :func:`~snell_bench.sampler.steps.renoise_euler_maruyama`)."""
    if s.tt_renoise == "euler_maruyama":
        return renoise_euler_maruyama(z, sigma, s_to, rng)
    return renoise(z, sigma, s_to, rng)


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
        seed: seeds every random draw (initial noise, noisy steps, time travel, posterior samples).

    Returns:
        The main image ``(1, 3, H, W)``, the panorama (or ``None``), model-call counts, timings,
        dumps and the run's decisions (with ``encode``: whether the posterior was sampled).

    Raises:
        ValueError: if ``i_minus`` has the wrong shape or is not finite, the generator's schedule
            does not have ``settings.steps + 1`` levels, or ``pano_to_main: frame`` meets warps
            without ``pano_refraction_frame``.
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
    synchronised = s.sync == "snellcaster"
    if synchronised:
        sampled = s.encode == "sample" and has_posterior(gen)
        decisions["encode"] = {"mode": s.encode, "posterior_sampled": sampled}
        if s.encode == "sample" and not sampled:
            log.info("sampler.encode=sample: %s has no posterior to sample, its encoder gives the mean", gen.name)
    T = s.steps
    use_pano = s.uses_panorama
    shape_main = gen.geometry.latent_shape(H, W)
    shape_pano = gen.geometry.latent_shape(*warps.pano.shape) if use_pano else None
    sigmas = _noise_schedule(gen, s, H, W)
    dev = generator_device(gen)
    clock = _Clock()

    # 2. encode prompts
    prompts = _encode_prompts(gen, prompt, pano_prompt, use_pano, shape_main == shape_pano)

    # 3. prepare latents: initial noise from the run's generator, main view first
    rng = seeded_generator(dev, seed)
    keep = latent_rounding(gen, s.latent_dtype)
    model_dtype = rounding_dtype(gen, s.latent_dtype)
    noise = torch.randn((1,) + shape_main, generator=rng, device=dev)
    decisions["initial_noise"] = digest(noise)  # a generated I⁻ of the same seed drew the same
    z_main = keep(noise)
    z_pano = keep(torch.randn((1,) + shape_pano, generator=rng, device=dev)) if use_pano else None

    # 4. prepare warps: maps on the device, I⁻'s warped pyramids
    t0 = time.perf_counter()
    views = Views(warps, i_minus.float(), s, reflection_mask, device=dev) if synchronised else None
    clock.add("setup", t0)

    # 5. denoising loop, in blocks (one step; with repaint time travel, a block run several times)
    calls = {"main": 0, "pano": 0}
    dumps: list[dict] = []
    enc_rng = rng if s.encode == "sample" else None
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

                    # 5b. decode the estimates (8-bit with quantize)
                    img_main = _decode_estimate(gen, x0_main, s.quantize, clock) if sync or dump else None
                    img_pano = _decode_estimate(gen, x0_pano, s.quantize, clock) if sync or dump else None
                    if run_main:
                        latest_main[j] = img_main
                    if run_pano:
                        latest_pano[j] = img_pano
                    img_main, img_pano = latest_main[j], latest_pano[j]

                    # 5c. warp and blend; 5d. encode the synchronised images
                    sync_main = sync_pano = None
                    if sync:
                        sync_main, sync_pano = _warp_and_blend(
                            views, img_main, img_pano, run_main, run_pano, s.quantize, clock
                        )
                        x0_main, x0_pano = _encode(gen, sync_main, sync_pano, run_main, run_pano, enc_rng, clock)

                    # 5e. guided time travel: renoise and step back with the same synchronised
                    # estimates, then re-predict the branches that moved and synchronise both again
                    travel_main, travel_pano = _guided_repeats(k, s)
                    moved_main = moved_pano = False
                    back = k - s.tt_length  # the noisier level's index
                    if max(travel_main, travel_pano) > 1 and back >= 0:
                        t0 = time.perf_counter()
                        noisier = float(sigmas[back])
                        for _ in range(travel_main - 1):
                            z_main = keep(_renoise(z_main, sigma, noisier, s, rng))
                            z_main = _step(z_main, x0_main, noisier, sigma, s, rng, keep, model_dtype)
                            moved_main = True
                        for _ in range(travel_pano - 1):
                            z_pano = keep(_renoise(z_pano, sigma, noisier, s, rng))
                            z_pano = _step(z_pano, x0_pano, noisier, sigma, s, rng, keep, model_dtype)
                            moved_pano = True
                        clock.add("step", t0)
                        new_main, new_pano = _estimate_x0(
                            gen, z_main, z_pano, sigma, prompts, moved_main, moved_pano, calls, clock
                        )
                        if moved_main:
                            x0_main = new_main
                            img_main = _decode_estimate(gen, new_main, s.quantize, clock) if sync or dump else None
                        if moved_pano:
                            x0_pano = new_pano
                            img_pano = _decode_estimate(gen, new_pano, s.quantize, clock) if sync or dump else None
                        if sync:
                            sync_main, sync_pano = _warp_and_blend(
                                views, img_main, img_pano, True, use_pano, s.quantize, clock
                            )
                            x0_main, x0_pano = _encode(gen, sync_main, sync_pano, True, use_pano, enc_rng, clock)

                    # 5f. step each running branch with its (synchronised) estimate
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
                                "main_x0": to_host(img_main),
                                "main_sync": to_host(sync_main if sync else img_main) if run_main else None,
                                "pano_x0": to_host(img_pano),
                                "pano_sync": to_host(sync_pano if sync else img_pano) if run_pano else None,
                            }
                        )

                # 5g. repaint time travel: renoise to the block's start each branch that repeats again
                if r + 1 < repeats_main:
                    z_main = keep(_renoise(z_main, float(sigmas[i + length]), float(sigmas[i]), s, rng))
                if r + 1 < repeats_pano:
                    z_pano = keep(_renoise(z_pano, float(sigmas[i + length]), float(sigmas[i]), s, rng))
            i += length
            bar.update(length)
        bar.close()

        # 6. decode the final latents (only the final images and the dumps leave the device)
        image = to_host(_decode(gen, z_main, clock))
        pano = to_host(_decode(gen, z_pano, clock)) if use_pano else None
    return SampleResult(
        image=image, panorama=pano, model_calls=calls, timings=dict(clock.t), dumps=dumps, decisions=decisions
    )
