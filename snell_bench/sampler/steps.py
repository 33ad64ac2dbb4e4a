"""Pure rectified-flow steps.

Convention:
    ``z_sigma = (1 - sigma) x0 + sigma eps`` (``sigma`` = 1 is pure noise), velocity ``v = eps - x0``.
    Tensors of any shape; ``sigma`` floats (python or 0-d tensors). Random draws come only from the
    ``torch.Generator`` passed in.
"""

from __future__ import annotations

import math

import torch

__all__ = ["euler_estimate", "sync_step", "stochastic_step", "renoise"]


def euler_estimate(z: torch.Tensor, v: torch.Tensor, sigma: float) -> torch.Tensor:
    """Clean-latent estimate ``x0_hat = z - sigma v``."""
    return z - float(sigma) * v


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
