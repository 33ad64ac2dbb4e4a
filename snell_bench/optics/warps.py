"""Pixel-to-pixel warps through a glass object: the :class:`WarpSet` and :func:`compute_warps`.

Convention
----------
Every warp is a *backward* map: for each destination pixel it stores the source pixel
coordinate ``(x, y)`` (float32, integer values at pixel centres), NaN where invalid, plus a bool
mask. Perspective arrays are ``(H, W, ...)``, panorama arrays ``(Hp, 2 Hp, ...)``. The panorama
is an equirectangular image centred at the object (:class:`~snell_bench.imaging.PanoramaCamera`,
gravity-aligned with the scene's up direction, its centre column looking along the camera's
horizontal forward direction).

=====================  ==========  ==========================================================
field                  paper       meaning
=====================  ==========  ==========================================================
``refraction``         π^R         object pixel -> pixel of I⁻ the refracted ray ends on;
                                   identity outside the object
``pano_refraction``    π⁻¹         object pixel -> panorama pixel of the refracted ray's end
``pano_reflection``    π^-R        object pixel -> panorama pixel of the first-bounce mirror
                                   ray's end
``pano_to_persp``      π           panorama pixel -> perspective pixel (straight rays from the
                                   panorama centre, through the glass-free scene)
``reflection``         —           object pixel -> pixel of I⁻ the mirror ray ends on
=====================  ==========  ==========================================================

Panorama coordinates of a ray are those of *its end point* seen from the panorama centre (exact
parallax for the scene's geometry); only a ray that hits nothing uses its direction.

Far background at infinity (``infinity_tolerance_px``): a background pixel whose depth is so large
that replacing its surface by a surface at infinity moves *any* warp that could land on it by less
than the tolerance (bound of :func:`far_background_mask`) leaves the mesh; a ray that leaves the
scene's geometry (the bounding box or nothing) then sees the pixel its *direction* projects to, if
that pixel is such a far one. Rays need no intersection with the far surface, and estimated depth
of the sky or the horizon (often unreliable) no longer matters.

Region of interest (``roi``): only pixels inside the projected bounding box of the object's
vertices can see it (perspective projection maps the convex hull into the convex hull of the
projected vertices), so primary rays are cast there only; the warps are identical.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from snell_bench.imaging.equirect import PanoramaCamera
from snell_bench.optics.tracer import HitKind, SceneTracer
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import build_background
from snell_bench.scene.objects import GlassObject

log = logging.getLogger(__name__)

__all__ = ["WarpSet", "compute_warps", "warp_inputs_hash", "far_background_mask", "object_pixel_box", "WARPS_VERSION"]

#: Bump when the meaning or computation of any warp changes (invalidates caches).
WARPS_VERSION = 1

_ARRAYS = (
    "object_mask",
    "refraction",
    "refraction_valid",
    "refraction_kind",
    "bounces",
    "fresnel",
    "reflection",
    "reflection_valid",
    "pano_refraction",
    "pano_refraction_valid",
    "pano_reflection",
    "pano_reflection_valid",
    "pano_to_persp",
    "pano_to_persp_valid",
    "pano_to_persp_object",
)


@dataclass(eq=False)
class WarpSet:
    """All warps of one (scene, object) pair; see the module docstring for conventions."""

    camera: Camera
    pano: PanoramaCamera
    ior: float
    #: (H, W) bool: the pixel's camera ray hits the object before the background.
    object_mask: np.ndarray
    #: (H, W, 2) float32 π^R; identity outside the object, NaN where invalid.
    refraction: np.ndarray
    #: (H, W) bool: true outside the object; inside, the refracted ray ends on a background point
    #: that I⁻ observes (front side, in view, not hidden behind other background geometry).
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
    #: (H, W, 2) float32 π⁻¹: panorama pixel of the refracted ray (object pixels), NaN elsewhere.
    pano_refraction: np.ndarray
    pano_refraction_valid: np.ndarray
    #: (H, W, 2) float32 π^-R: panorama pixel of the mirror ray (object pixels), NaN elsewhere.
    pano_reflection: np.ndarray
    pano_reflection_valid: np.ndarray
    #: (Hp, Wp, 2) float32 π: perspective pixel seen by each panorama pixel, NaN where invalid.
    pano_to_persp: np.ndarray
    #: (Hp, Wp) bool: the panorama ray ends on a background point observed in I⁻.
    pano_to_persp_valid: np.ndarray
    #: (Hp, Wp) bool: valid, but the perspective pixel shows the glass object (the image *with*
    #: the object does not show that point there; I⁻ does).
    pano_to_persp_object: np.ndarray
    input_hash: str = ""
    options: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)

    # ------------------------------------------------------------------ aliases (paper notation)
    @property
    def pi_R(self) -> np.ndarray:
        return self.refraction

    @property
    def pi_inv(self) -> np.ndarray:
        return self.pano_refraction

    @property
    def pi_minus_R(self) -> np.ndarray:
        return self.pano_reflection

    @property
    def pi(self) -> np.ndarray:
        return self.pano_to_persp

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | os.PathLike) -> Path:
        """Write every array and the metadata to one ``.npz`` file (atomically)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        meta = {
            "version": WARPS_VERSION,
            "camera": self.camera.to_dict(),
            "pano": self.pano.to_dict(),
            "ior": self.ior,
            "input_hash": self.input_hash,
            "options": self.options,
            "stats": self.stats,
        }
        arrays = {k: getattr(self, k) for k in _ARRAYS}
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez_compressed(f, meta=np.array(json.dumps(meta)), **arrays)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> "WarpSet":
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            if meta.get("version") != WARPS_VERSION:
                raise ValueError(
                    f"{path} holds warps of version {meta.get('version')}, this code writes {WARPS_VERSION}; "
                    "delete the file to recompute it"
                )
            arrays = {k: z[k] for k in _ARRAYS}
        return cls(
            camera=Camera.from_dict(meta["camera"]),
            pano=PanoramaCamera.from_dict(meta["pano"]),
            ior=float(meta["ior"]),
            input_hash=meta["input_hash"],
            options=meta["options"],
            stats=meta["stats"],
            **arrays,
        )

    def summary(self) -> dict:
        """Counts for logs and reports."""
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
        }

    def __repr__(self) -> str:
        return f"WarpSet({self.camera!r}, pano={self.pano.height}x{self.pano.width}, ior={self.ior}, {self.summary()})"


