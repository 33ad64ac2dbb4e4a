"""The :class:`WarpSet`: every warp of one (scene, object) pair, its persistence and cache key
(conventions: :mod:`snell_bench.optics.warps`)."""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from snell_bench.config.materials import CLEAR
from snell_bench.imaging.equirect import PanoramaCamera
from snell_bench.optics.tracer import HitKind
from snell_bench.scene.camera import Camera
from snell_bench.scene.objects import GlassObject
from snell_bench.utils.io import atomic_write

__all__ = ["WarpSet", "warp_inputs_hash", "assemble", "WARPS_VERSION", "ARRAY_FIELDS", "PANO_FIELDS", "CHANNELS"]

#: Bump when the meaning or computation of any warp changes, or a field is added (invalidates
#: caches: the version is part of the cache key, and :meth:`WarpSet.load` refuses other versions).
#: 2: ``pano_refraction_frame`` (π⁻¹ over the whole frame). 3: π⁻¹ and π^-R valid only where the
#: panorama centre sees the ray's end. 4: ``path_length`` (the refracted path inside the object),
#: ``optical_depth`` and the object's absorption. 5: ``interface_transmission`` (the Fresnel
#: transmission of the refracted path's later interfaces).
WARPS_VERSION = 5
#: The version of the several-media tracer (:mod:`snell_bench.optics.media`), in the key of a nested
#: object's warps only: a change there leaves every one-material object's cached warps valid.
NESTED_TRACE_VERSION = 2

ARRAY_FIELDS = (
    "object_mask",
    "refraction",
    "refraction_valid",
    "refraction_kind",
    "bounces",
    "fresnel",
    "path_length",
    "optical_depth",
    "interface_transmission",
    "reflection",
    "reflection_valid",
    "pano_refraction",
    "pano_refraction_valid",
    "pano_refraction_frame",
    "pano_refraction_frame_valid",
    "pano_reflection",
    "pano_reflection_valid",
    "pano_to_persp",
    "pano_to_persp_valid",
    "pano_to_persp_object",
)

#: The arrays of a :class:`WarpSet` indexed by panorama pixels; every other one by image pixels.
PANO_FIELDS = ("pano_to_persp", "pano_to_persp_valid", "pano_to_persp_object")
#: The trailing (channel) dimension of the arrays that have one; the others are ``(H, W)`` or ``(Hp, Wp)``.
CHANNELS = {
    "refraction": 2,
    "optical_depth": 3,
    "reflection": 2,
    "pano_refraction": 2,
    "pano_refraction_frame": 2,
    "pano_reflection": 2,
    "pano_to_persp": 2,
}


