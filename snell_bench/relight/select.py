"""Relighting by selection: N relit candidates, the one closest to the un-relit image inside the
object's silhouette kept.

The paper relights the sampled image with FLUX Kontext ("Create soft shadows and caustics under
<p_obj>") N times and keeps the candidate with the highest PSNR against the un-relit image inside
the object: relighting may add shadows and caustics around the object but should leave the
refraction, which the sampler made consistent with the scene, as it is.

Convention:
    - Images: ``(1, 3, H, W)`` float32 sRGB tensors in [0, 1]; masks: ``(H, W)`` bool (numpy or
      torch), ``True`` inside the object's silhouette.
    - PSNR: ``10 log10(1 / MSE)`` in dB (peak 1), the MSE over the three channels of the pixels
      inside the mask; identical images give ``inf``.
    - Seeds: candidate ``k`` of a cell with seed ``s`` has the seed
      ``SeedSequence([s, k]).generate_state(1)[0]`` (a 32-bit integer), made distinct by moving
      past a repeated value; the list depends on ``s`` and ``n`` only, and the first ``m`` seeds
      of ``n > m`` candidates are those of ``m`` candidates.
    - Choice: the highest PSNR; on a tie, the first candidate.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from snell_bench.relight.base import Relighter, check_image
from snell_bench.utils.tensors import as_tensor

__all__ = ["IDENTICAL_NOTE", "RelightResult", "candidate_seeds", "masked_psnr", "relight"]

#: The note a candidate identical to the un-relit image (infinite PSNR) carries in the records.
IDENTICAL_NOTE = "identical to the un-relit image"


def candidate_seeds(seed: int, n: int) -> list[int]:
    """The seeds of the ``n`` relighting candidates of a cell.

    Args:
        seed: the cell's seed (a non-negative integer).
        n: the number of candidates (>= 1).

    Returns:
        ``n`` distinct integers in ``[0, 2**32)``, deterministic in ``(seed, n)``; a prefix of the
        seeds of more candidates.

    Raises:
        ValueError: if ``seed`` is negative or ``n`` < 1.

    Examples:
        >>> s = candidate_seeds(0, 3)
        >>> len(set(s)), s == candidate_seeds(0, 5)[:3], s == candidate_seeds(1, 3)
        (3, True, False)
    """
    if int(seed) != seed or seed < 0:
        raise ValueError(f"the cell seed must be a non-negative integer, got {seed!r}")
    if int(n) != n or n < 1:
        raise ValueError(f"the number of relighting candidates must be an integer >= 1, got {n!r}")
    seeds: list[int] = []
    k = 0
    while len(seeds) < n:
        s = int(np.random.SeedSequence([int(seed), k]).generate_state(1, np.uint32)[0])
        k += 1
        if s not in seeds:
            seeds.append(s)
    return seeds


def masked_psnr(a, b, mask) -> float:
    """PSNR in dB between two images inside a mask (peak 1).

    Args:
        a: ``(1, 3, H, W)`` image in [0, 1] (a tensor or an array).
        b: ``(1, 3, H, W)`` image in [0, 1].
        mask: ``(H, W)`` bool, the pixels compared.

    Returns:
        ``10 log10(1 / MSE)`` with the MSE over the RGB values of the masked pixels (float64);
        ``inf`` when they are identical there.

    Raises:
        ValueError: if the shapes do not match, the mask is empty, or a masked value is not finite.

    Examples:
        >>> a = torch.zeros(1, 3, 2, 2); b = a.clone(); b[..., 0, 0] = 0.1
        >>> m = torch.tensor([[True, False], [False, False]])
        >>> round(masked_psnr(a, b, m), 6), masked_psnr(a, b, ~m)
        (20.0, inf)
    """
    a64 = as_tensor(a).detach().to("cpu", torch.float64)
    b64 = as_tensor(b).detach().to("cpu", torch.float64)
    m = as_tensor(mask).detach().to("cpu")
    if a64.shape != b64.shape or a64.ndim != 4 or a64.shape[:2] != (1, 3):
        raise ValueError(f"masked_psnr needs two (1, 3, H, W) images, got {tuple(a64.shape)} and {tuple(b64.shape)}")
    if m.dtype != torch.bool or tuple(m.shape) != tuple(a64.shape[-2:]):
        raise ValueError(
            f"the mask must be a bool (H, W) = {tuple(a64.shape[-2:])} array, got {m.dtype} {tuple(m.shape)}"
        )
    if not bool(m.any()):
        raise ValueError(
            "masked_psnr: the mask is empty (no pixel of the object's silhouette): there is nothing to compare; "
            "check the object mask (warps.object_mask) of this cell"
        )
    da, db = a64[0][:, m], b64[0][:, m]
    if not (torch.isfinite(da).all() and torch.isfinite(db).all()):
        raise ValueError("masked_psnr: an image has non-finite values inside the mask")
    mse = float(((da - db) ** 2).mean())
    return math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)


@dataclass
class RelightResult:
    """The relit image and the record of every candidate.

    Attributes:
        image: the chosen candidate, ``(1, 3, H, W)`` float32 sRGB in [0, 1].
        candidates: one ``{"seed": int, "psnr_db": float, "seconds": float}`` per candidate, in the
            order of the seeds (``psnr_db`` may be ``inf``; :meth:`to_json` makes it JSON-safe).
        chosen: the index of the chosen candidate in ``candidates``.
        prompt: the instruction the relighter got.
        relighter: the relighter's ``name``.
        description: the relighter's ``describe()``.
        images: every candidate image (same order), if kept, else ``None``.
    """

    image: torch.Tensor
    candidates: list[dict]
    chosen: int
    prompt: str = ""
    relighter: str = ""
    description: str = ""
    images: list[torch.Tensor] | None = field(default=None, repr=False)

    @property
    def seed(self) -> int:
        """The chosen candidate's seed."""
        return int(self.candidates[self.chosen]["seed"])

    @property
    def psnr_db(self) -> float:
        """The chosen candidate's masked PSNR (may be ``inf``)."""
        return float(self.candidates[self.chosen]["psnr_db"])

    def to_json(self) -> dict:
        """A JSON-safe record: no ``inf`` or ``NaN`` anywhere.

        Returns:
            ``{"relighter", "description", "prompt", "chosen", "seed", "psnr_db", "candidates"}``;
            an infinite PSNR is written as ``None`` with ``"note": IDENTICAL_NOTE`` beside it.
        """

        def entry(c: dict) -> dict:
            out = {k: v for k, v in c.items() if k != "psnr_db"}
            out["seed"] = int(c["seed"])
            psnr = float(c["psnr_db"])
            if math.isfinite(psnr):
                out["psnr_db"] = psnr
            else:
                out["psnr_db"] = None
                out["note"] = IDENTICAL_NOTE
            if "seconds" in out:
                out["seconds"] = float(out["seconds"])
            return out

        candidates = [entry(c) for c in self.candidates]
        return {
            "relighter": self.relighter,
            "description": self.description,
            "prompt": self.prompt,
            "chosen": int(self.chosen),
            "seed": self.seed,
            "psnr_db": candidates[self.chosen]["psnr_db"],
            "candidates": candidates,
        }


