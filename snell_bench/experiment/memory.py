"""The memory guard: a cell's peak host memory, estimated from its config before any work.

:func:`check_memory` estimates the peak of each distinct cell of a run (:func:`estimate_memory`)
and compares it with the budget ``models.host_memory_gb`` (``null``: this machine's memory, or the
process's cgroup limit where lower: :func:`memory_budget`). Above the budget it stops the run
before any work with one line naming the estimate, the stage that peaks, the budget and the
settings that fix it, with values that fit (``scene.max_side=<n>`` for a photo, ``scene.width``
and ``scene.height`` otherwise, ``warps.pano_height`` where the panorama alone can make it fit, the
faces a simplified copy of a large mesh file may have);
above :data:`WARN_FRACTION` of the budget it warns. For a photo the same pass checks the photo
before any cell runs (:func:`~snell_bench.scene.image_source.inspect_photo`: its header, the
intrinsics, the depth file's bit depth, scale, value range and shape against the upright photo),
so a bad photo stops the run instead of failing its cells one by one.

Model (bytes): the peak of each stage is what the process holds while the stage runs, what earlier
stages keep included, times :data:`MARGIN`::

    peak(stage) = MARGIN * (base[stage] + a[stage] * P + b[stage] * Q + c[stage] * P0)

- ``P``: pixels of I⁻ as the cell uses it (a photo after ``scene.max_side`` and the block fit,
  from its header; other sources ``scene.width x scene.height``);
- ``Q``: pixels of the panorama, ``2 warps.pano_height x warps.pano_height``;
- ``P0``: pixels of the photo as read, before ``scene.max_side`` (a procedural scene: ``P x
  scene.supersample²``, the pixels it renders);
- ``base``: the process with its libraries (Python, PyTorch, Open3D, Hydra: 0.99 GB measured) and
  what a stage loads once (Mitsuba's LLVM back end: 0.2 GB);
- the object's mesh, in every stage: :data:`~snell_bench.experiment.memory_mesh.MESH_BYTES_PER_FACE`
  (2,400) times its faces, from the mesh file's header (:mod:`~snell_bench.experiment.memory_mesh`,
  measured there: a mesh of 5,242,880 faces is estimated at 14.5 GB).

===========  =======  =========  ===========  ======  =============================================
stage        base GB  a (B/px)   b (B/pano    c (B/   what grows
                                 px)          px)
===========  =======  =========  ===========  ======  =============================================
scene        1.0      100        0            30      the photo decoded and turned upright, the
                                                      depth in float64, placement's points
             1.1      250        0            30      a procedural scene rendered (supersampled)
warps        1.0      520        145          0       the depth mesh and Open3D's ray-casting
                                                      scene, the warps of the frame and panorama
reference    1.2      2650       30           0       Mitsuba's background: the depth mesh split
                                                      so each piece shows one texel (8 triangles
                                                      a pixel), its flaps and back side, their
                                                      BVHs
true_render  1.2      950        0            0       a procedural scene's true render
sampler      1.25     780        360          0       latents and images of the frame and the
                                                      panorama, pyramids, warped copies
metrics      1.35     550        220          0       the images, masks and warps scored
===========  =======  =========  ===========  ======  =============================================

What does not grow: ``reference.spp`` and the reference's window. At 1280 x 960 the reference
peaks at 3.73 GB with 8, 242 and 1058 samples per pixel and with an object twice as large (a 3.6x
larger window): Mitsuba's LLVM variant draws a pixel's samples inside one compiled kernel, so
samples cost time, not memory. The reference peaks because of the whole frame's geometry, which
is why the fix is the image size (``scene.max_side``), not ``reference.spp``.

Measured (``benchmarks/bench_memory.py``: one cell of ``+experiment=photo`` per run, Snellcaster,
the analytic stand-in, Mitsuba's ``llvm_ad_rgb``, the peak of each stage from the kernel's
high-water mark reset at the stage's start; the TUM frame resampled, its depth holes (19 %)
filled: holes leave out triangles and lower the reference's peak by up to a sixth), GB:

=============  ======  =====  =====  =========  =======  =======  ========  ==============
photo          pano_   scene  warps  reference  sampler  metrics  estimate  estimate/peak
               height
=============  ======  =====  =====  =========  =======  =======  ========  ==============
640 x 480      256     1.03   1.17   1.95       1.48     1.48     2.32      1.19
1280 x 960     256     1.14   1.65   4.29       2.25     2.04     5.13      1.20
1920 x 1440    256     1.32   2.37   8.40       3.33     2.76     9.81      1.17
2400 x 1800    256     1.43   3.13   12.25      4.25     3.46     14.55     1.19
2400 x 1800,   256     1.15   1.17   1.94       1.52     1.52     2.32      1.20
max_side 640
640 x 480      2048    1.03   2.29   1.89       4.35     2.44     5.19      1.19
=============  ======  =====  =====  =========  =======  =======  ========  ==============

Every measured stage lies below the model before :data:`MARGIN` (also with the depth's holes, with
8 to 1058 samples, ``warps.pano_height`` 256 to 2048, the procedural ``living_room`` at 640 x 360 and
1280 x 720, supersampled 1 and 2); the margin of 15 % covers images beyond the largest measured
(4.3 Mpx; a 4000 x 3000 photo is estimated at 38.0 GB) and other scene content. The estimate is
1.15 to 1.4 times the measured peak (1.4 with the TUM frame's holes).

Not counted: model weights (``models.memory_gb`` budgets those), the worker processes of
``grid.prefetch`` (each holds the inputs of its own group), and memory of other processes. With
Mitsuba on the GPU (``cuda_ad_rgb``) the reference's geometry lies in GPU memory: the estimate is
then an upper bound of the host's.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import replace
from typing import Any

from omegaconf import DictConfig, OmegaConf

from snell_bench.config.choices import Source
from snell_bench.config.errors import ConfigError
from snell_bench.experiment.memory_mesh import fitting_faces, object_faces
from snell_bench.experiment.memory_model import (
    COEFFICIENTS,
    MARGIN,
    PROCEDURAL_SCENE,
    STAGES,
    MemoryEstimate,
    _gb,
    stage_bytes,
)

log = logging.getLogger(__name__)

__all__ = [
    "COEFFICIENTS",
    "PROCEDURAL_SCENE",
    "MARGIN",
    "STAGES",
    "WARN_FRACTION",
    "HostMemoryError",
    "MemoryEstimate",
    "check_memory",
    "estimate_memory",
    "fitting_pano_height",
    "fitting_size",
    "machine_memory",
    "memory_budget",
    "stage_bytes",
]

#: Above this share of the budget a run starts with a warning.
WARN_FRACTION = 0.75
#: A cgroup limit at or above this is "no limit".
_NO_LIMIT = 1 << 60


class HostMemoryError(ConfigError):
    """A cell's estimated peak host memory exceeds the budget (one line: the estimate, the stage,
    the budget and the settings that fix it)."""

    def __init__(self, line: str, estimate: MemoryEstimate) -> None:
        super().__init__([line])
        self.estimate = estimate


# ---------------------------------------------------------------------------------------------- sizes
def _photo(cfg: DictConfig) -> dict | None:
    """:func:`~snell_bench.scene.image_source.inspect_photo` of the cell's photo (``None`` when the
    photo is not an image Pillow reads: its cell reports that; one over the pixel limit is refused
    here)."""
    from snell_bench.scene.image_source import inspect_photo
    from snell_bench.scene.photo_file import PhotoTooLargeError, read_photo_header
    from snell_bench.utils.paths import data_path

    sc = cfg.scene
    image = data_path(sc.image, "scene.image", "image file")
    try:
        read_photo_header(image)
    except PhotoTooLargeError:
        raise
    except ValueError as e:
        log.warning("memory guard: %s; not estimated", e)
        return None
    return inspect_photo(
        image,
        data_path(sc.depth, "scene.depth", "depth file") if sc.depth else None,
        depth_scale=sc.depth_scale,
        depth_kind=sc.depth_kind,
        intrinsics=None if sc.intrinsics is None else list(sc.intrinsics),
        fov_deg=sc.fov_deg,
        block=cfg.model.multiple,
        max_side=sc.max_side,
    )


def estimate_memory(cfg: DictConfig) -> MemoryEstimate | None:
    """A cell's peak host memory per stage, from its config alone: nothing computed, of a photo only
    its header and its depth file read (:func:`~snell_bench.scene.image_source.inspect_photo`).

    Args:
        cfg: a composed cell config.

    Returns:
        The :class:`MemoryEstimate`; ``None`` for a photo Pillow cannot open (its cell fails with
        the reason).

    Raises:
        ValueError, FileNotFoundError: a photo that :func:`~snell_bench.scene.image_source.load_frame`
            would refuse (see :func:`~snell_bench.scene.image_source.inspect_photo`).
    """
    sc = cfg.scene
    source = sc.source
    ref = cfg.reference
    faces, mesh, exact = object_faces(cfg.object)
    common = dict(
        faces=faces,
        mesh=mesh,
        faces_exact=exact,
        pano_height=cfg.warps.pano_height,
        source=source.value,
        scene=sc.name,
        reference=ref.enabled,
        true_render=ref.true_render and source is Source.procedural,
    )
    if source is Source.image:
        photo = _photo(cfg)
        if photo is None:
            return None
        w0, h0 = photo["original_size"]
        read = (h0, w0) if photo["exif_orientation"] in (5, 6, 7, 8) else (w0, h0)
        return MemoryEstimate(size=tuple(photo["size"]), read_size=read, photo=photo, **common)
    ss = sc.supersample if source is Source.procedural else 1
    return MemoryEstimate(size=(sc.width, sc.height), supersample=ss, **common)


# ---------------------------------------------------------------------------------------------- budget
def machine_memory() -> tuple[float, str]:
    """This machine's memory in bytes and where the figure comes from: psutil's total, lowered to
    the cgroup's memory limit where one is set (a container, a Slurm job)."""
    import psutil

    total, where = float(psutil.virtual_memory().total), "this machine's memory"
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            with open(path) as f:
                text = f.read().strip()
        except OSError:
            continue
        if text.isdigit() and int(text) < min(total, _NO_LIMIT):
            total, where = float(text), f"this process's memory limit, {path}"
    return total, where