@dataclass(eq=False)
class WarpSet:
    """All warps of one (scene, object) pair; see the module docstring for conventions.

    Examples:
        >>> import tempfile
        >>> from snell_bench.optics.warps import compute_warps
        >>> T = np.eye(4); T[:3, 3] = [0.0, -0.5, 3.0]  # the unit-diameter sphere centred at z = 3
        >>> obj = GlassObject.sphere(subdivisions=2).transformed(T)
        >>> ws = compute_warps(np.full((24, 32), 5.0), Camera.from_fov(32, 24, 60.0), obj, pano_height=8)
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     back = WarpSet.load(ws.save(Path(tmp) / "warps.npz"))
        >>> bool(np.array_equal(back.refraction, ws.refraction, equal_nan=True)), back.ior
        (True, 1.5)
        >>> ws.summary()["object_pixels"]
        68
    """

    camera: Camera
    pano: PanoramaCamera
    ior: float
    #: (H, W) bool: the pixel's camera ray hits the object before the background.
    object_mask: np.ndarray
    #: (H, W, 2) float32 π^R; identity outside the object, NaN where invalid.
    refraction: np.ndarray
    #: (H, W) bool: true outside the object; inside, the refracted ray ends on a background point
    #: that I⁻ observes (front side, or either side with ``back_faces``; in view, not hidden behind
    #: other background geometry).
    refraction_valid: np.ndarray
    #: (H, W) int8 :class:`HitKind` of the refracted ray's end (NONE outside the object).
    refraction_kind: np.ndarray
    #: (H, W) uint8 surface interactions along the refracted path.
    bounces: np.ndarray
    #: (H, W) float32 unpolarised Fresnel reflectance at the first surface (0 outside the object).
    fresnel: np.ndarray
    #: (H, W, 2) float32 I⁻ pixel seen by the first-bounce mirror ray, NaN where invalid.
    reflection: np.ndarray
    reflection_valid: np.ndarray
    #: (H, W, 2) float32 π⁻¹: panorama pixel of the refracted ray (object pixels), NaN elsewhere and
    #: where the panorama centre does not see the ray's end (:mod:`~snell_bench.optics.occlusion`).
    pano_refraction: np.ndarray
    pano_refraction_valid: np.ndarray
    #: (H, W, 2) float32 π⁻¹ over the whole frame: ``pano_refraction`` on object pixels; elsewhere
    #: the panorama pixel that sees the background point the pixel shows, NaN where the pixel has
    #: no depth or the point is hidden from the panorama centre (re-cast through the glass-free
    #: scene; :func:`~snell_bench.optics.warp_maps.pano_refraction_frame_warp`).
    pano_refraction_frame: np.ndarray
    #: (H, W) bool: ``pano_refraction_frame`` is finite.
    pano_refraction_frame_valid: np.ndarray
    #: (H, W, 2) float32 π^-R: panorama pixel of the mirror ray (object pixels), NaN elsewhere and
    #: where the panorama centre does not see its end (with parallax; else of its direction).
    pano_reflection: np.ndarray
    pano_reflection_valid: np.ndarray
    #: (Hp, Wp, 2) float32 π: perspective pixel seen by each panorama pixel, NaN where invalid.
    pano_to_persp: np.ndarray
    #: (Hp, Wp) bool: the panorama ray ends on a background point observed in I⁻.
    pano_to_persp_valid: np.ndarray
    #: (Hp, Wp) bool: valid, but the perspective pixel shows the glass object (the image *with*
    #: the object does not show that point there; I⁻ does).
    pano_to_persp_object: np.ndarray
    #: (H, W) float32 length of the refracted path inside the object, over its internal reflections
    #: (scene units, metres; 0 outside the object; zeros when not given).
    path_length: np.ndarray | None = None
    #: (H, W, 3) float32 the refracted path's length in each medium times the medium's absorption σ
    #: (linear R, G, B; 0 outside the object and for clear glass; zeros when not given).
    optical_depth: np.ndarray | None = None
    #: (H, W) float32 the product of ``1 - R`` over the interfaces the refracted path crosses after
    #: the first (``R`` each one's Fresnel reflectance; total internal reflections keep everything):
    #: the share of the refracted light that stays on that path, which the paper's combination
    #: leaves out (1 outside the object; ones when not given).
    interface_transmission: np.ndarray | None = None
    input_hash: str = ""
    options: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    #: σ of the object's (outer) material per metre (linear R, G, B; ``(0, 0, 0)``: clear).
    absorption: tuple = CLEAR

    def __post_init__(self) -> None:
        if self.path_length is None:
            self.path_length = np.zeros(self.fresnel.shape, np.float32)
        if self.optical_depth is None:
            self.optical_depth = np.zeros(self.fresnel.shape + (3,), np.float32)
        if self.interface_transmission is None:
            self.interface_transmission = np.ones(self.fresnel.shape, np.float32)

    def transmittance(self) -> np.ndarray:
        """``(H, W, 3)`` float32 Beer–Lambert transmittance ``exp(-optical_depth)`` of the refracted
        path, ``exp(-σ L)`` in one medium (linear RGB; 1 outside the object and for clear glass)."""
        return np.exp(-self.optical_depth.astype(np.float64)).astype(np.float32)

    @property
    def absorbs(self) -> bool:
        """Whether any refracted path is absorbed (a tinted material, or a medium of a nested object)."""
        return bool((self.optical_depth > 0).any())

    # ------------------------------------------------------------------ aliases (paper notation)
    @property
    def pi_R(self) -> np.ndarray:
        """π^R, the refraction warp (:attr:`refraction`)."""
        return self.refraction

    @property
    def pi_inv(self) -> np.ndarray:
        """π⁻¹, the panorama warp of the refracted rays (:attr:`pano_refraction`)."""
        return self.pano_refraction

    @property
    def pi_minus_R(self) -> np.ndarray:
        """π^-R, the panorama warp of the mirror rays (:attr:`pano_reflection`)."""
        return self.pano_reflection

    @property
    def pi(self) -> np.ndarray:
        """π, the panorama-to-perspective warp (:attr:`pano_to_persp`)."""
        return self.pano_to_persp

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | os.PathLike) -> Path:
        """Write every array and the metadata to one ``.npz`` file, atomically.

        Args:
            path: the target file; missing parent folders are created.

        Returns:
            ``path`` as a :class:`~pathlib.Path`.
        """
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        meta = {
            "version": WARPS_VERSION,
            "camera": self.camera.to_dict(),
            "pano": self.pano.to_dict(),
            "ior": self.ior,
            "absorption": list(self.absorption),
            "input_hash": self.input_hash,
            "options": self.options,
            "stats": self.stats,
        }
        arrays = {k: getattr(self, k) for k in ARRAY_FIELDS}
        return atomic_write(path, lambda f: np.savez_compressed(f, meta=np.array(json.dumps(meta)), **arrays))

    @classmethod
    def load(cls, path: str | os.PathLike) -> WarpSet:
        """Read a file written by :meth:`save`.

        Args:
            path: an ``.npz`` file written by :meth:`save`.

        Returns:
            The :class:`WarpSet` it holds.

        Raises:
            ValueError: the file holds warps of another :data:`WARPS_VERSION`, or arrays whose shapes
                disagree with each other or its camera and panorama (:meth:`mismatch`).
        """
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            if meta.get("version") != WARPS_VERSION:
                raise ValueError(
                    f"{path} holds warps of version {meta.get('version')}, this code writes {WARPS_VERSION}; "
                    "delete the file to recompute it"
                )
            arrays = {k: z[k] for k in ARRAY_FIELDS}
        ws = cls(
            camera=Camera.from_dict(meta["camera"]),
            pano=PanoramaCamera.from_dict(meta["pano"]),
            ior=float(meta["ior"]),
            absorption=tuple(meta.get("absorption", CLEAR)),
            input_hash=meta["input_hash"],
            options=meta["options"],
            stats=meta["stats"],
            **arrays,
        )
        problem = ws.mismatch()
        if problem is not None:
            raise ValueError(f"{path} is inconsistent: {problem}; delete the file to recompute it")
        return ws

    def mismatch(self, input_hash: str | None = None, shape: tuple[int, int] | None = None) -> str | None:
        """Why these are not the warps a request expects (a cache entry checked against its key).

        Args:
            input_hash: the :func:`warp_inputs_hash` of the request (the cache key), or ``None``.
            shape: the ``(H, W)`` of the request's depth map, or ``None``.

        Returns:
            ``None`` when the warps fit; else what differs: the stored ``input_hash``, the camera's
            size against ``shape``, or an array whose shape does not follow from the camera (image
            arrays) or the panorama (:data:`PANO_FIELDS`) with its :data:`CHANNELS`.
        """
        if input_hash is not None and self.input_hash != input_hash:
            return f"input_hash {self.input_hash or '(none)'} is not {input_hash}"
        if shape is not None and tuple(shape) != self.camera.shape:
            return f"the camera is {self.camera.height}x{self.camera.width}, the depth map {tuple(shape)}"
        for name in ARRAY_FIELDS:
            base = self.pano.shape if name in PANO_FIELDS else self.camera.shape
            want = tuple(base) + ((CHANNELS[name],) if name in CHANNELS else ())
            got = getattr(self, name).shape
            if got != want:
                return f"{name} has shape {got}, expected {want}"
        return None

    def summary(self) -> dict:
        """Counts for logs and reports.

        Returns:
            A JSON-serialisable dict: object pixels, valid refraction in the object, the end kinds of
            the refracted rays, the most bounces, the mean Fresnel reflectance in the object and the
            valid fractions of π and of the whole-frame π⁻¹.
        """
        m = self.object_mask
        n = int(m.sum())
        kinds = {k.name.lower(): int((self.refraction_kind[m] == k).sum()) for k in HitKind if k != HitKind.NONE}
        return {
            "object_pixels": n,
            "refraction_valid_in_object": int(self.refraction_valid[m].sum()),
            "refraction_end": kinds,
            "max_bounces_used": int(self.bounces.max()) if n else 0,
            "mean_fresnel_in_object": float(self.fresnel[m].mean()) if n else float("nan"),
            "pano_to_persp_valid_fraction": float(self.pano_to_persp_valid.mean()),
            "pano_refraction_frame_valid_fraction": float(self.pano_refraction_frame_valid.mean()),
        }

    def __repr__(self) -> str:
        return f"WarpSet({self.camera!r}, pano={self.pano.height}x{self.pano.width}, ior={self.ior}, {self.summary()})"


