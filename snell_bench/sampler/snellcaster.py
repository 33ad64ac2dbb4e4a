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

Convention: images ``(1, 3, H, W)`` sRGB in [0, 1]; warps as in :class:`~snell_bench.optics.WarpSet`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm.auto import tqdm

from snell_bench.imaging.blend import blend_pyramids, fresnel_combine
from snell_bench.imaging.pyramid import gaussian_pyramid, laplacian_from_gaussian, pyramid_warp
from snell_bench.models.base import Generator, generator_device
from snell_bench.optics.warps import WarpSet
from snell_bench.sampler.adaptive import decide
from snell_bench.sampler.settings import SamplerSettings
from snell_bench.sampler.steps import (
    euler_estimate,
    latent_rounding,
    pipeline_step,
    renoise,
    rounding_dtype,
    stochastic_step,
    sync_step,
)

log = logging.getLogger(__name__)

__all__ = ["SampleResult", "sample"]


@dataclass
class SampleResult:
    image: torch.Tensor  # (1, 3, H, W)
    panorama: torch.Tensor | None  # (1, 3, Hp, Wp)
    model_calls: dict[str, int] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    dumps: list[dict] = field(default_factory=list)
    #: What the run modelled and why (:func:`snell_bench.sampler.adaptive.decide`).
    decisions: dict = field(default_factory=dict)


class _Clock:
    def __init__(self) -> None:
        self.t: dict[str, float] = {"setup": 0.0, "model": 0.0, "codec": 0.0, "warp_blend": 0.0, "step": 0.0}

    def add(self, key: str, t0: float) -> None:
        self.t[key] += time.perf_counter() - t0


def _nan_where(coords: np.ndarray, invalid: np.ndarray) -> np.ndarray:
    c = np.array(coords, dtype=np.float32, copy=True)
    c[invalid] = np.nan
    return c


class _Views:
    """Warp maps as tensors and the constant warps of I⁻, prepared once per run."""

    def __init__(
        self,
        ws: WarpSet,
        i_minus: torch.Tensor,
        s: SamplerSettings,
        reflection_mask: np.ndarray | None = None,
        device: torch.device | None = None,
    ) -> None:
        L = s.effective_levels
        self.levels = L
        self.roi = bool(s.roi)
        self._gauss_last: dict[bool, tuple[torch.Tensor, list[torch.Tensor]]] = {}
        self.lam = s.effective_lam
        dev = torch.device("cpu") if device is None else torch.device(device)

        def on_device(a: np.ndarray) -> torch.Tensor:  # every map and mask crosses to the device once
            return torch.from_numpy(np.ascontiguousarray(a)).to(dev)

        i_minus = i_minus.to(dev)
        self.object_mask = on_device(ws.object_mask)[None, None]
        self.fresnel = on_device(ws.fresnel)[None, None]
        # maps: NaN marks every invalid source, so the masks follow from the maps
        self.main_from_pano = on_device(ws.pano_refraction)
        self.main_refl_from_pano = on_device(ws.pano_reflection)
        refl_self = ws.reflection
        if reflection_mask is not None:  # reflect only where it is not negligible
            self.main_refl_from_pano = on_device(_nan_where(ws.pano_reflection, ~reflection_mask))
            refl_self = _nan_where(ws.reflection, ~reflection_mask)
        self.pano_from_main = on_device(_nan_where(ws.pano_to_persp, ws.pano_to_persp_object))
        self.refl_iminus = None  # reflection of I⁻ itself, for runs without the panorama branch
        if s.reflection and not s.uses_panorama:
            self.refl_iminus = pyramid_warp(i_minus, on_device(refl_self), levels=L, roi=self.roi)
        self.imin_main, self.imin_main_m = pyramid_warp(i_minus, on_device(ws.refraction), levels=L, collapse=False)
        self.imin_pano, self.imin_pano_m = pyramid_warp(
            i_minus, on_device(ws.pano_to_persp), levels=L, collapse=False, dest_wrap_x=True, roi=self.roi
        )

    @staticmethod
    def _own(gauss: list[torch.Tensor], wrap_x: bool = False):
        pyr = laplacian_from_gaussian(gauss, wrap_x=wrap_x)
        return pyr, [torch.ones((p.shape[0], 1) + p.shape[-2:], dtype=torch.bool, device=p.device) for p in pyr]

    def gauss(self, img: torch.Tensor | None, wrap_x: bool = False) -> list[torch.Tensor] | None:
        """The Gaussian pyramid of an estimate, built once and shared by its own Laplacian pyramid and
        every warp that reads it; an estimate lent unchanged to a time-travel repeat of the other
        branch is not decomposed again."""
        if img is None:
            return None
        last = self._gauss_last.get(wrap_x)
        if last is None or last[0] is not img:
            last = (img, gaussian_pyramid(img, self.levels, wrap_x=wrap_x))
            self._gauss_last[wrap_x] = last
        return last[1]

    def blend_main(
        self,
        x0: torch.Tensor,
        x0_pano: torch.Tensor | None,
        s: SamplerSettings,
        g_main: list[torch.Tensor] | None = None,
        g_pano: list[torch.Tensor] | None = None,
    ) -> torch.Tensor:
        g_main = g_main if g_main is not None else self.gauss(x0)
        g_pano = g_pano if g_pano is not None else self.gauss(x0_pano, wrap_x=True)
        own, own_m = self._own(g_main)
        lv, ms = [own, self.imin_main], [own_m, self.imin_main_m]
        if x0_pano is not None:
            p, pm = pyramid_warp(
                x0_pano,
                self.main_from_pano,
                levels=self.levels,
                wrap_x=True,
                collapse=False,
                roi=self.roi,
                src_pyramid=g_pano,
            )
            lv.insert(1, p)
            ms.insert(1, pm)
        refr, _ = blend_pyramids(lv, ms, lam=self.lam, fallback_levels=own)
        if not s.reflection:
            return refr
        if x0_pano is not None:
            refl, ok = pyramid_warp(
                x0_pano, self.main_refl_from_pano, levels=self.levels, wrap_x=True, roi=self.roi, src_pyramid=g_pano
            )
        elif self.refl_iminus is not None:  # no panorama: mirror rays that reach surfaces I⁻ shows
            refl, ok = self.refl_iminus
        else:
            return refr
        return fresnel_combine(refl, refr, self.fresnel, mask=self.object_mask & ok)

    def blend_pano(
        self,
        x0_pano: torch.Tensor,
        x0: torch.Tensor,
        g_pano: list[torch.Tensor] | None = None,
        g_main: list[torch.Tensor] | None = None,
    ) -> torch.Tensor:
        g_pano = g_pano if g_pano is not None else self.gauss(x0_pano, wrap_x=True)
        g_main = g_main if g_main is not None else self.gauss(x0)
        own, own_m = self._own(g_pano, wrap_x=True)
        m, mm = pyramid_warp(
            x0,
            self.pano_from_main,
            levels=self.levels,
            collapse=False,
            dest_wrap_x=True,
            roi=self.roi,
            src_pyramid=g_main,
        )
        out, _ = blend_pyramids(
            [own, m, self.imin_pano], [own_m, mm, self.imin_pano_m], lam=self.lam, fallback_levels=own, wrap_x=True
        )
        return out


