"""The mixture generator: an exact flow-matching model whose posterior mean is *not* linear.

A second CPU stand-in for FLUX beside :mod:`snell_bench.models.analytic`. The analytic backend's
Gaussian data distribution has a posterior mean that is affine in the latent, so a sampler's
trajectory is an affine map of its noise and its blends: renoising and denoising a window again
(time travel) lands where a single pass does, and averaging rules cannot trade one mode for
another. Here every latent block of the glass is a Gaussian *mixture* of several wrong guesses at
what glass shows (optionally with a broad component that follows the latent), so the model snaps
each block to one belief, and what the synchronised blends push into the latent can change which
belief wins. The configuration ``model=mixture`` uses narrow components only: a broad one lets the
model follow the blends and hides time travel's effect (README, "Results on CPU").

Convention:
    - Latent space, images, encode / decode, schedules and conditioning are the analytic backend's
      (this class subclasses :class:`~snell_bench.models.analytic.AnalyticGenerator`): sRGB images
      ``(B, 3, H, W)`` in [0, 1], centred (``2x - 1``), unshuffled into ``f x f`` blocks and mixed
      by a fixed orthogonal ``3 f^2 x 3 f^2`` matrix drawn from ``seed``; latents ``(B, 3 f^2, H / f,
      W / f)``; one latent position ``(h, w)`` is one ``f x f`` pixel block. The encoder has no
      posterior: ``encode(images, generator)`` ignores ``generator`` (``sampler.encode=sample`` gives
      the mean).
    - Flow matching: ``z = (1 - sigma) x0 + sigma eps``, velocity ``v = eps - x0``, so the Euler
      estimate ``z - sigma v`` is the posterior mean ``E[x0 | z]``; ``sigma`` in (0, 1], a float
      or a ``(B,)`` tensor.
    - Data distribution, per view and per latent block ``b`` (its ``C = 3 f^2`` coordinates
      ``x0_b``): ``sum_k pi_k N(mu_kb, s_kb^2 I)`` with ``K`` components, independent across blocks.
      Inside the view's *uncertain region* (the blocks that touch the object mask in the main view;
      the whole panorama) the components differ: narrow ones (``s = glass_std``, in the panorama
      ``pano_std``) centred on wrong appearances, and, if listed, a ``broad`` one (``s = broad_std``).
      Outside it every component has the first component's mean and ``s = prior_std``, so the
      distribution there is the analytic backend's Gaussian.
    - Exact posterior, per block, with ``a = 1 - sigma`` and ``V_k = a^2 s_k^2 + sigma^2``:
      responsibilities ``w_k ∝ pi_k N(z_b; a mu_kb, V_k I)`` (a softmax of log densities, in float64),
      ``E[x0 | z, k] = (a s_k^2 z + sigma^2 mu_k) / V_k``, ``E[x0 | z] = sum_k w_k E[x0 | z, k]`` and
      ``v = sum_k w_k ((sigma - a s_k^2) z - sigma mu_k) / V_k``, which is ``(z - E[x0 | z]) / sigma``
      written without the cancellation (finite and exact as ``sigma -> 0``, where ``E[x0 | z] -> z``,
      and as ``sigma -> 1``, where every ``w_k -> pi_k`` and it tends to the prior mean
      ``sum_k pi_k mu_k``).
    - Randomness: none; the model is deterministic given ``seed`` (the latent transform).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from snell_bench.models.analytic import AnalyticGenerator, as_rgb_batch, gaussian_blur, glass_blob_prior
from snell_bench.models.base import Condition
from snell_bench.utils.tensors import as_tensor

__all__ = [
    "GLASS_VARIANTS",
    "PANO_VARIANTS",
    "Component",
    "MixtureGenerator",
    "glass_variants",
    "panorama_variants",
]

#: Appearances of the main view's glass, each wrong in its own way (see :func:`glass_variants`).
GLASS_VARIANTS = ("blob", "dark", "flip", "shift", "blur", "specular", "clear", "lens", "broad")
#: Variants of the panorama prior (see :func:`panorama_variants`).
PANO_VARIANTS = ("prior", "dark", "shift", "blur", "broad")


@dataclass(frozen=True)
class Component:
    """One mixture component of a view.

    Attributes:
        image: its mean as an image ``(1, 3, H, W)``, sRGB in [0, 1].
        weight: its prior weight ``pi_k`` (> 0; a view's weights are normalised to sum to 1).
        std: its standard deviation ``s_k`` in the latent blocks of the uncertain region.
    """

    image: torch.Tensor
    weight: float
    std: float


def _object_frame(mask: torch.Tensor) -> tuple[float, float, float]:
    """Centre ``(cy, cx)`` and radius (half the larger side of the bounding box) of a mask."""
    ys, xs = torch.nonzero(mask, as_tuple=True)
    cy, cx = float(ys.float().mean()), float(xs.float().mean())
    radius = max(float(ys.max() - ys.min() + 1), float(xs.max() - xs.min() + 1)) / 2
    return cy, cx, max(radius, 1.0)


def _columns(img: torch.Tensor, src_x: torch.Tensor) -> torch.Tensor:
    """``img`` with column ``x`` read from column ``src_x[x]`` (rounded, clamped to the image)."""
    idx = src_x.round().long().clamp(0, img.shape[-1] - 1)
    return img[..., idx]


def _lens(img: torch.Tensor, cy: float, cx: float, k: float) -> torch.Tensor:
    """``img`` point-mirrored through ``(cy, cx)`` and scaled by ``k``: pixel ``c + d`` reads
    ``c - k d`` (bilinear, border replicated)."""
    H, W = img.shape[-2:]
    yy, xx = torch.meshgrid(
        torch.arange(H, dtype=torch.float32, device=img.device),
        torch.arange(W, dtype=torch.float32, device=img.device),
        indexing="ij",
    )
    sy, sx = cy - k * (yy - cy), cx - k * (xx - cx)
    grid = torch.stack([sx / max(W - 1, 1) * 2 - 1, sy / max(H - 1, 1) * 2 - 1], -1)[None].expand(
        img.shape[0], -1, -1, -1
    )
    return F.grid_sample(img, grid, mode="bilinear", padding_mode="border", align_corners=True)


def glass_variants(i_minus, object_mask, names: Sequence[str] = GLASS_VARIANTS) -> dict[str, torch.Tensor]:
    """Wrong appearances of glass: I⁻ outside the object mask, a guess without optics inside.

    The variants, inside the mask (``r`` the object's radius in pixels):
        - ``blob``: the analytic backend's :func:`~snell_bench.models.analytic.glass_blob_prior`
          (the background straight through, softened, tinted, a highlight and a dark rim);
        - ``dark``: the blob darkened and tinted green-grey, like thick bottle glass;
        - ``flip``: the background mirrored left-right about the object's centre (half of a real
          lens' inversion, without the minification);
        - ``shift``: the background displaced sideways by ``0.6 r`` (a guessed, wrong refraction);
        - ``blur``: the background blurred by ``r / 4`` (frosted glass);
        - ``specular``: the blob washed towards white (a milky, glossy ball);
        - ``clear``: the background straight through, untouched (an invisible object);
        - ``lens``: the background around the object point-mirrored through its centre and seen
          over twice the object's size (pixel ``c + d`` shows ``c - 2 d``, bilinear, border
          replicated): roughly what a ball lens shows, the one guess near the physics, with the
          wrong scale and none of the real distortion;
        - ``broad``: the blob again (the broad component's centre; its std makes it broad).

    Args:
        i_minus: the object-free image, ``(H, W, 3)`` or ``(1, 3, H, W)``, sRGB in [0, 1].
        object_mask: boolean ``(H, W)``.
        names: which variants, from :data:`GLASS_VARIANTS`.

    Returns:
        ``name -> (1, 3, H, W)`` images, equal to I⁻ outside the mask.

    Raises:
        ValueError: for an unknown name or a mask of another size than the image.
    """
    img = as_rgb_batch(i_minus)
    mask = as_tensor(object_mask, dtype=torch.bool, device=img.device)
    if mask.shape != img.shape[-2:]:
        raise ValueError(f"object mask {tuple(mask.shape)} does not match the image {tuple(img.shape[-2:])}")
    unknown = [n for n in names if n not in GLASS_VARIANTS]
    if unknown:
        raise ValueError(f"unknown glass variants {unknown}; use names from {GLASS_VARIANTS}")
    if not mask.any():
        return {n: img.clone() for n in names}
    cy, cx, radius = _object_frame(mask)
    W = img.shape[-1]
    xs = torch.arange(W, dtype=torch.float32, device=img.device)
    blob = glass_blob_prior(img, mask)
    dev = img.device
    inside = {
        "blob": lambda: blob,
        "dark": lambda: blob * torch.tensor([0.55, 0.66, 0.6], device=dev).view(1, 3, 1, 1),
        "flip": lambda: _columns(img, 2 * cx - xs),
        "shift": lambda: _columns(img, xs + 0.6 * radius),
        "blur": lambda: gaussian_blur(img, max(1.0, radius / 4)),
        "specular": lambda: 0.45 * blob + 0.55,
        "clear": lambda: img,
        "lens": lambda: _lens(img, cy, cx, 2.0),
        "broad": lambda: blob,
    }
    return {n: torch.where(mask, inside[n]().clamp(0, 1), img) for n in names}


def panorama_variants(panorama, names: Sequence[str] = PANO_VARIANTS) -> dict[str, torch.Tensor]:
    """Variants of a panorama prior ``(Hp, 2 Hp, 3)`` or ``(1, 3, Hp, Wp)``, all over the image.

    ``prior``: the panorama itself; ``dark``: darker and tinted; ``shift``: rotated about the
    vertical axis by 1/16 of a turn (columns rolled, periodic in x); ``blur``: blurred by ``Hp / 64``
    pixels; ``broad``: the panorama itself (the broad component's centre).

    Raises:
        ValueError: for an unknown name.
    """
    img = as_rgb_batch(panorama)
    unknown = [n for n in names if n not in PANO_VARIANTS]
    if unknown:
        raise ValueError(f"unknown panorama variants {unknown}; use names from {PANO_VARIANTS}")
    dev = img.device
    make = {
        "prior": lambda: img,
        "dark": lambda: img * torch.tensor([0.7, 0.78, 0.74], device=dev).view(1, 3, 1, 1),
        "shift": lambda: torch.roll(img, img.shape[-1] // 16, dims=-1),
        "blur": lambda: gaussian_blur(img, max(1.0, img.shape[-2] / 64)),
        "broad": lambda: img,
    }
    return {n: make[n]().clamp(0, 1) for n in names}


def _weights(spec, allowed: Sequence[str], what: str) -> dict[str, float]:
    if not isinstance(spec, Mapping):
        raise ValueError(f"{what} must map variant names to weights, got {spec!r}")
    out = {str(k): float(v) for k, v in spec.items()}
    if not out:
        raise ValueError(f"{what} is empty")
    for k, v in out.items():
        if k not in allowed:
            raise ValueError(f"{what}: unknown variant {k!r}; use names from {tuple(allowed)}")
        if not (v > 0 and math.isfinite(v)):
            raise ValueError(f"{what}: the weight of {k!r} must be finite and > 0, got {v}")
    return out


class MixtureGenerator(AnalyticGenerator):
    """Exact velocity of a per-block Gaussian-mixture data distribution (see the module docs).

    Args:
        main_components: the main view's components; the first one's mean is used outside the
            uncertain region.
        pano_components: the panorama's components (``None``: no panorama view).
        prior_std: the standard deviation outside the uncertain region (every component the same).
        glass_mask: boolean ``(H, W)`` of the main view: its uncertain region is the latent blocks
            that touch it (``None``: the whole image).
        downscale: the latent block size ``f``.
        seed: draws the latent transform's orthogonal matrix.

    Raises:
        ValueError: for no components, a non-positive or infinite weight or standard deviation,
            components of different sizes, or sizes that are not multiples of ``downscale``.
    """

    name = "mixture"
    #: A CPU backend in float32 (the posterior is evaluated in float64 inside).
    device = torch.device("cpu")
    dtype = torch.float32

    def __init__(
        self,
        main_components: Sequence[Component],
        pano_components: Sequence[Component] | None = None,
        *,
        prior_std: float = 0.05,
        glass_mask=None,
        group: int = 1,
        pano_group: int = 1,
        downscale: int = 8,
        seed: int = 0,
    ) -> None:
        for n, g in (("group", group), ("pano_group", pano_group)):
            if isinstance(g, bool) or int(g) != g or g < 0:
                raise ValueError(f"{n} must be an integer >= 0 (0: the whole view), got {g!r}")
        if not main_components:
            raise ValueError("the main view needs at least one mixture component")
        super().__init__(
            main_components[0].image, prior_std=prior_std, glass_std=prior_std, downscale=downscale, seed=seed
        )
        #: view -> (means (h w, K, C), variances s_k^2 (h w, K), log weights (K,), |mu_k|^2 (h w, K)),
        #: float64, blocks in row-major order.
        self._mixtures: dict[str, tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]] = {}
        #: view -> the side, in latent blocks, of the squares that share one component (0: all).
        self.groups = {"main": int(group), "pano": int(pano_group)}
        self.set_mixture("main", main_components, glass_mask)
        if pano_components is not None:
            self.set_mixture("pano", pano_components)

    @classmethod
    def from_scene(
        cls,
        i_minus,
        object_mask,
        panorama=None,
        *,
        prior_std: float = 0.05,
        glass_std: float = 0.1,
        broad_std: float = 0.3,
        pano_std: float | None = None,
        components: Mapping[str, float] | None = None,
        pano_components: Mapping[str, float] | None = None,
        group: int = 1,
        pano_group: int = 1,
        downscale: int = 8,
        seed: int = 0,
    ) -> MixtureGenerator:
        """The scene's mixture: wrong glass appearances inside the object, its panorama's variants.

        Args:
            i_minus: the object-free image ``(H, W, 3)`` or ``(1, 3, H, W)``, sRGB in [0, 1].
            object_mask: boolean ``(H, W)``, where the object is.
            panorama: the panorama prior ``(Hp, 2 Hp, 3)`` (right or wrong: the caller's choice);
                ``None``: no panorama view.
            prior_std: the standard deviation where the model is sure (the room).
            glass_std: the narrow glass components' standard deviation.
            broad_std: the ``broad`` components' standard deviation (main view and panorama).
            pano_std: the narrow panorama components' standard deviation (default ``prior_std``).
            components: main-view variant name (:data:`GLASS_VARIANTS`) -> weight; default
                ``{"blob": 1}``, one Gaussian: the analytic backend with ``glass_std``.
            pano_components: panorama variant name (:data:`PANO_VARIANTS`) -> weight; default
                ``{"prior": 1}``, the analytic backend's panorama with ``pano_std``.
            downscale: the latent block size.
            seed: the latent transform's seed.

        Returns:
            The generator; its first main component is the first name in ``components``.

        Raises:
            ValueError: for unknown variant names, bad weights or standard deviations.
        """
        spec = _weights(components if components is not None else {"blob": 1.0}, GLASS_VARIANTS, "model components")
        for n, v in (("glass_std", glass_std), ("broad_std", broad_std)):
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"model.generator.{n} must be finite and > 0, got {v}")
        images = glass_variants(i_minus, object_mask, list(spec))
        main = [Component(images[n], w, broad_std if n == "broad" else glass_std) for n, w in spec.items()]
        pano = None
        if panorama is not None:
            pstd = prior_std if pano_std is None else float(pano_std)
            pspec = _weights(
                pano_components if pano_components is not None else {"prior": 1.0}, PANO_VARIANTS, "pano components"
            )
            pimages = panorama_variants(panorama, list(pspec))
            pano = [Component(pimages[n], w, broad_std if n == "broad" else pstd) for n, w in pspec.items()]
        return cls(
            main,
            pano,
            prior_std=prior_std,
            glass_mask=object_mask,
            group=group,
            pano_group=pano_group,
            downscale=downscale,
            seed=seed,
        )

    def set_mixture(self, view: str, components: Sequence[Component], region=None) -> None:
        """A view's components, uncertain in the latent blocks that touch ``region`` ``(H, W)``
        (``None``: everywhere); outside it every component takes the first one's mean and
        ``prior_std``."""
        if not components:
            raise ValueError(f"view {view!r} needs at least one mixture component")
        first = as_rgb_batch(components[0].image)
        size = tuple(first.shape[-2:])
        _, h, w = self.geometry.latent_shape(*size)  # validates the size
        if region is None:
            touched = torch.ones((1, 1, h, w), dtype=torch.bool, device=self.device)
        else:
            m = as_tensor(region, dtype=torch.float32, device=self.device)
            if tuple(m.shape) != size:
                raise ValueError(f"glass mask {tuple(m.shape)} does not match the prior {size}")
            touched = F.max_pool2d(m[None, None], self.downscale) > 0
        mus, stds, logw = [], [], []
        base = self.encode(first)
        for c in components:
            img = as_rgb_batch(c.image)
            if tuple(img.shape[-2:]) != size:
                raise ValueError(f"view {view!r}: component of size {tuple(img.shape[-2:])}, expected {size}")
            if not (c.std > 0 and math.isfinite(c.std)):
                raise ValueError(f"view {view!r}: component std must be finite and > 0, got {c.std}")
            if not (c.weight > 0 and math.isfinite(c.weight)):
                raise ValueError(f"view {view!r}: component weight must be finite and > 0, got {c.weight}")
            mus.append(torch.where(touched, self.encode(img), base)[0])  # (C, h, w)
            stds.append(torch.where(touched[0, 0], float(c.std), self.prior_std))  # (h, w)
            logw.append(math.log(c.weight))
        C = self.geometry.channels
        lw = torch.tensor(logw, dtype=torch.float64, device=self.device)
        mu = torch.stack(mus).double().reshape(len(mus), C, h * w).permute(2, 0, 1).contiguous()  # (N, K, C)
        s2 = torch.stack(stds).double().reshape(len(stds), h * w).T.contiguous() ** 2
        self._mixtures[view] = (mu, s2, lw - torch.logsumexp(lw, 0), (mu * mu).sum(2))
        self._priors[view] = base  # the conditioning checks and prior_image use the first component
        self._std[view] = stds[0][None, None]

    @property
    def num_components(self) -> dict[str, int]:
        """``view -> K``."""
        return {v: int(m[0].shape[1]) for v, m in self._mixtures.items()}

    # ------------------------------------------------------------------ model
    def responsibilities(self, z: torch.Tensor, sigma, cond: Condition) -> torch.Tensor:
        """The posterior component weights ``w_k`` per block, ``(B, K, h, w)`` float64 (every view
        of the batch must have the same ``K``)."""
        return torch.stack(self._posterior(z, sigma, cond)[2])

    def posterior_mean(self, z: torch.Tensor, sigma, cond: Condition) -> torch.Tensor:
        return self._posterior(z, sigma, cond)[0].to(z.dtype)

    def velocity(self, z: torch.Tensor, sigma, cond: Condition) -> torch.Tensor:
        sig = self._sigma(sigma, z)
        if torch.any(sig <= 0):
            raise ValueError("velocity is undefined at sigma = 0; the sampler returns its estimate there")
        return self._posterior(z, sigma, cond)[1].to(z.dtype)

    @staticmethod
    def _group_sum(logp: torch.Tensor, h: int, w: int, group: int) -> torch.Tensor:
        """Per-block log densities ``(h w, K)`` summed over squares of ``group x group`` blocks (the
        last row and column of squares may be cut by the border; 0: over the whole view), given
        back to every block of the square."""
        if group == 1:
            return logp
        K = logp.shape[1]
        if group == 0:
            return logp.sum(0, keepdim=True).expand_as(logp)
        lp = logp.T.reshape(1, K, h, w)
        pooled = F.avg_pool2d(lp, group, stride=group, ceil_mode=True, divisor_override=1)
        up = pooled.repeat_interleave(group, 2).repeat_interleave(group, 3)[..., :h, :w]
        return up.reshape(K, h * w).T

    def _posterior(self, z: torch.Tensor, sigma, cond: Condition):
        """``(E[x0 | z], v, [w])`` of every sample, evaluated per block in float64.

        With ``A = sum_k w_k s_k^2 / V_k``, ``B = sum_k w_k / V_k`` and ``M = sum_k (w_k / V_k) mu_k``:
        ``E[x0 | z] = a A z + sigma^2 M`` and ``v = (sigma B - a A) z - sigma M``; the squared
        distances ``|z - a mu_k|^2`` are expanded into ``|z|^2 - 2 a z.mu_k + a^2 |mu_k|^2`` so that
        each reduction over the channels is one batched matrix product.
        """
        views = cond.data["views"]
        if len(views) == 1 and z.shape[0] > 1:
            views = views * z.shape[0]
        if len(views) != z.shape[0]:
            raise ValueError(f"condition has {len(views)} prompts for a batch of {z.shape[0]}")
        sig = torch.as_tensor(sigma, dtype=torch.float64).detach().cpu().flatten()  # as given, not rounded
        if sig.numel() == 1:
            sig = sig.expand(z.shape[0])
        if sig.numel() != z.shape[0]:
            raise ValueError(f"{sig.numel()} noise levels for a batch of {z.shape[0]}")
        B, C, h, w = z.shape
        means, vels, resp = [], [], []
        for b, view in enumerate(views):
            mu, s2, logw, mu2 = self._mixtures[view]
            if mu.shape[0] != h * w or mu.shape[2] != C:
                shape = (mu.shape[2],) + tuple(self._priors[view].shape[-2:])
                raise ValueError(f"latent {tuple(z.shape[1:])} does not match the {view!r} prior {shape}")
            zb = z[b].to(torch.float64).reshape(C, h * w).T  # (N, C)
            s = float(sig[b])
            a = 1.0 - s
            var = a * a * s2 + s * s  # (N, K)
            zm = torch.bmm(mu, zb[:, :, None])[..., 0]  # (N, K)
            d2 = (zb * zb).sum(1, keepdim=True) - 2 * a * zm + a * a * mu2
            d2 = d2.clamp_min(0)
            logl = -0.5 * d2 / var - 0.5 * C * torch.log(var)  # log N(z_b; a mu_kb, V_k I) + const
            # one component per group of blocks: its log likelihood is the sum over the group's blocks
            wk = torch.softmax(logw + self._group_sum(logl, h, w, self.groups.get(view, 1)), dim=1)  # (N, K)
            A = (wk * s2 / var).sum(1, keepdim=True)
            Bk = (wk / var).sum(1, keepdim=True)
            M = torch.bmm((wk / var)[:, None, :], mu)[:, 0]  # (N, C)
            means.append((a * A * zb + s * s * M).T.reshape(C, h, w))
            vels.append(((s * Bk - a * A) * zb - s * M).T.reshape(C, h, w))
            resp.append(wk.T.reshape(-1, h, w))
        return torch.stack(means), torch.stack(vels), resp
