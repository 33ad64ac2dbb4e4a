"""The two views of the synchronized sampler: their warps on the generator's device and the
blends of each step (paper §4.2).

Convention:
    - Images ``(1, 3, H, W)`` (main view) and ``(1, 3, Hp, Wp)`` (panorama, ``Wp = 2 Hp``), float32
      sRGB in [0, 1], on the generator's device; warps as in :class:`~snell_bench.optics.WarpSet`
      (backward maps ``(H', W', 2)`` in pixels, order x, y, NaN where invalid), moved to that
      device once per sample.
    - Blends are detail-preserving averages over Laplacian pyramids (``phi`` of
      :func:`~snell_bench.imaging.blend.blend_pyramids`); the reflection is mixed in by Fresnel in
      linear RGB (:func:`~snell_bench.imaging.blend.fresnel_combine`).
"""

from __future__ import annotations

import numpy as np
import torch

from snell_bench.config.sampler import SamplerSettings
from snell_bench.imaging.blend import blend_pyramids, fresnel_combine
from snell_bench.imaging.pyramid import gaussian_pyramid, laplacian_from_gaussian, pyramid_warp
from snell_bench.optics.warps import WarpSet

__all__ = ["Views", "on_device"]


def _nan_where(coords: np.ndarray, invalid: np.ndarray) -> np.ndarray:
    """A float32 copy of the backward map ``coords`` ``(H, W, 2)`` with NaN where ``invalid`` ``(H, W)``."""
    c = np.array(coords, dtype=np.float32, copy=True)
    c[invalid] = np.nan
    return c


def on_device(a: np.ndarray, device: torch.device) -> torch.Tensor:
    """A numpy map or mask as a tensor on ``device`` (same dtype and shape)."""
    return torch.from_numpy(np.ascontiguousarray(a)).to(device)


class Views:
    """The warps of one run on the generator's device, with the constant warps of I⁻, built once.

    Convention:
        - Maps (backward, NaN marks every invalid source, so the masks follow from the maps):
          ``main_from_pano`` π⁻¹ ``(H, W, 2)`` and ``main_refl_from_pano`` π^-R ``(H, W, 2)`` (panorama
          pixels, object pixels only); ``pano_from_main`` π ``(Hp, Wp, 2)`` (perspective pixels, NaN
          where the perspective pixel shows the object itself).
        - ``object_mask`` ``(1, 1, H, W)`` bool; ``fresnel`` ``(1, 1, H, W)`` reflectance in [0, 1].
        - I⁻ warped once, as Laplacian pyramids (``levels`` bands with their masks): by π^R into the
          main view (``imin_main``) and by π into the panorama (``imin_pano``); without the panorama
          branch, its mirror image by the self-reflection map (``refl_iminus``, collapsed, with its
          mask) when the reflection is modelled.
        - Blends are detail-preserving averages per Laplacian level of sRGB images in [0, 1] (the
          band-pass levels signed, the low-pass level in [0, 1]) with weight ``lam``, collapsed; the
          reflection is mixed in by Fresnel in linear RGB.

    Args:
        ws: the scene's warps.
        i_minus: ``(1, 3, H, W)`` float32 sRGB object-free image.
        s: the settings the run uses (levels, ``lam``, ``roi``, reflection, panorama).
        reflection_mask: ``(H, W)`` bool, the object pixels that keep a reflection; ``None``: all.
        device: where the maps and the pyramids live (``None``: the CPU).
    """

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
        self.reflection = bool(s.reflection)
        self._gauss_last: dict[bool, tuple[torch.Tensor, list[torch.Tensor]]] = {}
        self.lam = s.effective_lam
        dev = torch.device("cpu") if device is None else torch.device(device)

        i_minus = i_minus.to(dev)
        self.object_mask = on_device(ws.object_mask, dev)[None, None]
        self.fresnel = on_device(ws.fresnel, dev)[None, None]
        self.main_from_pano = on_device(ws.pano_refraction, dev)
        self.main_refl_from_pano = on_device(ws.pano_reflection, dev)
        refl_self = ws.reflection
        if reflection_mask is not None:  # reflect only where it is not negligible
            self.main_refl_from_pano = on_device(_nan_where(ws.pano_reflection, ~reflection_mask), dev)
            refl_self = _nan_where(ws.reflection, ~reflection_mask)
        self.pano_from_main = on_device(_nan_where(ws.pano_to_persp, ws.pano_to_persp_object), dev)
        self.refl_iminus = None
        if s.reflection and not s.uses_panorama:
            self.refl_iminus = pyramid_warp(i_minus, on_device(refl_self, dev), levels=L, roi=self.roi)
        self.imin_main, self.imin_main_m = pyramid_warp(
            i_minus, on_device(ws.refraction, dev), levels=L, collapse=False
        )
        self.imin_pano, self.imin_pano_m = pyramid_warp(
            i_minus, on_device(ws.pano_to_persp, dev), levels=L, collapse=False, dest_wrap_x=True, roi=self.roi
        )

    @staticmethod
    def _own(gauss: list[torch.Tensor], wrap_x: bool = False):
        """An estimate's own Laplacian pyramid (from its Gaussian one) and all-valid masks
        ``(1, 1, h_k, w_k)`` per level."""
        pyr = laplacian_from_gaussian(gauss, wrap_x=wrap_x)
        return pyr, [torch.ones((p.shape[0], 1) + p.shape[-2:], dtype=torch.bool, device=p.device) for p in pyr]

    def gauss(self, img: torch.Tensor | None, wrap_x: bool = False) -> list[torch.Tensor] | None:
        """The Gaussian pyramid of an estimate, built once and shared by its own Laplacian pyramid and
        every warp that reads it; an estimate lent unchanged to a time-travel repeat of the other
        branch is not decomposed again.

        Args:
            img: ``(1, 3, h, w)`` sRGB in [0, 1], or ``None``.
            wrap_x: ``img`` is the panorama (periodic in x).

        Returns:
            ``levels`` tensors, finest first, or ``None`` for ``None``.
        """
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
        g_main: list[torch.Tensor] | None = None,
        g_pano: list[torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """The main view's synchronized estimate:
        ``phi((x0, π⁻¹(x0_pano), π^R(I⁻)))`` per Laplacian level (the panorama's term left out
        without it), then ``π^-R(x0_pano)`` (without the panorama: the mirror image of I⁻) mixed in
        by Fresnel inside the object where the reflection is valid.

        Args:
            x0: ``(1, 3, H, W)`` the main view's decoded estimate, sRGB in [0, 1].
            x0_pano: ``(1, 3, Hp, Wp)`` the panorama's decoded estimate, or ``None``.
            g_main: :meth:`gauss` of ``x0`` (built here when ``None``).
            g_pano: :meth:`gauss` of ``x0_pano`` with ``wrap_x=True`` (built here when ``None``).

        Returns:
            ``(1, 3, H, W)`` sRGB.
        """
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
        if not self.reflection:
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
        """The panorama's synchronized estimate: ``phi((x0_pano, π(x0), π(I⁻)))`` per Laplacian
        level, periodic in x.

        Args:
            x0_pano: ``(1, 3, Hp, Wp)`` the panorama's decoded estimate, sRGB in [0, 1].
            x0: ``(1, 3, H, W)`` the main view's decoded estimate.
            g_pano: :meth:`gauss` of ``x0_pano`` with ``wrap_x=True`` (built here when ``None``).
            g_main: :meth:`gauss` of ``x0`` (built here when ``None``).

        Returns:
            ``(1, 3, Hp, Wp)`` sRGB.
        """
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