def relight(
    image: torch.Tensor,
    *,
    relighter: Relighter,
    prompt: str,
    seeds: list[int],
    object_mask,
    keep_images: bool = False,
    **scene: Any,
) -> RelightResult:
    """Relight ``image`` once per seed and keep the candidate closest to it inside the object.

    Args:
        image: the un-relit image, ``(1, 3, H, W)`` float32 sRGB in [0, 1].
        relighter: a :class:`~snell_bench.relight.base.Relighter`.
        prompt: the instruction (the paper: ``"Create soft shadows and caustics under <p_obj>"``).
        seeds: one seed per candidate (:func:`candidate_seeds`).
        object_mask: ``(H, W)`` bool, the object's silhouette (``warps.object_mask``).
        keep_images: also return every candidate image (``RelightResult.images``).
        **scene: passed to ``relighter.relight`` as they are: ``scene`` (the
            :class:`~snell_bench.scene.sources.SceneInputs`), ``obj`` (the placed object) and
            ``warps`` (its :class:`~snell_bench.optics.warps.WarpSet`).

    Returns:
        The :class:`RelightResult`: the candidate with the highest :func:`masked_psnr` against
        ``image`` inside ``object_mask`` (the first one on a tie), and every candidate's record.

    Raises:
        ValueError: if there is no seed, the mask is empty or does not match, or a candidate does
            not have the input's shape.
    """
    H, W = check_image(image)
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("relight needs at least one seed (relight.candidates >= 1)")
    mask = as_tensor(object_mask).detach().to("cpu")
    if mask.dtype != torch.bool or tuple(mask.shape) != (H, W):
        raise ValueError(f"object_mask must be a bool ({H}, {W}) array, got {mask.dtype} {tuple(mask.shape)}")
    if not bool(mask.any()):
        raise ValueError("relight: the object mask is empty, so no candidate can be chosen by its silhouette")
    ref = image.detach().to("cpu", torch.float32)
    best, best_psnr, best_image = 0, -math.inf, None
    candidates: list[dict] = []
    images: list[torch.Tensor] = []
    for k, seed in enumerate(seeds):
        t0 = time.perf_counter()
        out = relighter.relight(ref.clone(), prompt=prompt, seed=seed, **scene)
        seconds = time.perf_counter() - t0
        if check_image(out, f"the relit candidate of seed {seed}") != (H, W):
            raise ValueError(f"the relighter returned a {tuple(out.shape[-2:])} image for a {(H, W)} input")
        out = out.detach().to("cpu", torch.float32)
        psnr = masked_psnr(out, ref, mask)
        candidates.append({"seed": seed, "psnr_db": psnr, "seconds": round(seconds, 4)})
        if keep_images:
            images.append(out)
        if best_image is None or psnr > best_psnr:
            best, best_psnr, best_image = k, psnr, out
    assert best_image is not None
    return RelightResult(
        image=best_image,
        candidates=candidates,
        chosen=best,
        prompt=prompt,
        relighter=str(getattr(relighter, "name", type(relighter).__name__)),
        description=relighter.describe() if hasattr(relighter, "describe") else "",
        images=images if keep_images else None,
    )