def memory_budget(cfg: DictConfig) -> tuple[float, str]:
    """The budget in bytes and where it comes from: ``models.host_memory_gb`` (GB, 10^9 bytes) or
    :func:`machine_memory`."""
    gb = cfg.models.get("host_memory_gb")
    if gb is not None:
        return float(gb) * 1e9, f"models.host_memory_gb={float(gb):g}"
    total, where = machine_memory()
    return total, f"{where}, models.host_memory_gb=null"


# ---------------------------------------------------------------------------------------------- fixes
def fitting_size(est: MemoryEstimate, budget: float, block: int) -> tuple[int, int] | None:
    """The largest ``(width, height)`` of I⁻, of the estimate's aspect ratio and multiples of
    ``block``, whose peak fits ``budget`` at the estimate's panorama; ``None`` if not even one block
    does (a stage that does not shrink with the image, or the photo's reading, is too large).

    Args:
        est: the estimate.
        budget: bytes.
        block: ``model.multiple``.

    Returns:
        ``(width, height)`` or ``None``.
    """
    w, h = est.size

    def size_at(scale: float) -> tuple[int, int]:
        return tuple(max(block, int(n * scale) // block * block) for n in (w, h))

    def fits(scale: float) -> bool:
        return max(est.at(size_at(scale)).values()) <= budget

    lo, hi = block / max(w, h), 1.0
    if not fits(lo):
        return None
    if fits(hi):
        return est.size
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if fits(mid) else (lo, mid)
    return size_at(lo)


def fitting_pano_height(est: MemoryEstimate, budget: float) -> int | None:
    """The largest ``warps.pano_height``, the cell's halved until it fits ``budget`` at the
    estimate's image size (down to 64), or ``None``."""
    ph = est.pano_height
    while ph >= 64:
        if max(est.at(pano_height=ph).values()) <= budget:
            return ph
        ph //= 2
    return None


def _fixes(est: MemoryEstimate, budget: float, block: int) -> list[str]:
    """What brings ``est`` within ``budget``, with values that fit: each a phrase ("set k=v"; for a
    mesh file, the faces a simplified copy may have)."""
    fixes = []
    size = fitting_size(est, budget, block)
    if size is not None and size != est.size:
        if est.read_size is not None:
            fixes.append(f"set scene.max_side={max(size)}")
        else:
            fixes.append(f"set scene.width={size[0]} scene.height={size[1]}")
    elif size is None and est.read_size is not None:
        # the photo alone, read whole before it is resized, is too large, and a smaller file fits
        small = replace(est, size=(block, block), read_size=(block, block))
        if max(small.stages.values()) <= budget:
            w, h = est.read_size
            fixes.append(f"save a smaller copy of the photo (it is read whole, {w}x{h}, before scene.max_side applies)")
    ph = fitting_pano_height(est, budget)
    if ph is not None and ph < est.pano_height:
        fixes.append(f"set warps.pano_height={ph}")
    most = fitting_faces(est.peak_bytes - est.mesh_bytes, budget, est.mesh_bytes / max(est.faces, 1))
    if est.mesh.startswith("object.path=") and most is not None and most < est.faces:
        fixes.append(f"use a simplified copy of the mesh with at most {most:,} faces ({est.mesh})")
    return fixes


# ---------------------------------------------------------------------------------------------- the guard
#: The keys an estimate reads: cells that agree on them are estimated once.
_KEYS = (
    "scene.source",
    "scene.name",
    "scene.image",
    "scene.depth",
    "scene.depth_scale",
    "scene.depth_kind",
    "scene.intrinsics",
    "scene.fov_deg",
    "scene.max_side",
    "scene.width",
    "scene.height",
    "scene.supersample",
    "object.factory",
    "object.path",
    "model.multiple",
    "warps.pano_height",
    "reference.enabled",
    "reference.true_render",
    "models.host_memory_gb",
)


def _key(cfg: DictConfig) -> tuple:
    return tuple(repr(OmegaConf.select(cfg, k, default=None)) for k in _KEYS)


def check_memory(cells_or_cfgs: Iterable[Any], *, warn_fraction: float = WARN_FRACTION) -> list[MemoryEstimate]:
    """Estimate each distinct cell's peak host memory and stop a run that will not fit, before any
    work (see the module docstring).

    Args:
        cells_or_cfgs: composed cell configs, or :class:`~snell_bench.experiment.cells.Cell` s (their
            ``config``); configs that agree on the keys an estimate reads are estimated once.
        warn_fraction: above this share of the budget, a warning.

    Returns:
        The estimates, one per distinct config (photos Pillow cannot open left out: their cells fail
        with the reason).

    Raises:
        HostMemoryError: an estimate above the budget; the one-line message names the estimate,
            the stage that peaks, the image, the object's mesh where it takes 0.1 GB or more, the
            budget and the settings that fix it, with values that fit.
        ValueError, FileNotFoundError: a photo that would be refused when loaded (its pixels over
            :data:`~snell_bench.scene.photo_file.MAX_PHOTO_PIXELS`; its depth's bit depth, scale,
            values or shape; its intrinsics), so that no cell runs first.
    """
    seen: dict[tuple, MemoryEstimate | None] = {}
    for item in cells_or_cfgs:
        cfg = getattr(item, "config", item)
        key = _key(cfg)
        if key in seen:
            continue
        est = seen[key] = estimate_memory(cfg)
        if est is None:
            continue
        budget, where = memory_budget(cfg)
        peak = est.peak_bytes
        if peak > budget:
            fixes = _fixes(est, budget, cfg.model.multiple)
            fix = "".join(f"{f} or " for f in fixes)
            raise HostMemoryError(
                f"{est.describe()}, more than the budget of {_gb(budget)} ({where}): {fix}raise "
                "models.host_memory_gb if the machine has that much memory for one cell",
                est,
            )
        if peak > warn_fraction * budget:
            log.warning("%s: %.0f %% of the budget of %s (%s)", est.describe(), 100 * peak / budget, _gb(budget), where)
        else:
            log.info("%s; budget %s (%s)", est.describe(), _gb(budget), where)
    return [e for e in seen.values() if e is not None]
