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

The loop walks a plan of visits of the noise levels made from the settings alone before it starts
(:mod:`snell_bench.sampler.plan`: predict 5a-5d, travel and return 5e and 5g, step 5f), each visit
reading and updating both branches' state (:class:`_Branches`).

Model calls per branch: one per step, plus in ``guided`` mode one per window step (from step
``tt_length`` on) for a branch that travelled (``R > 1``), plus in ``repaint`` mode ``R - 1`` per
step of the blocks that start in the window (:attr:`SampleResult.model_calls`,
:func:`expected_model_calls`, which counts them in the plan).

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
from snell_bench.sampler.plan import BRANCHES, Visit, expected_model_calls, visits
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


@dataclass
class _Run:
    """What every visit of the loop reads, fixed for the run.

    Attributes:
        gen: the generator.
        s: the settings after the scene's decisions (:func:`~snell_bench.sampler.adaptive.decide`).
        sigmas: the ``T + 1`` noise levels (the plan's level indices point into it).
        prompts: both branches' conditioning.
        views: the warps and blends, or ``None`` unsynchronised (``sync: none``).
        keep: :func:`~snell_bench.sampler.steps.latent_rounding` of the run.
        model_dtype: :func:`~snell_bench.sampler.steps.rounding_dtype` of the run.
    """

    gen: Generator
    s: SamplerSettings
    sigmas: torch.Tensor
    prompts: _Prompts
    views: Views | None
    keep: Callable[[torch.Tensor], torch.Tensor]
    model_dtype: torch.dtype | None


def _no_branch() -> dict[str, torch.Tensor | None]:
    return dict.fromkeys(BRANCHES)


@dataclass
class _Branches:
    """Both branches' state as the loop walks the plan; every dict is keyed by branch (``main``, ``pano``).

    Attributes:
        z: ``(1, C, h, w)`` float32 latents at the level each branch has reached (``pano``: ``None``
            without the panorama branch).
        rng: the run's generator: every random draw.
        enc_rng: ``rng`` with ``encode: sample`` (posterior draws), else ``None``.
        x0: the latest clean-latent estimates (synchronised after a synchronised ``predict``).
        img: ``(1, 3, ., .)`` sRGB decoded estimates at the current level (``None`` where none was
            decoded); a branch the model did not evaluate shows its latest at that level.
        sync: the synchronised images at the current level (``None`` for a branch not blended).
        lent: per branch, its latest decoded estimate at each level of the current block.
        calls: velocity evaluations per branch (:attr:`SampleResult.model_calls`).
        clock: seconds per stage (:attr:`SampleResult.timings`).
        dumps: :attr:`SampleResult.dumps`.
    """

    z: dict[str, torch.Tensor | None]
    rng: torch.Generator
    enc_rng: torch.Generator | None
    x0: dict[str, torch.Tensor | None] = field(default_factory=_no_branch)
    img: dict[str, torch.Tensor | None] = field(default_factory=_no_branch)
    sync: dict[str, torch.Tensor | None] = field(default_factory=_no_branch)
    lent: dict[str, dict[int, torch.Tensor | None]] = field(default_factory=lambda: {b: {} for b in BRANCHES})
    calls: dict[str, int] = field(default_factory=lambda: dict.fromkeys(BRANCHES, 0))
    clock: _Clock = field(default_factory=_Clock)
    dumps: list[dict] = field(default_factory=list)


# ---------------------------------------------------------------------------- setting up a run


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


