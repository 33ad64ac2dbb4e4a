"""The files an evaluation reads: the images as snell_bench writes them (lossless PNG), or the JPEG
files the authors' released evaluation (``eval/eval.py``) reads, reproduced as round trips through
PIL's own encoder and decoder.

Convention:
    - Images: numpy ``(H, W, 3)`` (or torch ``(1, 3, H, W)`` / ``(3, H, W)``), sRGB in [0, 1] (or
      ``uint8``); masks bool ``(H, W)`` (True = scored). A round trip returns float32 ``(H, W, 3)``
      in [0, 1], the decoded 8-bit values ``/ 255``, and a bool ``(H, W)`` mask.
    - Before encoding, a float image is rounded to 8 bits as ``save_png`` writes it
      (:func:`~snell_bench.metrics.functional.quantize_8bit`, round half to even, clipped).
    - ``files="jpeg"`` (config key ``metrics.files``), what the authors' files go through:

      * the generated image: ``main.jpg``, written by ``PIL.Image.save`` with no options: quality
        :data:`GENERATED_QUALITY` (75), PIL's default chroma subsampling (4:2:0);
      * the reference: ``blender.jpg``, last written by ``PIL.Image.save(..., quality=95)``
        (:data:`REFERENCE_QUALITY`; 4:2:0). Blender's own JPEG (q95) before that re-save is not
        reproduced: snell_bench's reference is not Blender's;
      * the mask: ``blender_mask.jpg``, a one-channel ``L`` image of 0 / 255 written by
        ``PIL.Image.save`` with no options (quality 75, no chroma), read back with
        ``convert("L")``, ``/ 255`` in float32 and thresholded ``>= 0.5``
        (:data:`~snell_bench.metrics.functional.AUTHORS_MASK_THRESHOLD`): a decoded value of 128
        or more is scored, 127 or less is not.

    - ``files="png"``: everything as it is (PNG is lossless).
"""

from __future__ import annotations

import io
from typing import Any

import numpy as np
import torch

from .functional import AUTHORS_MASK_THRESHOLD, quantize_8bit

__all__ = [
    "FILES",
    "FILES_CONFIG_KEY",
    "GENERATED_QUALITY",
    "MASK_QUALITY",
    "REFERENCE_QUALITY",
    "check_files",
    "evaluated_files",
    "jpeg_mask_round_trip",
    "jpeg_round_trip",
]

#: The values of ``metrics.files``.
FILES = ("png", "jpeg")

#: The config key that selects the files.
FILES_CONFIG_KEY = "metrics.files"

#: JPEG quality of the authors' ``main.jpg`` (PIL's default, ``generate_dual_view.py`` passes none).
GENERATED_QUALITY = 75

#: JPEG quality of the authors' ``blender.jpg`` (``utils/render_gt.py``'s last ``save``).
REFERENCE_QUALITY = 95

#: JPEG quality of the authors' ``blender_mask.jpg`` (PIL's default).
MASK_QUALITY = 75


def check_files(files: Any) -> str:
    """``files`` checked: one of :data:`FILES`, else ``ValueError`` naming ``metrics.files``."""
    if not isinstance(files, str) or files not in FILES:
        raise ValueError(f"{FILES_CONFIG_KEY}={files!r} is unknown: use one of {', '.join(FILES)}")
    return files


def _hwc_uint8(image: Any) -> np.ndarray:
    if isinstance(image, torch.Tensor):
        t = image.detach().cpu()
        image = (t[0] if t.ndim == 4 else t).permute(1, 2, 0).numpy()
    q = quantize_8bit(image)
    if q.ndim == 3 and q.shape[-1] == 1:
        q = q[..., 0]
    if q.ndim == 2:
        q = np.repeat(q[..., None], 3, axis=-1)
    if q.ndim != 3 or q.shape[-1] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {q.shape}")
    return np.ascontiguousarray(q)


def _encode_decode(pixels: np.ndarray, mode: str, quality: int) -> np.ndarray:
    """``pixels`` written by ``PIL.Image.save(format="JPEG", quality=quality)`` (PIL's default
    subsampling) and read back with ``convert(mode)``, as ``uint8``."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(pixels, mode=mode).save(buf, format="JPEG", quality=int(quality))
    buf.seek(0)
    with Image.open(buf) as im:
        return np.asarray(im.convert(mode))


def jpeg_round_trip(image: Any, quality: int) -> np.ndarray:
    """The image as a JPEG of ``quality`` written and read by PIL: float32 ``(H, W, 3)`` in [0, 1].

    Convention:
        The image rounded to 8 bits (``save_png``'s rounding), ``PIL.Image.save(..., quality=q)``
        with PIL's default chroma subsampling (4:2:0 for RGB), read back with ``convert("RGB")``
        and divided by 255 in float32, as the authors' ``load_rgb_image`` reads it.
    """
    return _encode_decode(_hwc_uint8(image), "RGB", quality).astype(np.float32) / np.float32(255.0)


def jpeg_mask_round_trip(mask: Any, quality: int = MASK_QUALITY) -> np.ndarray:
    """The mask as the authors' ``blender_mask.jpg`` is written and read: bool ``(H, W)``.

    Convention:
        ``mask``: bool ``(H, W)`` (or with singleton dims; any other dtype is read as ``> 0.5``),
        written as an ``L`` image of 0 / 255 at JPEG ``quality``, decoded, ``/ 255`` in float32 and
        thresholded ``>= 0.5``. JPEG's ringing at the mask's edges can move pixels on both sides of
        an edge; isolated pixels may vanish.
    """
    m = mask.detach().cpu().numpy() if isinstance(mask, torch.Tensor) else np.asarray(mask)
    m = np.squeeze(m)
    if m.ndim != 2:
        raise ValueError(f"expected an (H, W) mask, got shape {np.shape(mask)}")
    if m.dtype != np.bool_:
        m = m > 0.5
    decoded = _encode_decode(np.where(m, 255, 0).astype(np.uint8), "L", quality)
    return (decoded.astype(np.float32) / np.float32(255.0)) >= AUTHORS_MASK_THRESHOLD


def evaluated_files(
    generated: Any, reference: Any, mask: Any, files: str = "png", *, reference_is_jpeg: bool = False
) -> tuple[Any, Any, Any]:
    """``(generated, reference, mask)`` as the evaluation of ``files`` reads them.

    Convention:
        ``"png"``: returned as given. ``"jpeg"``: the generated image through
        :func:`jpeg_round_trip` at :data:`GENERATED_QUALITY`, the reference at
        :data:`REFERENCE_QUALITY` (as given where ``reference_is_jpeg``: it already decodes the
        JPEG its renderer wrote, the Cycles reference), the mask through
        :func:`jpeg_mask_round_trip`; a ``None`` reference or mask stays ``None``. An unknown
        ``files`` raises ``ValueError`` naming ``metrics.files``.
    """
    if check_files(files) == "png":
        return generated, reference, mask
    gen = jpeg_round_trip(generated, GENERATED_QUALITY)
    if reference is None or reference_is_jpeg:
        ref = reference
    else:
        ref = jpeg_round_trip(reference, REFERENCE_QUALITY)
    m = None if mask is None else jpeg_mask_round_trip(mask)
    return gen, ref, m