def warp_inputs_hash(depth: np.ndarray, camera: Camera, obj: GlassObject, options: dict) -> str:
    """Content hash of everything a :class:`WarpSet` depends on (for caching)."""
    h = hashlib.sha256()
    h.update(f"warps-v{WARPS_VERSION}".encode())
    d = np.ascontiguousarray(depth, dtype=np.float32)
    h.update(repr(d.shape).encode())
    h.update(d.tobytes())
    h.update(json.dumps(camera.to_dict(), sort_keys=True).encode())
    h.update(obj.content_hash().encode())
    h.update(json.dumps(options, sort_keys=True, default=str).encode())
    return h.hexdigest()


def _check_object_in_view(obj: GlassObject, camera: Camera) -> None:
    if not obj.placed:
        raise ValueError(
            f"{obj.name}: the object is in its canonical frame, not in camera coordinates; place it first "
            "(snell_bench.scene.place_object) or build it with GlassObject.from_mesh(...) from camera-frame vertices"
        )
    v = obj.vertices
    zmin = float(v[:, 2].min())
    if zmin <= 0:
        where = "behind the camera" if float(v[:, 2].max()) <= 0 else "crossing the camera plane (z <= 0)"
        raise ValueError(
            f"{obj.name}: the object is {where} (min z = {zmin:.4g}); move it in front of the camera (z > 0)"
        )
    pix, _ = camera.project(v)
    lo, hi = pix.min(axis=0), pix.max(axis=0)
    if hi[0] < -0.5 or lo[0] > camera.width - 0.5 or hi[1] < -0.5 or lo[1] > camera.height - 0.5:
        raise ValueError(
            f"{obj.name}: the object is outside the view (its projection spans x in [{lo[0]:.1f}, {hi[0]:.1f}], "
            f"y in [{lo[1]:.1f}, {hi[1]:.1f}], the image is {camera.width}x{camera.height}); move it into the frustum"
        )


