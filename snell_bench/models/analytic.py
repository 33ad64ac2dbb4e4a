"""The analytic generator: an exact flow-matching model of a known data distribution, for CPUs.

This is a stand-in for FLUX, not a generative model of images. It lets every mechanism of the
synchronized sampler (warping, blending, time travel, Fresnel, ablations) run, and be measured, on
a CPU in seconds, with answers that are known in closed form.

Convention:
    - Latent space: a fixed invertible transform of pixels. An sRGB image in [0, 1] is centred
      (``2x - 1``), unshuffled into ``f x f`` blocks (``f = downscale``, 8 like FLUX's VAE, giving
      ``3 f^2`` channels) and mixed by a fixed orthogonal matrix drawn from ``seed``. ``decode`` is the
      exact inverse, clamped to [0, 1] as a VAE's output would be; so decode -> warp -> encode is a
      real round trip through a latent space, not a no-op.
    - Data distribution: every latent coordinate is independent Gaussian, ``x0 ~ N(mu, s^2)``, with
      ``mu = encode(prior image)`` per view and ``s = prior_std``. With ``z = (1 - sigma) x0 + sigma eps``
      the exact posterior mean is ``E[x0 | z] = mu + k (z - (1 - sigma) mu)``,
      ``k = (1 - sigma) s^2 / ((1 - sigma)^2 s^2 + sigma^2)``, and the model returns the exact velocity
      ``v = (z - E[x0 | z]) / sigma`` (so the Euler estimate ``z - sigma v`` is that posterior mean).
    - Priors: the *main* view's prior is I⁻ with an optically wrong glass "blob" in the object region,
      the way text-to-image models fail at glass: the background seen straight through (no
      refraction, no flip), softened, tinted, with a specular highlight and a dark rim. The *panorama*
      prior is the scene's true panorama from the object's centre.
    - Uncertainty: ``s`` is ``prior_std`` where the model is sure of itself (the room, the panorama)
      and ``glass_std`` in the latent blocks that touch the object, where a text-to-image model does
      not know what glass shows. ``glass_std`` is the model's *strength* against synchronisation: a
      small value pulls every estimate in the glass back to the blob; a large one lets the estimate
      follow the latent, so the blended (warped) estimates win. Different ``s`` per latent position
      keep the posterior exact: the latent transform mixes only within a block, where ``s`` is constant.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from kornia.filters import filter2d_separable

from snell_bench.models.base import Condition, LatentGeometry, check_schedule
from snell_bench.sampler.schedule import flux_sigmas, linear_sigmas
from snell_bench.utils.tensors import as_tensor, hwc_to_bchw

__all__ = ["AnalyticGenerator", "as_rgb_batch", "gaussian_blur", "glass_blob_prior"]


def as_rgb_batch(x) -> torch.Tensor:
    """``x`` (an RGB image ``(H, W, 3)``, ``(3, H, W)`` or ``(B, 3, H, W)``, array or tensor) as a
    contiguous float32 ``(B, 3, H, W)`` tensor; a :class:`ValueError` naming the shape otherwise."""
    t = as_tensor(x, dtype=torch.float32)
    if t.ndim == 3 and t.shape[-1] == 3:  # (H, W, 3) numpy layout
        t = hwc_to_bchw(t)
    if t.ndim == 3:
        t = t[None]
    if t.ndim != 4 or t.shape[1] != 3:
        raise ValueError(f"expected an RGB image (H, W, 3) or (B, 3, H, W), got shape {tuple(t.shape)}")
    return t.contiguous()


def gaussian_blur(img: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of ``(B, C, H, W)`` with standard deviation ``sigma`` (pixels), a
    kernel of ``2 ceil(2.5 sigma) + 1`` taps, and the border replicated."""
    k = int(2 * math.ceil(2.5 * sigma) + 1)
    # the kernel is computed here rather than by kornia's gaussian_blur2d, which rounds sigma to
    # float32 before squaring it: its weights can differ in the last bit, and so would every prior
    g = torch.exp(-((torch.arange(k) - k // 2).float() ** 2) / (2 * sigma**2))
    g = (g / g.sum())[None]
    return filter2d_separable(img, g, g, border_type="replicate")


def glass_blob_prior(i_minus, object_mask, *, blur_px: float | None = None) -> torch.Tensor:
    """I⁻ with an optically wrong glass blob in the object mask.

    Inside the mask: the background straight through (no refraction), blurred, slightly tinted
    and brightened, plus a soft highlight at the upper left and a darker rim: what a model that does
    not know optics paints for "a glass sphere".

    Args:
        i_minus: the object-free image, ``(H, W, 3)`` or ``(1, 3, H, W)``, sRGB in [0, 1].
        object_mask: boolean ``(H, W)``, where the object is.
        blur_px: the Gaussian blur's standard deviation in pixels (default: the object's
            radius / 12, at least 1); the kernel spans ``2 ceil(2.5 blur_px) + 1`` pixels and the
            image's border is replicated.

    Returns:
        The prior image ``(1, 3, H, W)``.

    Raises:
        ValueError: if the mask's size is not the image's.
    """
    img = as_rgb_batch(i_minus)
    mask = as_tensor(object_mask, dtype=torch.bool)
    if mask.shape != img.shape[-2:]:
        raise ValueError(f"object mask {tuple(mask.shape)} does not match the image {tuple(img.shape[-2:])}")
    if not mask.any():
        return img.clone()
    ys, xs = torch.nonzero(mask, as_tuple=True)
    cy, cx = ys.float().mean(), xs.float().mean()
    radius = max(float((ys.max() - ys.min() + 1).item()), float((xs.max() - xs.min() + 1).item())) / 2
    blurred = gaussian_blur(img, blur_px if blur_px is not None else max(1.0, radius / 12))
    H, W = mask.shape
    yy, xx = torch.meshgrid(torch.arange(H).float(), torch.arange(W).float(), indexing="ij")
    r = torch.sqrt((yy - cy) ** 2 + (xx - cx) ** 2) / max(radius, 1.0)
    tint = torch.tensor([0.92, 0.97, 1.05]).view(1, 3, 1, 1)
    body = (0.8 * blurred + 0.12) * tint
    rim = torch.clamp((r - 0.75) / 0.25, 0, 1) ** 2
    body = body * (1 - 0.45 * rim)
    hl = torch.exp(-(((yy - (cy - 0.45 * radius)) ** 2 + (xx - (cx - 0.4 * radius)) ** 2) / (2 * (0.14 * radius) ** 2)))
    body = body + 0.6 * hl
    return torch.where(mask, body.clamp(0, 1), img)


class AnalyticGenerator:
    """Exact velocity of a per-coordinate Gaussian data distribution (see the module docs).

    Args:
        main_prior: the main view's prior image, ``(H, W, 3)`` or ``(1, 3, H, W)``.
        pano_prior: the panorama's prior image (``None``: no panorama view).
        prior_std: the data distribution's standard deviation where the model is sure.
        glass_std: the standard deviation in the latent blocks touching ``glass_mask``.
        glass_mask: boolean ``(H, W)`` of the main view, where the model is unsure.
        downscale: the latent block size ``f``.
        seed: draws the latent transform's orthogonal matrix.

    Raises:
        ValueError: for a non-positive or infinite standard deviation, a bad ``downscale``, or
            prior sizes that are not multiples of it.
    """

    name = "analytic"
    #: A CPU backend in float32.
    device = torch.device("cpu")
    dtype = torch.float32
    #: The encoder is a deterministic map: ``encode(..., generator)`` returns the mean.
    has_posterior = False

    def __init__(
        self,
        main_prior,
        pano_prior=None,
        *,
        prior_std: float = 0.05,
        glass_std: float = 0.1,
        glass_mask=None,
        downscale: int = 8,
        seed: int = 0,
    ) -> None:
        for name, v in (("prior_std", prior_std), ("glass_std", glass_std)):
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"model.{name} must be finite and > 0, got {v}")
        if int(downscale) != downscale or downscale < 1:
            raise ValueError(f"downscale must be a positive integer, got {downscale}")
        self.prior_std = float(prior_std)
        self.glass_std = float(glass_std)
        self.downscale = int(downscale)
        C = 3 * self.downscale**2
        self.geometry = LatentGeometry(channels=C, downscale=self.downscale, multiple=self.downscale)
        gen = torch.Generator().manual_seed(int(seed))
        q, r = torch.linalg.qr(torch.randn(C, C, generator=gen, dtype=torch.float64))
        q = q * torch.sign(torch.diagonal(r))  # a unique orthogonal matrix for the seed
        self._mix = q.to(torch.float32)  # latent = mix @ pixels (per block)
        self._priors: dict[str, torch.Tensor] = {}
        self._std: dict[str, torch.Tensor] = {}  # (1, 1, h, w) per view
        self.set_prior("main", main_prior, glass_mask)
        if pano_prior is not None:
            self.set_prior("pano", pano_prior)

    @classmethod
    def from_scene(cls, i_minus, object_mask, panorama=None, **kwargs) -> AnalyticGenerator:
        """Main prior: I⁻ with a wrong glass blob in the object mask, uncertain (``glass_std``) there;
        panorama prior: the true panorama."""
        return cls(glass_blob_prior(i_minus, object_mask), panorama, glass_mask=object_mask, **kwargs)

    def set_prior(self, view: str, image, glass_mask=None) -> None:
        """The prior image of a view, and where (``glass_mask`` (H, W)) the model is unsure."""
        img = as_rgb_batch(image)
        _, h, w = self.geometry.latent_shape(img.shape[-2], img.shape[-1])  # validates the size
        self._priors[view] = self.encode(img)
        std = torch.full((1, 1, h, w), self.prior_std)
        if glass_mask is not None:
            m = as_tensor(glass_mask, dtype=torch.float32)
            if m.shape != img.shape[-2:]:
                raise ValueError(f"glass mask {tuple(m.shape)} does not match the prior {tuple(img.shape[-2:])}")
            touched = F.max_pool2d(m[None, None], self.downscale) > 0
            std = torch.where(touched, torch.tensor(self.glass_std), std)
        self._std[view] = std

    def prior_image(self, view: str) -> torch.Tensor:
        return self.decode(self._priors[view])

    # ------------------------------------------------------------------ latent space
    def encode(self, images: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """``(B, 3, H, W)`` in [0, 1] -> ``(B, 3 f^2, H / f, W / f)``; deterministic.

        The encoder is an exact linear map, not a distribution: there is no posterior to sample, so
        ``generator`` is accepted for the protocol (``sampler.encode=sample``) and neither read nor
        advanced; the result is the same latent either way.
        """
        self.geometry.latent_shape(images.shape[-2], images.shape[-1])
        x = F.pixel_unshuffle(images.float() * 2 - 1, self.downscale)
        return torch.einsum("dc,bchw->bdhw", self._mix, x)

    def decode(self, latents: torch.Tensor) -> torch.Tensor:
        x = torch.einsum("dc,bdhw->bchw", self._mix, latents.float())
        return ((F.pixel_shuffle(x, self.downscale) + 1) / 2).clamp(0, 1)

    # ------------------------------------------------------------------ schedule
    def sigmas(self, num_steps: int, height: int, width: int, kind: str = "flux") -> torch.Tensor:
        """The noise schedule, from the float64 closed forms of :mod:`snell_bench.sampler.schedule`.

        Args:
            num_steps: the number of denoising steps ``T``.
            height: the image height in pixels (a multiple of ``downscale``).
            width: the image width in pixels.
            kind: ``"flux"``: FLUX.1-dev's shifted schedule (base/max sequence length 256/4096,
                shift 0.5/1.15) for ``(h / 2) (w / 2)`` tokens of this model's ``h x w`` latent
                grid; ``"linear"``: ``1, 1 - 1/T, ..., 0``.

        Returns:
            A float64 tensor ``(T + 1,)``, decreasing from 1 to 0.

        Raises:
            ValueError: for an unknown kind, a bad step count or an image size that is not a
                multiple of ``downscale``.
        """
        check_schedule(kind, num_steps)
        if kind == "linear":
            return linear_sigmas(num_steps)
        _, h, w = self.geometry.latent_shape(height, width)
        return flux_sigmas(num_steps, (h // 2) * (w // 2))

    # ------------------------------------------------------------------ model
    def condition(self, prompts: list[str], views: list[str]) -> Condition:
        if len(prompts) != len(views):
            raise ValueError("one view per prompt")
        for v in views:
            if v not in self._priors:
                raise ValueError(f"the analytic generator has no prior for view {v!r} (has {sorted(self._priors)})")
        return Condition(prompts=list(prompts), data={"views": list(views)})

    def posterior_mean(self, z: torch.Tensor, sigma, cond: Condition) -> torch.Tensor:
        mu, std = self._prior_batch(z, cond)
        sigma = self._sigma(sigma, z)
        s2 = std**2
        k = (1 - sigma) * s2 / ((1 - sigma) ** 2 * s2 + sigma**2)
        return mu + k * (z - (1 - sigma) * mu)

    def velocity(self, z: torch.Tensor, sigma, cond: Condition) -> torch.Tensor:
        sig = self._sigma(sigma, z)
        if torch.any(sig <= 0):
            raise ValueError("velocity is undefined at sigma = 0; the sampler returns its estimate there")
        return (z - self.posterior_mean(z, sigma, cond)) / sig

    def _sigma(self, sigma, z: torch.Tensor) -> torch.Tensor:
        s = torch.as_tensor(sigma, dtype=z.dtype, device=z.device)
        if s.ndim == 0:
            s = s.expand(z.shape[0])
        return s.view(-1, 1, 1, 1)

    def _prior_batch(self, z: torch.Tensor, cond: Condition) -> torch.Tensor:
        views = cond.data["views"]
        if len(views) == 1 and z.shape[0] > 1:
            views = views * z.shape[0]
        if len(views) != z.shape[0]:
            raise ValueError(f"condition has {len(views)} prompts for a batch of {z.shape[0]}")
        mus, stds = [], []
        for v in views:
            mu = self._priors[v]
            if mu.shape[1:] != z.shape[1:]:
                raise ValueError(f"latent {tuple(z.shape[1:])} does not match the {v!r} prior {tuple(mu.shape[1:])}")
            mus.append(mu)
            stds.append(self._std[v])
        return torch.cat(mus, 0), torch.cat(stds, 0)
