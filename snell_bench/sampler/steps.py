"""Pure rectified-flow steps.

Convention:
    ``z_sigma = (1 - sigma) x0 + sigma eps`` (``sigma`` = 1 is pure noise), velocity ``v = eps - x0``.
    Tensors of any shape; ``sigma`` floats (python or 0-d tensors). Random draws come only from the
    ``torch.Generator`` passed in (:func:`seeded_generator`).
"""

from __future__ import annotations

import math

import torch

from snell_bench.utils.tensors import is_meta

__all__ = [
    "seeded_generator",
    "euler_estimate",
    "latent_rounding",
    "pipeline_step",
    "rounding_dtype",
    "sync_step",
    "stochastic_step",
    "sde_step",
    "renoise",
    "renoise_euler_maruyama",
]


def seeded_generator(device: torch.device | str, seed: int) -> torch.Generator:
    """The ``torch.Generator`` a run draws from, on ``device`` and seeded with ``seed``.

    ``meta`` (shapes, no data) has no generator of its own: a CPU generator stands in, which torch
    accepts for a ``meta`` draw (nothing is drawn) and diffusers' ``randn_tensor`` draws on the
    CPU and moves to ``meta``. Every other device gets its own, so its draws are unchanged.

    Examples:
        >>> seeded_generator("meta", 0).device, seeded_generator("cpu", 0).initial_seed()
        (device(type='cpu'), 0)
    """
    device = torch.device(device)
    return torch.Generator("cpu" if is_meta(device) else device).manual_seed(int(seed))


def rounding_dtype(gen, mode: str = "float32") -> torch.dtype | None:
    """The dtype a sampler rounds its latents to after every step, or ``None`` (no rounding).

    ``mode="float32"`` keeps the latents float32 whatever the model's precision; ``mode="model"``
    rounds them to the model's dtype (``gen.dtype``; float32 when absent), as ``FluxPipeline``
    does by holding its latents in the transformer's dtype (bfloat16 on a GPU) between scheduler
    steps; a float32 model needs no rounding. ``mode="float16"`` rounds them to float16 whatever
    the model (the authors' float16 pipeline, also on a float32 stand-in).

    Args:
        gen: the generator (its ``dtype`` attribute is read).
        mode: ``"float32"``, ``"model"`` or ``"float16"`` (config key ``sampler.latent_dtype``).

    Raises:
        ValueError: for an unknown mode.

    Examples:
        >>> rounding_dtype(None, "float16"), rounding_dtype(None, "model"), rounding_dtype(None)
        (torch.float16, None, None)
    """
    if mode not in ("float32", "model", "float16"):
        raise ValueError(f"sampler.latent_dtype={mode!r} is unknown; use 'float32', 'model' or 'float16'")
    if mode == "float16":
        return torch.float16
    dt = getattr(gen, "dtype", None) or torch.float32
    return None if mode == "float32" or dt == torch.float32 else dt


def latent_rounding(gen, mode: str = "float32"):
    """``z -> z`` rounded to :func:`rounding_dtype` and back to float32 (the identity when there is
    no rounding): applied to the initial noise, after stochastic steps and time travel."""
    dt = rounding_dtype(gen, mode)
    if dt is None:
        return lambda z: z
    return lambda z: z.to(dt).to(torch.float32)


def euler_estimate(z: torch.Tensor, v: torch.Tensor, sigma: float) -> torch.Tensor:
    """Clean-latent estimate ``x0_hat = z - sigma v``."""
    return z - float(sigma) * v


def pipeline_step(
    z: torch.Tensor, x0: torch.Tensor, sigma: float, sigma_next: float, dtype: torch.dtype
) -> torch.Tensor:
    """:func:`sync_step` computed as ``FlowMatchEulerDiscreteScheduler.step`` does with latents held
    in ``dtype`` (``FluxPipeline`` in bfloat16): ``z' = dtype(z + dtype((sigma' - sigma) v))`` with the
    velocity ``v = (z - x0) / sigma`` rounded to ``dtype`` (the model's output), the sum in float32.
    For ``dtype = float32`` it equals :func:`sync_step` up to float rounding.

    Returns:
        ``z'`` as float32 holding ``dtype`` values.
    """
    sigma, sigma_next = float(sigma), float(sigma_next)
    if sigma <= 0.0:
        raise ValueError("cannot step from sigma = 0")
    v = ((z - x0) / sigma).to(dtype)
    dt = torch.tensor(sigma_next - sigma, dtype=torch.float32, device=z.device)
    return (z.float() + dt * v).to(dtype).to(torch.float32)


def sync_step(z: torch.Tensor, x0: torch.Tensor, sigma: float, sigma_next: float) -> torch.Tensor:
    """Deterministic step with a (synchronized) clean estimate:
    ``z' = (sigma'/sigma) z + (1 - sigma'/sigma) x0``. At ``sigma' = 0`` it returns ``x0`` itself
    (no division by zero anywhere)."""
    sigma, sigma_next = float(sigma), float(sigma_next)
    if sigma_next <= 0.0:
        return x0.clone()
    if sigma <= 0.0:
        raise ValueError("cannot step from sigma = 0")
    r = sigma_next / sigma
    return r * z + (1.0 - r) * x0