def _decide(gen: Generator, warps: WarpSet, i_minus: torch.Tensor, settings: SamplerSettings):
    """Stage 1 of :func:`sample`: check the inputs, decide what the scene needs modelled
    (:func:`~snell_bench.sampler.adaptive.decide`) and whether the encoder samples.

    Returns:
        ``(settings, decisions, reflection_mask)`` as :func:`~snell_bench.sampler.adaptive.decide`.
    """
    _check_i_minus(i_minus, *warps.camera.shape)
    s, decisions, reflection_mask = decide(warps, settings)
    if decisions.get("panorama", {}).get("used") is False and "observed_share" in decisions["panorama"]:
        log.info(
            "panorama branch skipped: %.1f %% of object pixels observed in I⁻",
            100 * decisions["panorama"]["observed_share"],
        )
    if s.sync == "snellcaster":
        sampled = s.encode == "sample" and has_posterior(gen)
        decisions["encode"] = {"mode": s.encode, "posterior_sampled": sampled}
        if s.encode == "sample" and not sampled:
            log.info("sampler.encode=sample: %s has no posterior to sample, its encoder gives the mean", gen.name)
    return s, decisions, reflection_mask


def _prepare(
    gen: Generator, warps: WarpSet, i_minus: torch.Tensor, settings: SamplerSettings, *, prompts: tuple, seed: int
) -> tuple[_Run, _Branches, dict]:
    """Stages 1-4 of :func:`sample` (its arguments; ``prompts``: the main view's and the panorama's).

    Returns:
        ``(run, branches, decisions)``: the loop's fixed inputs, the initial state (the initial noise
        drawn from the run's generator seeded with ``seed``, main view first) and the decisions.
    """
    # 1. check inputs; decide what the scene needs modelled; the noise schedule
    s, decisions, reflection_mask = _decide(gen, warps, i_minus, settings)
    H, W = warps.camera.shape
    shape = {"main": gen.geometry.latent_shape(H, W)}
    shape["pano"] = gen.geometry.latent_shape(*warps.pano.shape) if s.uses_panorama else None
    sigmas = _noise_schedule(gen, s, H, W)
    dev = generator_device(gen)
    clock = _Clock()

    # 2. encode prompts
    conds = _encode_prompts(gen, *prompts, s.uses_panorama, shape["main"] == shape["pano"])

    # 3. prepare latents: initial noise from the run's generator, main view first
    rng = seeded_generator(dev, seed)
    keep = latent_rounding(gen, s.latent_dtype)
    noise = torch.randn((1,) + shape["main"], generator=rng, device=dev)
    decisions["initial_noise"] = digest(noise)  # a generated I⁻ of the same seed drew the same
    z = {"main": keep(noise), "pano": None}
    if s.uses_panorama:
        z["pano"] = keep(torch.randn((1,) + shape["pano"], generator=rng, device=dev))
    state = _Branches(z=z, rng=rng, enc_rng=rng if s.encode == "sample" else None, clock=clock)

    # 4. prepare warps: maps on the device, I⁻'s warped pyramids
    t0 = time.perf_counter()
    views = Views(warps, i_minus.float(), s, reflection_mask, device=dev) if s.sync == "snellcaster" else None
    clock.add("setup", t0)
    run = _Run(gen, s, sigmas, conds, views, keep, rounding_dtype(gen, s.latent_dtype))
    return run, state, decisions


# ---------------------------------------------------------------------------- stages of the loop


def _estimate_x0(run: _Run, st: _Branches, branches: tuple[str, ...], sigma: float) -> None:
    """5a: the model calls at ``sigma`` for ``branches`` and their clean latent estimates
    ``x0_hat = z - sigma v`` into ``st.x0``.

    Both branches go through one batched call when both run and :attr:`_Prompts.both` exists.
    ``st.calls`` and ``st.clock`` (``model``) are updated.
    """
    t0 = time.perf_counter()
    z, p = st.z, run.prompts
    if len(branches) == 2 and p.both is not None:
        v = run.gen.velocity(torch.cat([z["main"], z["pano"]]), sigma, p.both)
        vel = {"main": v[:1], "pano": v[1:]}
    else:
        vel = {b: run.gen.velocity(z[b], sigma, getattr(p, b)) for b in branches}
    for b in branches:
        st.calls[b] += 1
    st.clock.add("model", t0)
    for b in branches:
        st.x0[b] = euler_estimate(z[b], vel[b], sigma)