def object_pixel_box(obj: GlassObject, camera: Camera) -> tuple[int, int, int, int]:
    """``(x0, y0, x1, y1)``, inclusive pixel-centre bounds of the object's projection, clipped to the
    image (every pixel whose camera ray can hit the object lies inside)."""
    pix, _ = camera.project(obj.vertices)
    lo, hi = np.floor(pix.min(axis=0)), np.ceil(pix.max(axis=0))
    x0, y0 = int(max(lo[0], 0)), int(max(lo[1], 0))
    x1, y1 = int(min(hi[0], camera.width - 1)), int(min(hi[1], camera.height - 1))
    return x0, y0, x1, y1


def far_background_mask(
    depth: np.ndarray,
    camera: Camera,
    center: np.ndarray,
    radius: float,
    tolerance_px: float,
    pano_height: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Background pixels that may be treated as at infinity, and the bound behind the decision.

    A ray leaving a point ``p`` of the object's bounding ball ``|p - c| <= r`` with direction ``d``
    ends on the background at ``q = p + t d``; at infinity it would be seen at the pixel ``u`` that
    ``d`` projects to. With ``u'`` the normalised coordinates of ``u`` (``d ∝ (u'_x, u'_y, 1)``), the
    exact pixel is ``u + f (p_xy - p_z u') / q_z``, so the error is at most
    ``f (|c_xy - c_z u'| + r sqrt(1 + |u'|²)) / q_z`` (``f`` the larger focal length). ``q_z`` is
    bounded below by the smallest depth around the pixel (3 x 3). The panorama's straight rays
    start at ``c`` (covered by the same bound); its angular coordinates of a refracted ray move by at
    most ``r / (|q| - |c|)`` radians, ``pano_height / π`` pixels per radian.

    Returns ``(far (H, W) bool, bound_px (H, W) float64)``: ``far`` where the bound is below
    ``tolerance_px`` (invalid depth is never far; it stays a hole).
    """
    if not (tolerance_px > 0) or not np.isfinite(tolerance_px):
        raise ValueError(
            f"infinity_tolerance_px must be a positive number of pixels, got {tolerance_px!r}; "
            "use null to keep the exact geometry"
        )
    depth = np.asarray(depth, np.float64)
    H, W = depth.shape
    valid = np.isfinite(depth) & (depth > 0)
    z = np.where(valid, depth, np.inf)
    zp = np.pad(z, 1, mode="edge")
    zmin = np.min([zp[dy : dy + H, dx : dx + W] for dy in range(3) for dx in range(3)], axis=0)
    c = np.asarray(center, np.float64)
    un = camera.pixel_rays(normalize=False)[..., :2]  # (H, W, 2): u'
    f = float(max(camera.K[0, 0], camera.K[1, 1]))
    lateral = np.linalg.norm(c[:2] - c[2] * un, axis=-1) + radius * np.sqrt(1.0 + (un**2).sum(-1))
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = f * lateral / zmin
        if pano_height is not None:
            dist = zmin * np.sqrt(1.0 + (un**2).sum(-1)) - float(np.linalg.norm(c))
            bound = np.maximum(bound, np.where(dist > 0, pano_height / np.pi * radius / dist, np.inf))
    bound = np.where(valid & np.isfinite(zmin), bound, np.inf)
    return valid & (bound < tolerance_px), bound


def compute_warps(
    depth: np.ndarray,
    camera: Camera,
    obj: GlassObject,
    pano_height: int = 1024,
    *,
    max_bounces: int = 8,
    normals: str = "interpolated",
    edge_threshold: float = 0.05,
    up=None,
    eps: float | None = None,
    cache_dir: str | os.PathLike | None = None,
    verify_visibility: bool = False,
    roi: bool = True,
    infinity_tolerance_px: float | None = None,
) -> WarpSet:
    """Trace the camera's rays through ``obj`` placed in the scene of ``depth`` and return every warp.

    Parameters
    ----------
    depth: ``(H, W)`` z-depth of the object-free image I⁻ (NaN, inf or <= 0 where unknown).
    camera: the camera of I⁻ (its size must match ``depth``).
    obj: a glass object in camera coordinates (placed or built with ``GlassObject.from_mesh``).
    pano_height: height of the 360° panorama (its width is twice that).
    max_bounces: surface interactions per refracted path before it is marked trapped.
    normals: ``"interpolated"`` (smooth shading normals, creased at sharp edges) or ``"face"``.
    edge_threshold: relative depth jump at which the background mesh is cut.
    up: the scene's up direction in camera coordinates; default ``obj.up``, else ``(0, -1, 0)``.
    eps: self-intersection offset (default: scaled to the object, see :mod:`~snell_bench.optics.tracer`).
    cache_dir: if given, warps are loaded from / saved to ``<cache_dir>/<input hash>.npz``.
    verify_visibility: also cast a camera ray to every background point a warp lands on (redundant
        for depth-map backgrounds, see ``_self_warp``; for checking).
    roi: cast primary rays only inside the object's projected bounding box (same result, faster).
    infinity_tolerance_px: treat background that moves no warp by more than this many pixels as at
        infinity (see the module docs); ``None`` keeps the exact geometry.
    """
    depth = np.asarray(depth)
    if depth.ndim != 2 or depth.shape != camera.shape:
        raise ValueError(
            f"depth has shape {depth.shape} but the camera is {camera.height}x{camera.width}; "
            "pass a depth map of the camera's (height, width)"
        )
    if int(pano_height) != pano_height or pano_height < 2:
        raise ValueError(f"pano_height must be an integer >= 2, got {pano_height!r}")
    pano_height = int(pano_height)
    up_vec = np.asarray(up if up is not None else (obj.up if obj.up is not None else (0.0, -1.0, 0.0)), np.float64)
    if up_vec.shape != (3,) or not np.all(np.isfinite(up_vec)) or np.linalg.norm(up_vec) == 0:
        raise ValueError(f"up must be a non-zero 3-vector, got {up!r}")
    up_vec = up_vec / np.linalg.norm(up_vec)
    options = {
        "pano_height": pano_height,
        "max_bounces": int(max_bounces),
        "normals": normals,
        "edge_threshold": float(edge_threshold),
        "up": up_vec.round(12).tolist(),
        "eps": eps,
        "verify_visibility": bool(verify_visibility),
    }
    if infinity_tolerance_px is not None:  # keeps the hashes of exact warps unchanged
        options["infinity_tolerance_px"] = float(infinity_tolerance_px)
    key = warp_inputs_hash(depth, camera, obj, options)
    cache_path = Path(cache_dir) / f"{key}.npz" if cache_dir is not None else None
    if cache_path is not None and cache_path.is_file():
        log.info("warps: loading cached %s", cache_path)
        return WarpSet.load(cache_path)

    _check_object_in_view(obj, camera)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    lo, hi = obj.mesh.bounds
    far = None
    far_stats: dict = {}
    if infinity_tolerance_px is not None:
        radius = float(np.linalg.norm(obj.vertices - obj.center, axis=1).max())
        far, bound = far_background_mask(depth, camera, obj.center, radius, float(infinity_tolerance_px), pano_height)
        far_stats = {
            "tolerance_px": float(infinity_tolerance_px),
            "far_fraction": float(far.mean()),
            "max_bound_px_of_far": float(bound[far].max()) if far.any() else None,
            "nearest_far_depth": float(np.asarray(depth)[far].min()) if far.any() else None,
        }
    background = build_background(depth, camera, edge_threshold, extra_points=np.stack([lo, hi]), exclude=far)
    tracer = SceneTracer(background, obj, max_bounces=max_bounces, normals=normals, eps=eps)
    at_inf = _AtInfinity(camera, far) if far is not None and far.any() else None
    timings["build"] = time.perf_counter() - t0

    H, W = camera.shape
    t0 = time.perf_counter()
    # ---- 1. primary rays: which pixels see the object (before the background)
    if roi:
        x0, y0, x1, y1 = object_pixel_box(obj, camera)
        yy, xx = np.mgrid[y0 : y1 + 1, x0 : x1 + 1]
        sel = (yy * W + xx).reshape(-1)
        rays_sel = camera.pixel_rays(np.stack([xx, yy], -1).reshape(-1, 2).astype(np.float64))
    else:
        sel = np.arange(H * W)
        rays_sel = camera.pixel_rays().reshape(-1, 3)
    t_obj = tracer.cast_camera_object(rays_sel)
    hit = np.flatnonzero(np.isfinite(t_obj))
    if len(hit):
        t_bg = tracer.cast_background(np.zeros((len(hit), 3)), rays_sel[hit]).t
        hit = hit[t_obj[hit] < t_bg]
    cand = sel[hit]
    rays_cand = rays_sel[hit]
    mask = np.zeros(H * W, bool)
    mask[cand] = True
    if not len(cand):
        log.warning("%s covers no pixel centre of the %dx%d image: the object mask is empty", obj.name, W, H)
    timings["primary"] = time.perf_counter() - t0

    # ---- 2. refraction through the object (object pixels only)
    t0 = time.perf_counter()
    tr = tracer.trace(np.zeros((len(cand), 3)), rays_cand)
    if at_inf is not None:
        at_inf.resolve(tr.kind, tr.point, tr.direction, tr.on_box)
    timings["refraction"] = time.perf_counter() - t0

    grid = camera.pixel_grid().reshape(-1, 2)
    t0 = time.perf_counter()
    refraction = grid.astype(np.float32)
    refraction_valid = np.ones(H * W, bool)
    src, ok = _self_warp(camera, tracer, tr.point, tr.kind, verify_visibility)
    refraction[cand] = np.where(ok[:, None], src, np.nan)
    refraction_valid[cand] = ok
    kind = np.zeros(H * W, np.int8)
    kind[cand] = tr.kind
    bounces = np.zeros(H * W, np.uint8)
    bounces[cand] = np.minimum(tr.bounces, 255)
    fres = np.zeros(H * W, np.float32)
    fres[cand] = tr.fresnel

    # ---- 3. first-bounce reflection
    refl = tracer.trace_reflection(tr)
    if at_inf is not None:
        at_inf.resolve(refl.kind, refl.point, tr.reflected, refl.on_box)
    src_r, ok_r = _self_warp(camera, tracer, refl.point, refl.kind, verify_visibility)
    reflection = np.full((H * W, 2), np.nan, np.float32)
    reflection_valid = np.zeros(H * W, bool)
    reflection[cand] = np.where(ok_r[:, None], src_r, np.nan)
    reflection_valid[cand] = ok_r
    timings["reflection"] = time.perf_counter() - t0

    # ---- 4. panorama warps
    t0 = time.perf_counter()
    pano = PanoramaCamera.level(obj.center, up_vec, (0.0, 0.0, 1.0), pano_height)
    exited = np.isin(tr.kind, (HitKind.OBSERVED, HitKind.UNOBSERVED, HitKind.ESCAPED))
    pr = _pano_coords(pano, tr.point, tr.direction)
    pano_refraction = np.full((H * W, 2), np.nan, np.float32)
    pano_refraction[cand] = np.where(exited[:, None], pr, np.nan)
    pano_refraction_valid = np.zeros(H * W, bool)
    pano_refraction_valid[cand] = exited & np.isfinite(pr).all(axis=1)
    rr = _pano_coords(pano, refl.point, tr.reflected)
    pano_reflection = np.full((H * W, 2), np.nan, np.float32)
    pano_reflection[cand] = rr
    pano_reflection_valid = np.zeros(H * W, bool)
    pano_reflection_valid[cand] = np.isfinite(rr).all(axis=1)

    pdirs = pano.directions().reshape(-1, 3)
    ph = tracer.cast_background(np.broadcast_to(pano.center, pdirs.shape), pdirs)
    if at_inf is not None:
        at_inf.resolve(ph.kind, ph.point, pdirs, ph.on_box)
    pix, pok = _self_warp(camera, tracer, ph.point, ph.kind, verify_visibility)
    pano_to_persp = np.where(pok[:, None], pix, np.nan).astype(np.float32)
    near = np.rint(np.where(pok[:, None], pix, 0)).astype(np.int64)
    near[:, 0] = near[:, 0].clip(0, W - 1)
    near[:, 1] = near[:, 1].clip(0, H - 1)
    pano_to_persp_object = pok & mask[near[:, 1] * W + near[:, 0]]
    timings["panorama"] = time.perf_counter() - t0

    Hp, Wp = pano.shape
    ws = WarpSet(
        camera=camera,
        pano=pano,
        ior=obj.ior,
        object_mask=mask.reshape(H, W),
        refraction=refraction.reshape(H, W, 2),
        refraction_valid=refraction_valid.reshape(H, W),
        refraction_kind=kind.reshape(H, W),
        bounces=bounces.reshape(H, W),
        fresnel=fres.reshape(H, W),
        reflection=reflection.reshape(H, W, 2),
        reflection_valid=reflection_valid.reshape(H, W),
        pano_refraction=pano_refraction.reshape(H, W, 2),
        pano_refraction_valid=pano_refraction_valid.reshape(H, W),
        pano_reflection=pano_reflection.reshape(H, W, 2),
        pano_reflection_valid=pano_reflection_valid.reshape(H, W),
        pano_to_persp=pano_to_persp.reshape(Hp, Wp, 2),
        pano_to_persp_valid=pok.reshape(Hp, Wp),
        pano_to_persp_object=pano_to_persp_object.reshape(Hp, Wp),
        input_hash=key,
        options=options,
        stats={
            "timings_s": {k: round(v, 4) for k, v in timings.items()},
            "invalid_depth_pixels": background.invalid_pixels,
            "cut_triangles": background.cut_triangles,
            "roi": bool(roi),
            "traced_primary_rays": int(len(sel)),
            **({"far_background": far_stats} if far_stats else {}),
            "background_triangles": int(len(background.faces)),
            "eps": tracer.eps,
        },
    )
    if cache_path is not None:
        ws.save(cache_path)
    log.info("warps: %s", ws.summary())
    return ws


class _AtInfinity:
    """Resolves rays that leave the scene's geometry towards far background at infinity."""

    def __init__(self, camera: Camera, far: np.ndarray) -> None:
        self.camera = camera
        self.far = far.reshape(-1)

    def resolve(self, kind: np.ndarray, point: np.ndarray, direction: np.ndarray, on_box: np.ndarray) -> None:
        """In place: a ray that ends on the bounding box or nowhere, and whose direction projects
        onto a far pixel, becomes OBSERVED at that pixel's point at infinity (its ``point`` set to
        ``direction x 1e12`` so that every later projection uses its direction)."""
        idx = np.flatnonzero(on_box | (kind == HitKind.ESCAPED))
        if not len(idx):
            return
        d = np.asarray(direction[idx], np.float64)
        pix, z = self.camera.project(np.where(np.isfinite(d), d, 0.0))
        ok = (z > 0) & self.camera.in_view(pix)
        idx, pix, d = idx[ok], pix[ok], d[ok]
        W, H = self.camera.width, self.camera.height
        near = np.rint(pix).astype(np.int64)
        near[:, 0] = near[:, 0].clip(0, W - 1)
        near[:, 1] = near[:, 1].clip(0, H - 1)
        is_far = self.far[near[:, 1] * W + near[:, 0]]
        idx, d = idx[is_far], d[is_far]
        kind[idx] = HitKind.OBSERVED
        point[idx] = d / np.linalg.norm(d, axis=1, keepdims=True) * 1e12


def _self_warp(
    camera: Camera, tracer: SceneTracer, points: np.ndarray, kind: np.ndarray, verify_visibility: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of I⁻ that observe background points; ``ok`` where observed, in view and visible.

    The background is a depth-map mesh: its triangles project onto the image without overlapping,
    so the front side of any of its points is seen by the camera (nothing else in I⁻ can hide it).
    ``verify_visibility`` casts the camera ray to every point anyway (the test suite checks that
    both agree).
    """
    pix, z = camera.project(np.where(np.isfinite(points), points, 0.0))
    ok = (kind == HitKind.OBSERVED) & camera.in_view(pix) & (z > 0)
    if verify_visibility and ok.any():  # points at infinity (far background) are visible by construction
        idx = np.flatnonzero(ok & (np.linalg.norm(np.where(np.isfinite(points), points, 0.0), axis=1) < 1e11))
        ok[idx] = tracer.visible_from_camera(points[idx])
    return pix.astype(np.float32), ok


def _pano_coords(pano: PanoramaCamera, points: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Panorama pixels of ray ends (by point where there is one, else by direction)."""
    has_point = np.isfinite(points).all(axis=1)
    out = np.full((len(points), 2), np.nan)
    if has_point.any():
        out[has_point] = pano.project_points(points[has_point])
    rest = ~has_point & np.isfinite(directions).all(axis=1)
    if rest.any():
        out[rest] = pano.project_directions(directions[rest])
    return out.astype(np.float32)