def stochastic_step(
    z: torch.Tensor, x0: torch.Tensor, sigma: float, sigma_next: float, generator: torch.Generator, eta: float = 1.0
) -> torch.Tensor:
    """Stochastic step: ``z' = (1 - sigma') x0 + sigma' eps'`` with
    ``eps' = sqrt(1 - eta^2) eps_hat + eta n``, ``eps_hat = (z - (1 - sigma) x0) / sigma`` the implied
    noise and ``n ~ N(0, I)`` from ``generator``. ``eta = 0`` is :func:`sync_step`; ``eta = 1``
    renoises fully (and needs no implied noise, so it may start from ``sigma = 0``)."""
    sigma, sigma_next = float(sigma), float(sigma_next)
    if not 0.0 <= eta <= 1.0:
        raise ValueError(f"eta must be in [0, 1], got {eta}")
    if sigma_next <= 0.0:
        return x0.clone()
    keep = math.sqrt(1.0 - eta * eta)
    if keep > 0.0 and sigma <= 0.0:
        raise ValueError("cannot step from sigma = 0 with eta < 1 (the implied noise is undefined)")
    n = torch.randn(z.shape, generator=generator, dtype=z.dtype, device=z.device)
    eps = eta * n
    if keep > 0.0:
        eps = keep * ((z - (1.0 - sigma) * x0) / sigma) + eps
    return (1.0 - sigma_next) * x0 + sigma_next * eps


def renoise(z: torch.Tensor, sigma: float, s: float, generator: torch.Generator) -> torch.Tensor:
    """Time travel: the exact forward kernel from ``sigma`` to a noisier ``s`` (``s >= sigma``):
    ``z_s = a z_sigma + sqrt(s^2 - a^2 sigma^2) n``, ``a = (1 - s) / (1 - sigma)``. If
    ``z_sigma = (1 - sigma) x0 + sigma eps`` then ``z_s`` has exactly the marginal
    ``(1 - s) x0 + s eps'``."""
    sigma, s = float(sigma), float(s)
    if not (0.0 <= sigma <= s <= 1.0) or sigma >= 1.0:
        raise ValueError(f"renoise needs 0 <= sigma <= s <= 1 and sigma < 1, got sigma={sigma}, s={s}")
    a = (1.0 - s) / (1.0 - sigma)
    std = math.sqrt(max(s * s - a * a * sigma * sigma, 0.0))
    n = torch.randn(z.shape, generator=generator, dtype=z.dtype, device=z.device)
    return a * z + std * n


def sde_step(
    z: torch.Tensor, x0: torch.Tensor, sigma: float, sigma_next: float, generator: torch.Generator
) -> torch.Tensor:
    """Euler-Maruyama step (the authors' scheduler with ``stochastic_sampling``):
    ``z' = z + (sigma' - sigma) v + |sigma' - sigma| n`` with ``v = (z - x0) / sigma`` and
    ``n ~ N(0, I)`` from ``generator``; at ``sigma' = 0`` it returns ``x0`` (no draw). Its noise does
    not keep the marginal ``(1 - sigma') x0 + sigma' eps`` (the variance grows by ``(sigma - sigma')^2``
    per step); it is the released code's step, kept to reproduce it.

    Raises:
        ValueError: stepping from ``sigma = 0`` to a positive level.
    """
    sigma, sigma_next = float(sigma), float(sigma_next)
    if sigma_next <= 0.0:
        return x0.clone()
    if sigma <= 0.0:
        raise ValueError("cannot step from sigma = 0")
    n = torch.randn(z.shape, generator=generator, dtype=z.dtype, device=z.device)
    v = (z - x0) / sigma
    return z + (sigma_next - sigma) * v + abs(sigma_next - sigma) * n


def renoise_euler_maruyama(z: torch.Tensor, sigma: float, s: float, generator: torch.Generator) -> torch.Tensor:
    """Time travel as the authors' code renoises from ``sigma`` to a noisier ``s``: one
    Euler-Maruyama step of the forward flow with the velocity towards a fresh draw ``n``,
    ``z_s = z + (s - sigma) (n - z) / (1 - sigma) + |s - sigma| n`` (the same ``n`` twice). Unlike
    :func:`renoise` its marginal is not the forward process's: the mean is ``a z`` with
    ``a = (1 - s) / (1 - sigma)`` as there, the added noise's standard deviation is
    ``(s - sigma) (1 / (1 - sigma) + 1)`` instead of ``sqrt(s^2 - a^2 sigma^2)``.

    Raises:
        ValueError: unless ``0 <= sigma <= s <= 1`` and ``sigma < 1``.
    """
    sigma, s = float(sigma), float(s)
    if not (0.0 <= sigma <= s <= 1.0) or sigma >= 1.0:
        raise ValueError(f"renoise needs 0 <= sigma <= s <= 1 and sigma < 1, got sigma={sigma}, s={s}")
    n = torch.randn(z.shape, generator=generator, dtype=z.dtype, device=z.device)
    return z + (s - sigma) * (n - z) / (1.0 - sigma) + abs(s - sigma) * n
