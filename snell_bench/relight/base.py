"""The relighter protocol: what the relighting stage calls once per candidate.

Convention:
    - Images: ``(1, 3, H, W)`` float32 sRGB tensors in [0, 1] on the CPU, in and out; the output has
      the input's size.
    - ``seed`` is the candidate's seed (:func:`~snell_bench.relight.select.candidate_seeds`); a
      relighter is a deterministic function of its construction, the image, the prompt and the seed.
    - ``scene`` (a :class:`~snell_bench.scene.sources.SceneInputs`), ``obj`` (the placed
      :class:`~snell_bench.scene.objects.GlassObject`, camera frame) and ``warps`` (its
      :class:`~snell_bench.optics.warps.WarpSet`) describe the scene the image shows; a relighter
      that works from the image alone (an image-editing model) ignores them; ``panorama`` (the
      cell's ``(1, 3, h, 2h)`` panorama at the object, or ``None``) is a light probe
      (:class:`~snell_bench.relight.traced.TracedRelighter`).
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import torch

__all__ = ["Relighter", "check_image"]


@runtime_checkable
class Relighter(Protocol):
    """Anything that relights an image of the scene for one seed.

    Attributes:
        name: a short label for the records (``flux_kontext``, ``tiny_kontext``, ``traced_shadow``).
    """

    name: str

    def describe(self) -> str:
        """What the relighter is and does, in one line, for the records."""
        ...

    def relight(
        self,
        image: torch.Tensor,
        *,
        prompt: str,
        seed: int,
        scene: Any = None,
        obj: Any = None,
        warps: Any = None,
        panorama: Any = None,
    ) -> torch.Tensor:
        """The relit image, ``(1, 3, H, W)`` float32 sRGB in [0, 1] on the CPU."""
        ...


def check_image(image: torch.Tensor, name: str = "image") -> tuple[int, int]:
    """Check that ``image`` is a ``(1, 3, H, W)`` floating-point tensor and return ``(H, W)``.

    Args:
        image: the tensor to check.
        name: what the error messages call it.

    Returns:
        ``(H, W)``.

    Raises:
        TypeError: if ``image`` is not a floating-point tensor.
        ValueError: if its shape is not ``(1, 3, H, W)``.
    """
    if not isinstance(image, torch.Tensor) or not image.is_floating_point():
        raise TypeError(f"{name} must be a floating-point torch tensor (1, 3, H, W), got {type(image).__name__}")
    if image.ndim != 4 or image.shape[0] != 1 or image.shape[1] != 3:
        raise ValueError(f"{name} must have shape (1, 3, H, W), got {tuple(image.shape)}")
    return int(image.shape[2]), int(image.shape[3])