def _decode(gen: Generator, latent: torch.Tensor | None, clock: _Clock) -> torch.Tensor | None:
    """``(1, C, h, w)`` latent -> ``(1, 3, H, W)`` sRGB image in [0, 1] (``None`` -> ``None``);
    the time counts as ``codec``."""
    t0 = time.perf_counter()
    out = gen.decode(latent) if latent is not None else None
    clock.add("codec", t0)
    return out


def _decode_estimate(run: _Run, latent: torch.Tensor | None, clock: _Clock) -> torch.Tensor | None:
    """5b: :func:`_decode` of a clean-latent estimate, rounded to 8 bits with ``quantize``
    (:func:`~snell_bench.sampler.eight_bit.to_8bit_round`)."""
    img = _decode(run.gen, latent, clock)
    return to_8bit_round(img) if run.s.quantize and img is not None else img


def _warp_and_blend(run: _Run, st: _Branches, blend: tuple[str, ...]) -> dict[str, torch.Tensor | None]:
    """5c: the synchronized estimates of the ``blend`` branches (:meth:`Views.blend_main`,
    :meth:`Views.blend_pano`), each reading the other's image in ``st.img``, truncated to 8 bits with
    ``quantize`` (:func:`~snell_bench.sampler.eight_bit.to_8bit_floor`); ``None`` for the other
    branches. The time counts as ``warp_blend``."""
    t0 = time.perf_counter()
    views, img = run.views, st.img
    g_main, g_pano = views.gauss(img["main"]), views.gauss(img["pano"], wrap_x=True)
    out = _no_branch()
    if "main" in blend:
        out["main"] = views.blend_main(img["main"], img["pano"], g_main, g_pano)
    if "pano" in blend:
        out["pano"] = views.blend_pano(img["pano"], img["main"], g_pano, g_main)
    if run.s.quantize:
        out = {b: to_8bit_floor(x) if x is not None else None for b, x in out.items()}
    st.clock.add("warp_blend", t0)
    return out


def _encode(run: _Run, st: _Branches, blend: tuple[str, ...]) -> dict[str, torch.Tensor | None]:
    """5d: the synchronized images ``st.sync`` of the ``blend`` branches as clean latents
    ``(1, C, ., .)`` (``None`` for the others): the posterior mean, or with ``st.enc_rng`` a draw
    from the posterior (main view first); the time counts as ``codec``."""
    t0 = time.perf_counter()
    out = {b: run.gen.encode(st.sync[b], generator=st.enc_rng) if b in blend else None for b in BRANCHES}
    st.clock.add("codec", t0)
    return out


def _step(run: _Run, z: torch.Tensor, x0: torch.Tensor, sigma: float, sigma_next: float, rng) -> torch.Tensor:
    """One branch's step from ``sigma`` to ``sigma_next`` with the clean estimate ``x0``.

    Euler-Maruyama (``s.sde``, :func:`~snell_bench.sampler.steps.sde_step`) or stochastic
    (``s.stochastic``), each with fresh noise from ``rng`` and rounded by ``run.keep``, else
    deterministic: the scheduler's step with latents held in ``run.model_dtype`` when the latents
    are rounded to the model's dtype (:func:`~snell_bench.sampler.steps.pipeline_step`), else
    :func:`~snell_bench.sampler.steps.sync_step`.

    Args:
        z: ``(1, C, h, w)`` float32 latent at ``sigma``.
        x0: ``(1, C, h, w)`` clean latent estimate.

    Returns:
        ``(1, C, h, w)`` float32 latent at ``sigma_next``.
    """
    s = run.s
    if s.sde:
        return run.keep(sde_step(z, x0, sigma, sigma_next, rng))
    if s.stochastic:
        return run.keep(stochastic_step(z, x0, sigma, sigma_next, rng, s.eta))
    if run.model_dtype is not None:
        return pipeline_step(z, x0, sigma, sigma_next, run.model_dtype)
    return sync_step(z, x0, sigma, sigma_next)


