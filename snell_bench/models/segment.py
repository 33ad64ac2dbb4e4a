"""Segmenting the supporting surface the prompt names, so that the object is placed on it.

A :class:`SurfaceSegmenter` turns the object-free image I⁻ and a phrase naming the surface
("wooden coffee table") into a bool mask of that surface;
:func:`~snell_bench.scene.placement.find_support_plane` then fits the support plane to the depth
inside the mask (``region=``). Backends: SAM 3 through transformers (:class:`Sam3Segmenter`), a
random-weight SAM 3 for tests (:class:`TinySam3Segmenter`, around
:func:`~snell_bench.models.tiny_segment.tiny_sam3`), and a mask file the user drew
(:class:`MaskFileSegmenter`).

Convention:
    - Input image: float ``(H, W, 3)`` sRGB in ``[0, 1]`` (that of
      :mod:`snell_bench.scene.image_source`); output: ``np.ndarray`` of dtype bool and shape
      ``(H, W)``, ``True`` on the surface. The segmenters never raise for a surface they cannot
      find: they return an empty mask, and :func:`surface_region` turns that into an error naming
      the phrase.
    - SAM 3 is prompted with the phrase as text (no boxes). By default (``instance="union"``,
      config key ``segment.instance``) the mask is the **union** of the instance masks whose score
      (``sigmoid(logit) * sigmoid(presence)``, transformers' ``post_process_instance_segmentation``)
      exceeds ``threshold``, binarised at ``mask_threshold`` after resizing to the input size. A
      union rather than the best instance: a surface is often seen in pieces (a floor between
      pieces of furniture), and where two different surfaces match the phrase, the placement's
      plane fit keeps the dominant plane of the region. ``"best"``: the highest-scoring instance;
      ``"first"``: the first instance above ``threshold`` in the model's query order (what the
      authors' ``utils/obj_placement.py`` takes: ``centers_2d[0]``; it is not the best one, SAM 3
      does not sort its queries) (:func:`pick_instance`).
    - A segmenter's mask may be a :class:`SurfaceMask`, which also carries the box of the chosen
      instance(s) (SAM 3's predicted box, ``x0, y0, x1, y1`` in pixels with the image's edges at 0
      and ``W``, ``H``; pixel ``i`` spans ``[i, i + 1]``); the placement's ``centre_ray`` anchor
      aims at its centre.
    - The image reaches SAM 3 quantised to 8 bits (as a photo would), through the processor's own
      resizing and normalisation.
    - Weights are never downloaded: ``from_pretrained(..., local_files_only=True)``; missing weights
      raise :class:`~snell_bench.models.errors.WeightsNotFoundError` naming the config key
      ``segment.path``. Mask-file problems name ``segment.mask``, devices ``segment.device``.
    - Every call runs under :func:`torch.inference_mode` with the model in eval mode, so the mask is
      a deterministic function of the image, the phrase and the weights (on the CPU).
    - transformers is imported only when a SAM 3 segmenter is built.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from snell_bench.utils.paths import data_path

from .errors import WeightsNotFoundError
from .tiny_segment import tiny_sam3

log = logging.getLogger(__name__)

__all__ = [
    "SAM3_ID",
    "MaskFileSegmenter",
    "Sam3Segmenter",
    "INSTANCE_CHOICES",
    "SurfaceMask",
    "SurfaceSegmenter",
    "TinySam3Segmenter",
    "pick_instance",
    "read_mask",
    "surface_region",
    "tiny_sam3",
]

#: The Hugging Face id of SAM 3 (gated: the licence must be accepted on the hub).
SAM3_ID = "facebook/sam3"
#: How the mask is made from SAM 3's instances (config key ``segment.instance``).
INSTANCE_CHOICES = ("union", "best", "first")


class SurfaceMask(np.ndarray):
    """A bool ``(H, W)`` surface mask with ``box``: the box of the instance(s) it came from
    (``x0, y0, x1, y1`` float64 in pixels, the image's edges at 0 and ``W``, ``H``), or ``None``.

    An ndarray in every other way (NumPy's documented way to add an attribute to an array);
    ``np.asarray`` drops the box.
    """

    box: np.ndarray | None

    def __new__(cls, mask: np.ndarray, box=None) -> SurfaceMask:
        obj = np.asarray(mask, dtype=bool).view(cls)
        obj.box = None if box is None else np.asarray(box, np.float64).reshape(4)
        return obj

    def __array_finalize__(self, obj) -> None:
        self.box = getattr(obj, "box", None)


def pick_instance(found: dict[str, np.ndarray], how: str, shape: tuple[int, int]) -> SurfaceMask:
    """The surface mask from instance masks (the output of :meth:`Sam3Segmenter.instances`).

    Args:
        found: ``{"masks": bool (N, H, W), "scores": (N,), "boxes": (N, 4), "query": int (N,)}``
            (``query``: each instance's position in the model's query order; optional for
            ``"union"`` and ``"best"``).
        how: ``"union"`` (every instance; the box spans their boxes), ``"best"`` (the highest
            score, the earliest query on ties) or ``"first"`` (the earliest query).
        shape: ``(H, W)``, for an empty result.

    Returns:
        The mask and its box; all ``False`` with ``box=None`` when ``N = 0``.

    Raises:
        ValueError: for an unknown ``how`` (naming ``segment.instance``).
    """
    if how not in INSTANCE_CHOICES:
        raise ValueError(f"segment.instance={how!r}: use one of {', '.join(INSTANCE_CHOICES)}")
    masks = np.asarray(found["masks"], bool)
    if len(masks) == 0:
        return SurfaceMask(np.zeros(shape, bool))
    boxes = np.asarray(found["boxes"], np.float64).reshape(-1, 4)
    if how == "union":
        box = np.concatenate([boxes[:, :2].min(axis=0), boxes[:, 2:].max(axis=0)])
        return SurfaceMask(masks.any(axis=0), box)
    query = np.asarray(found.get("query", np.arange(len(masks))), np.int64)
    scores = np.asarray(found["scores"], np.float64)
    # lexsort: the last key is the primary one
    i = int(np.lexsort((query, -scores))[0]) if how == "best" else int(np.argmin(query))
    return SurfaceMask(masks[i], boxes[i])


@runtime_checkable
class SurfaceSegmenter(Protocol):
    """Finds the supporting surface a phrase names in an image.

    Attributes:
        name: the backend's name (``sam3``, ``tiny_sam3``, ``mask``).
    """

    name: str

    def __call__(self, image: np.ndarray, phrase: str) -> np.ndarray:
        """The surface's mask.

        Args:
            image: float ``(H, W, 3)`` sRGB in ``[0, 1]``.
            phrase: what the surface is, e.g. ``"wooden coffee table"``.

        Returns:
            bool ``(H, W)``, ``True`` on the surface; all ``False`` when it is not found.
        """
        ...


def _check_image(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must be (H, W, 3) sRGB, got shape {image.shape}")
    if not np.issubdtype(image.dtype, np.floating):
        raise TypeError(f"image must be float sRGB in [0, 1], got dtype {image.dtype}")
    if not np.all(np.isfinite(image)):
        raise ValueError("image has NaN or infinite values")
    return image


def _check_phrase(phrase: str) -> str:
    if not isinstance(phrase, str) or not phrase.strip():
        raise ValueError(f"the surface phrase must be a non-empty string (e.g. 'wooden coffee table'), got {phrase!r}")
    return phrase.strip()


def surface_region(segmenter: SurfaceSegmenter, image: np.ndarray, phrase: str, instance: str = "union") -> np.ndarray:
    """Segment the surface and check the result: the ``region`` for
    :func:`~snell_bench.scene.placement.find_support_plane`.

    Args:
        segmenter: the backend.
        image: float ``(H, W, 3)`` sRGB in ``[0, 1]``.
        phrase: the surface's name.
        instance: for a segmenter with ``instances`` (SAM 3): which of them make the mask
            (:func:`pick_instance`; config key ``segment.instance``). Others (a mask file) ignore it.

    Returns:
        bool ``(H, W)``, not empty (a :class:`SurfaceMask` with its box when the segmenter gives one).

    Raises:
        ValueError: if the segmenter finds nothing (the message names the phrase and the config
            keys ``scene.surface``, ``segment.threshold`` and ``segment``), or returns a mask of
            the wrong shape.
        TypeError: if the segmenter returns a mask that is not boolean.
    """
    image = _check_image(image)
    if instance not in INSTANCE_CHOICES:
        raise ValueError(f"segment.instance={instance!r}: use one of {', '.join(INSTANCE_CHOICES)}")
    if instance != "union" and hasattr(segmenter, "instances"):
        raw = pick_instance(segmenter.instances(image, phrase), instance, image.shape[:2])
    else:  # the union: the segmenter's own mask
        raw = segmenter(image, phrase)
    mask = raw if isinstance(raw, SurfaceMask) else np.asarray(raw)
    name = getattr(segmenter, "name", type(segmenter).__name__)
    if mask.shape != image.shape[:2]:
        raise ValueError(f"segmenter {name!r} returned a mask of shape {mask.shape} for an image of {image.shape[:2]}")
    if mask.dtype != np.bool_:
        raise TypeError(f"segmenter {name!r} returned a mask of dtype {mask.dtype}, not bool")
    if not mask.any():
        raise ValueError(
            f"segmenter {name!r} found no {phrase!r} in the image: name the supporting surface as it is seen "
            "(config key scene.surface), lower segment.threshold, give a mask file (segment=mask segment.mask=PATH), "
            "or place the object without segmentation (segment=ransac)"
        )
    return mask


# ---------------------------------------------------------------------------- mask file
def read_mask(path: str | os.PathLike) -> np.ndarray:
    """A mask image as bool: a pixel is ``True`` where any colour channel is nonzero.

    Args:
        path: an image file Pillow reads (PNG: 1-bit, 8- or 16-bit grey, RGB, RGBA, palette).
            Transparency is ignored; palette images are read through their colours.

    Returns:
        bool ``(H, W)``.
    """
    from PIL import Image

    with Image.open(path) as im:
        if im.mode == "P":
            im = im.convert("RGBA")
        mode = im.mode
        arr = np.asarray(im)
    if arr.ndim == 3:
        if mode in ("LA", "RGBA", "PA", "La", "RGBa"):
            arr = arr[..., :-1]
        return np.any(arr != 0, axis=-1)
    return arr != 0


class MaskFileSegmenter:
    """The surface from a mask image the user drew (nonzero = surface); the phrase is ignored.

    Args:
        path: the mask file (config key ``segment.mask``), the size of the image it is used with
            (I⁻ as the pipeline uses it); relative paths: the working folder, else the installed package.

    Raises:
        ValueError: if ``path`` is not set.
        FileNotFoundError: if the file does not exist (both name ``segment.mask``).
    """

    name = "mask"

    def __init__(self, path: str | os.PathLike | None):
        if path is None or not str(path).strip():
            raise ValueError("segment=mask needs a mask file: set segment.mask=PATH (a PNG, nonzero = surface)")
        p = Path(data_path(Path(os.fspath(path)).expanduser(), "segment.mask", "mask image (PNG)"))
        self.path = p
        try:
            self.mask = read_mask(p)
        except OSError as err:
            raise ValueError(f"segment.mask={str(path)!r}: not an image Pillow can read ({err})") from err
        self.mask.setflags(write=False)

    def __call__(self, image: np.ndarray, phrase: str | None = None) -> np.ndarray:
        """The mask file's mask (a fresh copy).

        Args:
            image: float ``(H, W, 3)`` sRGB; only its size is used.
            phrase: ignored.

        Returns:
            bool ``(H, W)``.

        Raises:
            ValueError: if the mask's size is not the image's (naming ``segment.mask``).
        """
        h, w = _check_image(image).shape[:2]
        if self.mask.shape != (h, w):
            mh, mw = self.mask.shape
            raise ValueError(
                f"segment.mask={str(self.path)!r} is {mw}x{mh} pixels but the image is {w}x{h}: the mask must have "
                "the size of I⁻ as used (after its centre crop to a multiple of model.multiple)"
            )
        return self.mask.copy()


# ---------------------------------------------------------------------------- SAM 3
def _weights_help(what: str) -> str:
    return (
        f"SAM 3 weights not found: {what}. Set the config key segment.path to a local folder with the transformers "
        f"layout of {SAM3_ID} (config.json, model.safetensors, processor and tokenizer files), e.g. "
        f"`segment.path=/data/sam3`, or to a Hugging Face id already in the local cache. To populate the cache, on "
        f"a machine with internet: accept the licence at https://huggingface.co/{SAM3_ID}, run `hf auth login`, "
        f"then `hf download {SAM3_ID}`, and copy the cache (~/.cache/huggingface/hub, or $HF_HOME/hub) to this "
        "machine. Weights are never downloaded by snell_bench; segment=ransac places the object without them."
    )


def _load_sam3(path: str | os.PathLike):
    """``(Sam3Model, Sam3Processor)`` from a local folder or a cached hub id, never downloading."""
    from transformers import Sam3Model, Sam3Processor

    text = os.fspath(path)
    local = Path(text).expanduser()
    if local.exists() and not local.is_dir():
        raise WeightsNotFoundError(_weights_help(f"{text!r} is a file, not a folder"))
    if text.startswith((".", "/", "~")) and not local.is_dir():
        raise WeightsNotFoundError(_weights_help(f"no folder {text!r}"))
    source = str(local) if local.is_dir() else text
    try:
        processor = Sam3Processor.from_pretrained(source, local_files_only=True)
        model = Sam3Model.from_pretrained(source, local_files_only=True)
    except (OSError, ValueError) as err:  # missing files, not cached, not a valid id
        where = (
            f"the folder {source!r}" if local.is_dir() else f"{text!r} (not a folder; not in the Hugging Face cache)"
        )
        raise WeightsNotFoundError(_weights_help(f"{where}: {type(err).__name__}: {str(err)[:200]}")) from err
    return model, processor


def _resolve_device(device: Any):
    import torch

    from .devices import resolve_device

    if device is None or str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return resolve_device(
        device,
        unavailable=(
            f"segment.device={device!r} asks for CUDA, which is not available on this machine: set segment.device=cpu "
            "(SAM 3 runs on the CPU too, slowly) or segment.device=null (CUDA when available, else the CPU)"
        ),
    )


class Sam3Segmenter:
    """SAM 3 (transformers ``Sam3Model`` + ``Sam3Processor``), prompted with the surface phrase.

    Args:
        path: a local folder with the transformers layout, or a Hugging Face id found in the local
            cache (config key ``segment.path``; the authors use ``facebook/sam3``).
        device: ``"cpu"``, ``"cuda[:i]"``, or ``None`` / ``"auto"``: CUDA when available, else the
            CPU (config key ``segment.device``). The model runs in float32.
        threshold: the score an instance needs to count (config key ``segment.threshold``).
        mask_threshold: the mask probability above which a pixel belongs to an instance.

    Raises:
        WeightsNotFoundError: naming ``segment.path``, when the weights are not on this machine.
        DeviceNotAvailableError: naming ``segment.device``, when CUDA is asked for and missing.
    """

    name = "sam3"

    def __init__(
        self,
        path: str | os.PathLike = SAM3_ID,
        *,
        device: Any = "cpu",
        threshold: float = 0.5,
        mask_threshold: float = 0.5,
    ):
        if path is None or not str(path).strip():
            raise WeightsNotFoundError(_weights_help("segment.path is not set"))
        dev = _resolve_device(device)  # before loading: a missing GPU fails fast
        model, processor = _load_sam3(path)
        self.path = str(path)
        self._setup(model, processor, dev, threshold, mask_threshold)

    def _setup(self, model, processor, device, threshold: float, mask_threshold: float) -> None:
        if not 0.0 <= float(threshold) <= 1.0:
            raise ValueError(f"segment.threshold must be in [0, 1], got {threshold}")
        if not 0.0 <= float(mask_threshold) <= 1.0:
            raise ValueError(f"mask_threshold must be in [0, 1], got {mask_threshold}")
        self.device = device
        self.model = model.to(device).eval().requires_grad_(False)
        self.processor = processor
        self.threshold = float(threshold)
        self.mask_threshold = float(mask_threshold)

    def instances(self, image: np.ndarray, phrase: str) -> dict[str, np.ndarray]:
        """Every instance of the phrase that passes ``threshold``, at the input size.

        Args:
            image: float ``(H, W, 3)`` sRGB in ``[0, 1]``.
            phrase: what to segment.

        Returns:
            ``{"masks": bool (N, H, W), "scores": float32 (N,), "boxes": float32 (N, 4), "query":
            int64 (N,)}`` (boxes in pixels, ``x0, y0, x1, y1``; ``query``: the instance's rank in
            the model's query order among those kept), highest score first; ``N`` may be 0.
        """
        import torch

        image = _check_image(image)
        phrase = _check_phrase(phrase)
        h, w = image.shape[:2]
        pixels = np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)
        inputs = self.processor(images=pixels, text=phrase, return_tensors="pt").to(self.device)
        with torch.inference_mode():
            outputs = self.model(**inputs)
            result = self.processor.post_process_instance_segmentation(
                outputs, threshold=self.threshold, mask_threshold=self.mask_threshold, target_sizes=[(h, w)]
            )[0]
        scores = result["scores"].float().cpu().numpy()
        order = np.argsort(-scores, kind="stable")
        if len(scores) == 0:  # the post-processing leaves an empty set at the model's mask size
            masks = np.zeros((0, h, w), bool)
        else:
            masks = result["masks"].bool().cpu().numpy()[order]
        boxes = result["boxes"].float().cpu().numpy().reshape(-1, 4)[order]
        return {"masks": masks, "scores": scores[order], "boxes": boxes, "query": order.astype(np.int64)}

    def __call__(self, image: np.ndarray, phrase: str, instance: str = "union") -> SurfaceMask:
        """The phrase's instance masks, combined as ``instance`` says (:func:`pick_instance`).

        Args:
            image: float ``(H, W, 3)`` sRGB in ``[0, 1]``.
            phrase: the surface's name.
            instance: ``"union"`` (default), ``"best"`` or ``"first"``.

        Returns:
            bool ``(H, W)`` with the box of the chosen instance(s); all ``False`` when no instance
            passes ``threshold``.
        """
        found = self.instances(image, phrase)
        mask = pick_instance(found, instance, np.shape(image)[:2])
        log.info(
            "%s: %d instance(s) of %r (scores %s), %.1f%% of the image",
            self.name,
            len(found["scores"]),
            phrase,
            np.round(found["scores"], 3).tolist(),
            100.0 * mask.mean(),
        )
        return mask


class TinySam3Segmenter(Sam3Segmenter):
    """:class:`Sam3Segmenter` around :func:`tiny_sam3` (random weights: its masks mean nothing).

    Random weights give scores near 0.25 (both sigmoids near one half), so the default
    ``threshold=0.5`` finds nothing and ``threshold=0`` keeps every query.

    Args:
        seed: seeds the random weights.
        device: as :class:`Sam3Segmenter` (default the CPU).
        threshold: as :class:`Sam3Segmenter`.
        mask_threshold: as :class:`Sam3Segmenter`.
    """

    name = "tiny_sam3"

    def __init__(self, seed: int = 0, *, device: Any = "cpu", threshold: float = 0.5, mask_threshold: float = 0.5):
        model, processor = tiny_sam3(seed)
        self.path = None
        self.seed = int(seed)
        self._setup(model, processor, _resolve_device(device), threshold, mask_threshold)