def _in_window(i: int, T: int, window: tuple[float, float]) -> bool:
    return window[0] * T <= i < window[1] * T


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
    H, W = warps.camera.shape
    if tuple(i_minus.shape) != (1, 3, H, W):
        raise ValueError(f"i_minus must be (1, 3, {H}, {W}) for these warps, got {tuple(i_minus.shape)}")
    if not torch.isfinite(i_minus).all():
        raise ValueError("i_minus holds NaN or inf")
    s, decisions, reflection_mask = decide(warps, settings)
    if decisions.get("panorama", {}).get("used") is False and "observed_share" in decisions["panorama"]:
        log.info(
            "panorama branch skipped: %.1f %% of object pixels observed in I⁻",
            100 * decisions["panorama"]["observed_share"],
        )
    dev = generator_device(gen)
    g = torch.Generator(dev).manual_seed(int(seed))
    clock = _Clock()
    use_pano = s.uses_panorama
    shape_m = gen.geometry.latent_shape(H, W)
    shape_p = gen.geometry.latent_shape(*warps.pano.shape) if use_pano else None
    sig = gen.sigmas(s.steps, H, W, kind=s.schedule)
    T = s.steps
    if tuple(sig.shape) != (T + 1,):
        raise ValueError(f"{gen.name}.sigmas gave {tuple(sig.shape)} noise levels for {T} steps, expected ({T + 1},)")
    keep = latent_rounding(gen, s.latent_dtype)
    model_dtype = rounding_dtype(gen, s.latent_dtype)

    z_m = keep(torch.randn((1,) + shape_m, generator=g, device=dev))
    z_p = keep(torch.randn((1,) + shape_p, generator=g, device=dev)) if use_pano else None
    cond_m = gen.condition([prompt], ["main"])
    cond_p = gen.condition([pano_prompt], ["pano"]) if use_pano else None
    cond_both = gen.condition([prompt, pano_prompt], ["main", "pano"]) if use_pano and shape_m == shape_p else None

    t0 = time.perf_counter()
    views = _Views(warps, i_minus.float(), s, reflection_mask, device=dev) if s.sync == "snellcaster" else None
    clock.add("setup", t0)

    calls = {"main": 0, "pano": 0}
    dumps: list[dict] = []

    def velocities(run_m: bool, run_p: bool, sigma: float):
        """Model calls -> the clean latent estimates (None for a branch that does not run)."""
        t0 = time.perf_counter()
        vm = vp = None
        if run_m and run_p and cond_both is not None:
            v = gen.velocity(torch.cat([z_m, z_p]), sigma, cond_both)
            vm, vp = v[:1], v[1:]
        else:
            if run_m:
                vm = gen.velocity(z_m, sigma, cond_m)
            if run_p:
                vp = gen.velocity(z_p, sigma, cond_p)
        calls["main"] += int(run_m)
        calls["pano"] += int(run_p)
        clock.add("model", t0)
        lm = euler_estimate(z_m, vm, sigma) if run_m else None
        lp = euler_estimate(z_p, vp, sigma) if run_p else None
        return lm, lp

    def decode(lat):
        t0 = time.perf_counter()
        out = gen.decode(lat) if lat is not None else None
        clock.add("codec", t0)
        return out

    def step(z, x0_lat, sigma, sigma_next):
        if s.stochastic:
            return keep(stochastic_step(z, x0_lat, sigma, sigma_next, g, s.eta))
        if model_dtype is not None:  # the scheduler's step with latents in the model's dtype
            return pipeline_step(z, x0_lat, sigma, sigma_next, model_dtype)
        return sync_step(z, x0_lat, sigma, sigma_next)

    def to_host(x):
        return None if x is None else x.cpu()

    bar = tqdm(total=T, desc=f"sampling ({s.sync})", disable=not s.progress, leave=False)
    i = 0
    with torch.inference_mode():
        while i < T:
            travel = s.sync == "snellcaster" and s.time_travel and _in_window(i, T, s.tt_window)
            L = min(s.tt_length, T - i) if travel else 1
            Rm = s.tt_repeats_main if travel else 1
            Rp = (s.tt_repeats_pano if travel else 1) if use_pano else 0
            hist_m: list[torch.Tensor | None] = [None] * L
            hist_p: list[torch.Tensor | None] = [None] * L
            for r in range(max(Rm, Rp)):
                run_m, run_p = r < Rm, r < Rp
                for j in range(L):
                    sigma, sigma_next = float(sig[i + j]), float(sig[i + j + 1])
                    lm, lp = velocities(run_m, run_p, sigma)
                    dump = bool(s.dump_every) and (i + j) % s.dump_every == 0 and r == max(Rm, Rp) - 1
                    # the synchronised blends need the decoded estimates; the generator alone (and an
                    # unsynchronised last step) decodes nothing before the final image
                    sync = views is not None and (s.sync_last_step or i + j < T - 1)
                    xm = decode(lm) if sync or dump else None
                    xp = decode(lp) if sync or dump else None
                    if run_m:
                        hist_m[j] = xm
                    if run_p:
                        hist_p[j] = xp
                    xm_use, xp_use = hist_m[j], hist_p[j] if use_pano else None
                    sm = sp = None
                    if sync:
                        t0 = time.perf_counter()
                        gm, gp = views.gauss(xm_use), views.gauss(xp_use, wrap_x=True)
                        sm = views.blend_main(xm_use, xp_use, s, gm, gp) if run_m else None
                        sp = views.blend_pano(xp_use, xm_use, gp, gm) if run_p else None
                        clock.add("warp_blend", t0)
                        t0 = time.perf_counter()
                        lm = gen.encode(sm) if run_m else None
                        lp = gen.encode(sp) if run_p else None
                        clock.add("codec", t0)
                    t0 = time.perf_counter()
                    if run_m:
                        z_m = step(z_m, lm, sigma, sigma_next)
                    if run_p:
                        z_p = step(z_p, lp, sigma, sigma_next)
                    clock.add("step", t0)
                    if dump:
                        dumps.append(
                            {
                                "step": i + j,
                                "sigma": sigma,
                                "main_x0": to_host(xm_use),
                                "main_sync": to_host(sm if sync else xm_use) if run_m else None,
                                "pano_x0": to_host(xp_use),
                                "pano_sync": to_host(sp if sync else xp_use) if run_p else None,
                            }
                        )
                # travel back for the next repeat of each branch that repeats again
                if r + 1 < Rm:
                    z_m = keep(renoise(z_m, float(sig[i + L]), float(sig[i]), g))
                if r + 1 < Rp:
                    z_p = keep(renoise(z_p, float(sig[i + L]), float(sig[i]), g))
            i += L
            bar.update(L)
        bar.close()
        image = decode(z_m).cpu()  # only the final images (and dumps) come back from the device
        pano = decode(z_p).cpu() if use_pano else None
    return SampleResult(
        image=image, panorama=pano, model_calls=calls, timings=dict(clock.t), dumps=dumps, decisions=decisions
    )