def _renoise(z: torch.Tensor, sigma: float, s_to: float, s: SamplerSettings, rng: torch.Generator) -> torch.Tensor:
    """Time travel from ``sigma`` to the noisier ``s_to`` with the run's kernel (``tt_renoise``:
    :func:`~snell_bench.sampler.steps.renoise` or
    :func:`~snell_bench.sampler.steps.renoise_euler_maruyama`)."""
    if s.tt_renoise == "euler_maruyama":
        return renoise_euler_maruyama(z, sigma, s_to, rng)
    return renoise(z, sigma, s_to, rng)


def _move(run: _Run, st: _Branches, v: Visit, sigma: float, sigma_to: float) -> None:
    """5e-5g: a ``travel`` (renoise back to ``sigma_to``), ``return`` or ``step`` (to ``sigma_to``
    with the held estimate) visit of each of ``v.branches`` in turn; the time counts as ``step``."""
    t0 = time.perf_counter()
    for b in v.branches:
        if v.op == "travel":
            st.z[b] = run.keep(_renoise(st.z[b], sigma, sigma_to, run.s, st.rng))
        else:
            st.z[b] = _step(run, st.z[b], st.x0[b], sigma, sigma_to, st.rng)
    st.clock.add("step", t0)


def _dump(st: _Branches, v: Visit, sigma: float) -> dict:
    """The dump of a ``step`` visit: the level's decoded estimates (``*_x0``) and synchronised images
    (``*_sync``; the estimate itself at an unsynchronised level, ``None`` for a branch that does not
    step), on the CPU."""
    out: dict = {"step": v.src, "sigma": sigma}
    for b in BRANCHES:
        out[f"{b}_x0"] = to_host(st.img[b])
        out[f"{b}_sync"] = to_host(st.sync[b] if v.sync else st.img[b]) if b in v.branches else None
    return out


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
    (their noise levels must match to be blended), visiting its levels in the order of the plan
    (:func:`~snell_bench.sampler.plan.visits`).

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
    # 1.-4. check inputs, decide, the noise schedule, prompts, initial noise, warps on the device
    run, st, decisions = _prepare(gen, warps, i_minus, settings, prompts=(prompt, pano_prompt), seed=seed)
    s = run.s
    bar = tqdm(total=s.steps, desc=f"sampling ({s.sync})", disable=not s.progress, leave=False)
    # 5. denoising loop: the plan's visits of the noise levels
    with torch.inference_mode():
        for v in visits(s):
            sigma, sigma_to = float(run.sigmas[v.src]), float(run.sigmas[v.dst])
            if v.op == "predict":
                # 5a. estimate x0 (clean latents); 5b. decode them (8-bit with quantize) for the
                # blends or a dump; a branch not evaluated lends its latest estimate at this level
                _estimate_x0(run, st, v.branches, sigma)
                for b in v.branches:
                    st.lent[b][v.src] = _decode_estimate(run, st.x0[b], st.clock) if v.sync or v.dump else None
                st.img = {b: st.lent[b].get(v.src) for b in BRANCHES}
                # 5c. warp and blend; 5d. encode the synchronised images
                st.sync = _warp_and_blend(run, st, v.blend) if v.sync else _no_branch()
                if v.sync:
                    st.x0 = _encode(run, st, v.blend)
                continue
            # 5e. guided time travel: renoise back and return with the held estimate; 5f. step each
            # running branch with its (synchronised) estimate; 5g. repaint: renoise to the block's start
            _move(run, st, v, sigma, sigma_to)
            if v.op == "step" and v.dump:
                st.dumps.append(_dump(st, v, sigma))
            if v.op == "step" and v.last:  # the level is done: nothing left to lend
                for lent in st.lent.values():
                    lent.pop(v.src, None)
                bar.update(1)
        bar.close()

        # 6. decode the final latents (only the final images and the dumps leave the device)
        image = to_host(_decode(gen, st.z["main"], st.clock))
        pano = to_host(_decode(gen, st.z["pano"], st.clock)) if s.uses_panorama else None
    return SampleResult(
        image=image, panorama=pano, model_calls=st.calls, timings=dict(st.clock.t), dumps=st.dumps, decisions=decisions
    )
