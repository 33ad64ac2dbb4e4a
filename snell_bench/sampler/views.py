"""The two views of the synchronized sampler: their warps on the generator's device and the
blends of each step (paper §4.2).

Convention:
    - Images ``(1, 3, H, W)`` (main view) and ``(1, 3, Hp, Wp)`` (panorama, ``Wp = 2 Hp``), float32
      sRGB in [0, 1], on the generator's device; warps as in :class:`~snell_bench.optics.WarpSet`
      (backward maps ``(H', W', 2)`` in pixels, order x, y, NaN where invalid), moved to that
      device once per sample.
    - Warps go through Laplacian pyramids of ``warp_levels`` levels (scale-matched,
      :func:`~snell_bench.imaging.pyramid.pyramid_warp`; ``lpw: false``: a single-level remap).
    - Blends are detail-preserving averages ``phi`` (``dpa_domain``): of whole images in FLUX's
      [-1, 1] image space (``image``, :func:`~snell_bench.imaging.blend.blend_images`), or per
      Laplacian band with the low-pass level in [-1, 1] (``bands``,
      :func:`~snell_bench.imaging.blend.blend_pyramids`); the refraction of an absorbing object
      is tinted by its transmittance (:func:`~snell_bench.imaging.blend.absorb`), then the
      reflection is mixed in by Fresnel in linear RGB
      (:func:`~snell_bench.imaging.blend.fresnel_combine`), both in linear RGB.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from snell_bench.config.sampler import SamplerSettings
from snell_bench.imaging.blend import absorb, blend_images, blend_pyramids, fresnel_combine
from snell_bench.imaging.pyramid import gaussian_pyramid, laplacian_from_gaussian, pyramid_warp, warped_bands
from snell_bench.optics.warps import WarpSet

__all__ = ["Views", "keep_outside", "on_device", "pano_to_main_map"]


def _nan_where(coords: np.ndarray, invalid: np.ndarray) -> np.ndarray:
    """A float32 copy of the backward map ``coords`` ``(H, W, 2)`` with NaN where ``invalid`` ``(H, W)``."""
    c = np.array(coords, dtype=np.float32, copy=True)
    c[invalid] = np.nan
    return c


def on_device(a: np.ndarray, device: torch.device) -> torch.Tensor:
    """A numpy map or mask as a tensor on ``device`` (same dtype and shape)."""
    return torch.from_numpy(np.ascontiguousarray(a)).to(device)


def pano_to_main_map(ws: WarpSet, mode: str) -> np.ndarray:
    """π⁻¹ as the main view's blend reads it: ``(H, W, 2)`` panorama pixels, NaN where invalid.

    Args:
        ws: the scene's warps.
        mode: ``"object"`` (:attr:`WarpSet.pano_refraction`: object pixels only) or ``"frame"``
            (``WarpSet.pano_refraction_frame``: every pixel, the straight camera ray's point outside
            the object).

    Raises:
        ValueError: ``frame`` with warps that lack ``pano_refraction_frame``, or an unknown mode.
    """
    if mode == "object":
        return ws.pano_refraction
    if mode == "frame":
        frame = getattr(ws, "pano_refraction_frame", None)
        if frame is None:
            raise ValueError(
                "sampler.pano_to_main='frame' needs WarpSet.pano_refraction_frame (π⁻¹ over the whole "
                "frame), which these warps do not have; recompute the warps with a snell_bench that "
                "computes it, or use sampler.pano_to_main=object"
            )
        return frame
    raise ValueError(f"sampler.pano_to_main={mode!r} is unknown; use 'frame' or 'object'")


def keep_outside(term, masks, own, object_mask: torch.Tensor):
    """A term warped from the object's pixels only, with ``own`` values, bit for bit, wherever it
    has none outside the object.

    Args:
        term: ``(B, C, H, W)`` image, or Gaussian levels (list, finest first, ``floor(n / 2)`` per
            level), warped through a map that is NaN outside the object.
        masks: its validity: ``(B, 1, H, W)`` bool, or one such mask per level (a coarse pixel is
            valid where any of its level-0 pixels is).
        own: what stands for the term outside the object: an image, or its Gaussian pyramid.
        object_mask: ``(1, 1, H, W)`` bool, the object's pixels.

    Returns:
        ``(term, masks)`` in the layout given: ``term`` where it is valid; elsewhere ``own``, valid,
        unless every level-0 pixel under the (coarse) pixel is the object's: the object's own invalid
        pixels stay invalid, and 0.
    """
    levels = term if isinstance(term, list) else [term]
    mask_levels = masks if isinstance(term, list) else [masks]
    own_levels = own if isinstance(term, list) else [own]
    outside = ~object_mask
    out, out_m = [], []
    for k, (t, m, o) in enumerate(zip(levels, mask_levels, own_levels)):
        if k:  # some level-0 pixel of the block is outside the object
            outside = F.max_pool2d(outside.to(t.dtype), 2) > 0
        out.append(torch.where(m, t, torch.where(outside, o, torch.zeros_like(t))))
        out_m.append(m | outside)
    return (out, out_m) if isinstance(term, list) else (out[0], out_m[0])


class Views:
    """The warps of one run on the generator's device, with the constant warps of I⁻, built once.

    Convention:
        - Maps (backward, NaN marks every invalid source, so the masks follow from the maps):
          ``main_from_pano`` π⁻¹ ``(H, W, 2)`` (panorama pixels; object pixels only, or every pixel
          with ``pano_to_main: frame``) and ``main_refl_from_pano`` π^-R ``(H, W, 2)`` (object pixels);
          ``pano_from_main`` π ``(Hp, Wp, 2)`` (perspective pixels, NaN where the perspective pixel
          shows the object itself).
        - ``object_mask`` ``(1, 1, H, W)`` bool; ``fresnel`` ``(1, 1, H, W)`` reflectance in [0, 1].
        - I⁻ warped once: by π^R into the main view (``imin_main``: warped from the object's pixels,
          I⁻ itself outside the object, bit for bit) and by π into the panorama (``imin_pano``), as images with their masks (``dpa_domain: image``) or as Laplacian
          pyramids with per-level masks (``bands``); without the panorama branch, its mirror image
          by the self-reflection map (``refl_iminus``, collapsed, with its mask) when the reflection
          is modelled.
        - Warps: ``warp_levels`` levels, scale-matched when ``lpw`` (a single-level remap
          otherwise; with ``bands`` the pyramid samples level ``k`` for level ``k`` and collapses
          to that remap).
        - Blends: phi with weight ``lam`` in [-1, 1] (module docstring); the reflection is mixed in
          by Fresnel in linear RGB.

    Args:
        ws: the scene's warps.
        i_minus: ``(1, 3, H, W)`` float32 sRGB object-free image.
        s: the settings the run uses (levels, ``lpw``, ``dpa_domain``, ``pano_to_main``, ``lam``,
            ``roi``, reflection, panorama).
        reflection_mask: ``(H, W)`` bool, the object pixels that keep a reflection; ``None``: all.
        device: where the maps and the pyramids live (``None``: the CPU).

    Raises:
        ValueError: ``pano_to_main: frame`` with the panorama branch and warps without
            ``pano_refraction_frame``.
    """

    def __init__(
        self,
        ws: WarpSet,
        i_minus: torch.Tensor,
        s: SamplerSettings,
        reflection_mask: np.ndarray | None = None,
        device: torch.device | None = None,
    ) -> None:
        self.levels = s.effective_levels  # depth of every Gaussian pyramid built
        self.bands = s.dpa_domain == "bands"
        self.match_scale = bool(s.lpw)
        self.lpw_pano = bool(s.lpw_pano)
        # bands: warp at every blend level (point-sampled per level without lpw); image: one image
        self.warp_levels = s.levels if self.bands else s.warp_levels
        self.image_warp_levels = s.warp_levels  # warps used as whole images (the reflection)
        self.roi = bool(s.roi)
        self.reflection = bool(s.reflection)
        self._gauss_last: dict[bool, tuple[torch.Tensor, list[torch.Tensor]]] = {}
        self.lam = s.effective_lam
        dev = torch.device("cpu") if device is None else torch.device(device)

        i_minus = i_minus.to(dev)
        self.object_mask = on_device(ws.object_mask, dev)[None, None]
        self.fresnel = on_device(ws.fresnel, dev)[None, None]
        #: (1, 3, H, W) exp(-σ L) of an absorbing object's refracted paths; None: clear
        self.transmittance = on_device(ws.transmittance(), dev).permute(2, 0, 1)[None] if ws.absorbs else None
        self.main_from_pano = None
        if s.uses_panorama:
            self.main_from_pano = on_device(np.asarray(pano_to_main_map(ws, s.pano_to_main), np.float32), dev)
        self.main_refl_from_pano = on_device(ws.pano_reflection, dev)
        refl_self = ws.reflection
        if reflection_mask is not None:  # reflect only where it is not negligible
            self.main_refl_from_pano = on_device(_nan_where(ws.pano_reflection, ~reflection_mask), dev)
            refl_self = _nan_where(ws.reflection, ~reflection_mask)
        self.pano_from_main = on_device(_nan_where(ws.pano_to_persp, ws.pano_to_persp_object), dev)
        self.refl_iminus = None
        if s.reflection and not s.uses_panorama:
            self.refl_iminus = pyramid_warp(i_minus, on_device(refl_self, dev), levels=s.warp_levels, roi=self.roi)
        self.imin_main, self.imin_main_m = self._imin_main(i_minus, ws, dev)
        self.imin_pano, self.imin_pano_m = self._warp(
            i_minus, on_device(ws.pano_to_persp, dev), dest_wrap_x=True, roi=self.roi, lpw=self.lpw_pano
        )

    def _imin_main(self, i_minus: torch.Tensor, ws: WarpSet, dev: torch.device):
        """π^R(I⁻) as the blends read it: the refraction warped from the object's own pixels only (π^R
        with NaN outside the object: no coordinate or difference across the silhouette reaches the
        pyramid), and I⁻ itself outside the object, bit for bit (:func:`keep_outside`). With
        ``bands``, the warped Gaussian levels are completed by I⁻'s own before they are split into
        bands, so the term's pyramid collapses to the completed image, and away from the object
        (beyond the upsampling's reach) its bands are I⁻'s own, bit for bit."""
        inside = on_device(_nan_where(ws.refraction, ~ws.object_mask), dev)
        if not self.bands:
            warped, masks = self._warp(i_minus, inside, roi=self.roi)
            return keep_outside(warped, masks, i_minus, self.object_mask)
        levels, masks = self._warp(i_minus, inside, roi=self.roi, gaussian=True)
        own = gaussian_pyramid(i_minus, self.warp_levels)
        levels, masks = keep_outside(levels, masks, own, self.object_mask)
        return warped_bands(levels, masks), masks

    def _warp(
        self,
        src: torch.Tensor,
        coords: torch.Tensor,
        *,
        wrap_x: bool = False,
        dest_wrap_x: bool = False,
        roi: bool = False,
        src_pyramid: list[torch.Tensor] | None = None,
        lpw: bool = True,
        gaussian: bool = False,
    ):
        """``src`` through ``coords`` as the blends read it: ``(image, mask)`` (``image`` domain) or
        ``(bands, masks)`` (``bands``); ``lpw=False`` makes this warp a single-level remap even when
        the run warps through pyramids (``lpw_pano``); ``gaussian``: the warped Gaussian levels
        instead of bands (``bands`` only)."""
        scale = self.match_scale and lpw
        return pyramid_warp(
            src,
            coords,
            levels=self.warp_levels if scale or self.bands else 1,
            wrap_x=wrap_x,
            collapse=not self.bands,
            match_scale=scale,
            dest_wrap_x=dest_wrap_x,
            roi=roi,
            src_pyramid=src_pyramid,
            gaussian=gaussian,
        )

    def _own(self, img: torch.Tensor, gauss: list[torch.Tensor], wrap_x: bool = False):
        """An estimate as the blends read it (the image, or its Laplacian pyramid from its Gaussian
        one) with all-valid masks."""
        if not self.bands:
            return img, torch.ones((img.shape[0], 1) + img.shape[-2:], dtype=torch.bool, device=img.device)
        pyr = laplacian_from_gaussian(gauss, wrap_x=wrap_x)
        return pyr, [torch.ones((p.shape[0], 1) + p.shape[-2:], dtype=torch.bool, device=p.device) for p in pyr]

    def _blend(self, inputs: list, masks: list, own, wrap_x: bool = False) -> torch.Tensor:
        """phi of the inputs in the run's domain (the estimate's own value where none is valid)."""
        if self.bands:
            out, _ = blend_pyramids(
                inputs, masks, lam=self.lam, fallback_levels=own, wrap_x=wrap_x, signed_lowpass=True
            )
        else:
            out, _ = blend_images(inputs, masks, lam=self.lam, fallback=own)
        return out

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
        ``phi((x0, π⁻¹(x0_pano), π^R(I⁻)))`` (the panorama's term left out without it), then
        ``π^-R(x0_pano)`` (without the panorama: the mirror image of I⁻) mixed in by Fresnel inside
        the object where the reflection is valid.

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
        own, own_m = self._own(x0, g_main)
        lv, ms = [own, self.imin_main], [own_m, self.imin_main_m]
        if x0_pano is not None and self.main_from_pano is not None:
            p, pm = self._warp(x0_pano, self.main_from_pano, wrap_x=True, roi=self.roi, src_pyramid=g_pano)
            lv.insert(1, p)
            ms.insert(1, pm)
        refr = self._blend(lv, ms, own)
        if self.transmittance is not None:  # tinted along the path in the glass, before the Fresnel mix
            refr = absorb(refr, self.transmittance)
        if not self.reflection:
            return refr
        if x0_pano is not None:
            refl, ok = pyramid_warp(
                x0_pano,
                self.main_refl_from_pano,
                levels=self.image_warp_levels,
                wrap_x=True,
                roi=self.roi,
                src_pyramid=g_pano,
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
        """The panorama's synchronized estimate: ``phi((x0_pano, π(x0), π(I⁻)))``, periodic in x.

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
        own, own_m = self._own(x0_pano, g_pano, wrap_x=True)
        m, mm = self._warp(
            x0, self.pano_from_main, dest_wrap_x=True, roi=self.roi, src_pyramid=g_main, lpw=self.lpw_pano
        )
        return self._blend([own, m, self.imin_pano], [own_m, mm, self.imin_pano_m], own, wrap_x=True)