def warp_inputs_hash(depth: np.ndarray, camera: Camera, obj: GlassObject, options: dict) -> str:
    """Content hash of everything a :class:`WarpSet` depends on (its cache key).

    Args:
        depth: the ``(H, W)`` depth map (hashed as float32).
        camera: the camera of ``depth``.
        obj: the placed glass object.
        options: the JSON-serialisable options of :func:`compute_warps` (key order does not matter).

    Returns:
        A 64-character hexadecimal SHA-256 digest.

    Examples:
        >>> cam = Camera.from_fov(8, 6, 60.0)
        >>> T = np.eye(4); T[:3, 3] = [0.0, -0.5, 3.0]  # the unit-diameter sphere centred at z = 3
        >>> obj = GlassObject.sphere(subdivisions=1).transformed(T)
        >>> a = warp_inputs_hash(np.ones((6, 8)), cam, obj, {"pano_height": 8, "eps": None})
        >>> len(a), a == warp_inputs_hash(np.ones((6, 8)), cam, obj, {"eps": None, "pano_height": 8})
        (64, True)
        >>> a == warp_inputs_hash(np.ones((6, 8)), cam, obj, {"pano_height": 16, "eps": None})
        False
    """
    h = hashlib.sha256()
    h.update(f"warps-v{WARPS_VERSION}".encode())
    d = np.ascontiguousarray(depth, dtype=np.float32)
    h.update(repr(d.shape).encode())
    h.update(d.tobytes())
    h.update(json.dumps(camera.to_dict(), sort_keys=True).encode())
    h.update(obj.content_hash().encode())
    if getattr(obj, "media", None) is not None:
        h.update(f"nested-v{NESTED_TRACE_VERSION}".encode())
    h.update(json.dumps(options, sort_keys=True, default=str).encode())
    return h.hexdigest()


def assemble(camera: Camera, pano: PanoramaCamera, ior: float, arrays: dict[str, np.ndarray], **meta) -> WarpSet:
    """A :class:`WarpSet` from flat per-pixel arrays.

    Args:
        camera: the perspective camera (``(H, W)`` arrays).
        pano: the panorama (``(Hp, Wp)`` arrays).
        ior: the object's index of refraction.
        arrays: every array of :data:`ARRAY_FIELDS`, flattened over its pixels (``(H * W, ...)`` or
            ``(Hp * Wp, ...)``).
        **meta: ``input_hash``, ``options`` and ``stats``.

    Returns:
        The :class:`WarpSet`, its arrays reshaped to ``(H, W, ...)`` and ``(Hp, Wp, ...)``.
    """
    shaped = {}
    for name in ARRAY_FIELDS:
        a = arrays[name]
        shaped[name] = a.reshape((pano.shape if name in PANO_FIELDS else camera.shape) + a.shape[1:])
    return WarpSet(camera=camera, pano=pano, ior=ior, **shaped, **meta)
