"""The generator alone from a prompt: the rectified-flow Euler loop of a text-to-image pipeline.

Convention: the same initial noise, schedule and deterministic steps as the synchronized sampler
with ``sync="none"`` (:func:`snell_bench.sampler.snellcaster.sample`), without any warps; the
image is ``(1, 3, H, W)`` float32 sRGB in [0, 1] on the CPU (on ``meta`` for a generator there); the
loop runs on the generator's device.
"""

from __future__ import annotations

import torch

from snell_bench.models.base import Generator, generator_device
from snell_bench.sampler.steps import (
    euler_estimate,
    latent_rounding,
    pipeline_step,
    rounding_dtype,
    seeded_generator,
    sync_step,
)
from snell_bench.utils.tensors import digest, to_host

__all__ = ["text_to_image"]


@torch.no_grad()
def text_to_image(
    gen: Generator,
    prompt: str,
    height: int,
    width: int,
    *,
    steps: int = 20,
    seed: int = 0,
    schedule: str = "flux",
    latent_dtype: str = "float32",
    record: dict | None = None,
) -> torch.Tensor:
    """Generate one image from ``prompt``.

    Args:
        gen: any generator backend.
        prompt: the text.
        height: image height in pixels (a multiple of ``gen.geometry.multiple``).
        width: image width in pixels (likewise).
        steps: denoising steps T.
        seed: seeds the initial noise (the only randomness).
        schedule: ``flux`` or ``linear`` (:meth:`Generator.sigmas`).
        latent_dtype: ``float32`` or ``model`` (:func:`~snell_bench.sampler.steps.latent_rounding`).
        record: a dict that receives ``initial_noise``, the :func:`~snell_bench.utils.tensors.digest`
            of the initial noise (the synchronised sampler records its own draw likewise).

    Returns:
        The image ``(1, 3, H, W)`` in [0, 1], deterministic for the seed.
    """
    dev = generator_device(gen)
    keep = latent_rounding(gen, latent_dtype)
    model_dtype = rounding_dtype(gen, latent_dtype)
    g = seeded_generator(dev, seed)
    shape = gen.geometry.latent_shape(int(height), int(width))
    sig = gen.sigmas(int(steps), int(height), int(width), kind=schedule)
    noise = torch.randn((1,) + shape, generator=g, device=dev)
    if record is not None:
        record["initial_noise"] = digest(noise)
    z = keep(noise)
    cond = gen.condition([prompt], ["main"])
    for i in range(int(steps)):
        sigma, sigma_next = float(sig[i]), float(sig[i + 1])
        x0 = euler_estimate(z, gen.velocity(z, sigma, cond), sigma)
        if model_dtype is not None:  # the scheduler's step with latents in the model's dtype
            z = pipeline_step(z, x0, sigma, sigma_next, model_dtype)
        else:
            z = x0 if sigma_next == 0 else sync_step(z, x0, sigma, sigma_next)
    return to_host(gen.decode(z))
