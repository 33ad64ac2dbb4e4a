"""The authors' metric mask (``utils/render_gt.py``'s ``--out_mask``), computed with Open3D.

One ray per pixel centre; where its first hit is the glass object it is followed through the glass
(Snell's law at every hit, total internal reflection where there is no refracted ray) for at most 16
hits, and the pixel is white where the path meets the background, whichever side of a background
face it meets. Then small holes inside the object's silhouette are filled (:func:`fill_small_holes`).
The file their evaluation reads is that mask saved as a JPEG (``metrics.files=jpeg`` does that).

Convention:
    - Camera frame and pixel centres of :mod:`snell_bench.scene.camera`; rays start at the camera's
      centre through pixel centres.
    - Normals: the triangles' face normals (Blender's ``scene.ray_cast`` returns those; here
      Open3D's ``primitive_normals``), flipped against the ray where it leaves the glass. The medium
      is tracked per ray: it starts in air (IOR 1), enters glass of ``ior`` at a face whose normal
      opposes the ray and leaves to air otherwise; a total internal reflection keeps it.
    - A later ray starts ``eps`` (scene units, theirs: 1e-4) past the hit along its new direction.
    - Masks: ``(H, W)`` bool.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from snell_bench.scene.camera import Camera

__all__ = ["MAX_HITS", "authors_mask", "fill_small_holes"]

#: Casts per path, the camera ray's first hit on the object included (theirs: 16).
MAX_HITS = 16
#: The 8-neighbourhood of a pixel.
_NEIGHBOURS = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]], np.int32)


def fill_small_holes(mask: np.ndarray, region: np.ndarray, iterations: int = 2, min_neighbors: int = 6) -> np.ndarray:
    """Fill pinholes as ``render_gt`` does: up to ``iterations`` times, every pixel of ``region``
    that is not set and has at least ``min_neighbors`` set pixels among its 8 neighbours (outside
    the image counts as unset) is set; it stops early when a round sets nothing.

    Args:
        mask: ``(H, W)`` bool.
        region: ``(H, W)`` bool, the only pixels that may be filled.
        iterations: rounds (at least one).
        min_neighbors: set neighbours a pixel needs.

    Returns:
        ``(H, W)`` bool (a new array).
    """
    filled = np.array(mask, bool)
    region = np.asarray(region, bool)
    if filled.shape != region.shape:
        raise ValueError(f"mask {filled.shape} and region {region.shape} must have the same shape")
    for _ in range(max(1, int(iterations))):
        count = ndimage.convolve(filled.astype(np.int32), _NEIGHBOURS, mode="constant", cval=0)
        add = region & ~filled & (count >= int(min_neighbors))
        if not add.any():
            break
        filled |= add
    return filled


def _refract(d: np.ndarray, n: np.ndarray, eta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Refracted unit directions of unit ``d`` at unit normals ``n`` facing against ``d``, with
    ``eta = n_from / n_to`` per ray; and where the refraction exists (no total internal reflection)."""
    cos_i = -np.clip(np.einsum("ij,ij->i", d, n), -1.0, 1.0)
    k = 1.0 - eta**2 * (1.0 - cos_i**2)
    ok = k >= 0.0
    t = eta[:, None] * d + (eta * cos_i - np.sqrt(np.where(ok, k, 0.0)))[:, None] * n
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return t, ok


def authors_mask(
    camera: Camera,
    background: tuple[np.ndarray, np.ndarray],
    obj: tuple[np.ndarray, np.ndarray],
    *,
    ior: float = 1.5,
    max_hits: int = MAX_HITS,
    eps: float = 1e-4,
) -> tuple[np.ndarray, np.ndarray]:
    """The authors' metric mask (see the module's conventions).

    Args:
        camera: the camera.
        background: ``(vertices (N, 3), faces (F, 3))`` of the background mesh, camera frame.
        obj: ``(vertices, faces)`` of the glass object, camera frame.
        ior: the glass's index of refraction (theirs: 1.5 whatever the object).
        max_hits: casts per path, the first hit on the object included.
        eps: how far past a hit a later ray starts.

    Returns:
        ``(mask, silhouette)``: the hole-filled mask, and the pixels whose first hit is the object.
    """
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()

    def add(v, f) -> int:
        return scene.add_triangles(
            o3d.core.Tensor.from_numpy(np.ascontiguousarray(v, np.float32)),
            o3d.core.Tensor.from_numpy(np.ascontiguousarray(f, np.uint32)),
        )

    bg_id, obj_id = add(*background), add(*obj)

    def cast(o, d):
        rays = np.ascontiguousarray(np.concatenate([o, d], axis=1), np.float32)
        r = scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
        return r["t_hit"].numpy().astype(np.float64), r["geometry_ids"].numpy(), r["primitive_normals"].numpy()

    d = camera.pixel_rays().reshape(-1, 3).astype(np.float64)
    o = np.zeros_like(d)
    t, gid, _ = cast(o, d)
    silhouette = np.isfinite(t) & (gid == obj_id)
    white = np.zeros(len(d), bool)
    idx = np.flatnonzero(silhouette)
    o, d, medium = o[idx], d[idx], np.ones(len(idx))
    for _ in range(int(max_hits)):
        if not len(idx):
            break
        t, gid, n = cast(o, d)
        white[idx[np.isfinite(t) & (gid == bg_id)]] = True
        go = np.isfinite(t) & (gid == obj_id)
        idx, o, d, t, medium, n = idx[go], o[go], d[go], t[go], medium[go], n[go].astype(np.float64)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        entering = np.einsum("ij,ij->i", d, n) < 0.0
        face_n = np.where(entering[:, None], n, -n)
        to = np.where(entering, float(ior), 1.0)
        refr, ok = _refract(d, face_n, medium / to)
        refl = d - 2.0 * np.einsum("ij,ij->i", d, face_n)[:, None] * face_n
        hit = o + t[:, None] * d
        d = np.where(ok[:, None], refr, refl / np.linalg.norm(refl, axis=1, keepdims=True))
        medium = np.where(ok, to, medium)
        o = hit + float(eps) * d
    shape = camera.shape
    mask = fill_small_holes(white.reshape(shape), silhouette.reshape(shape))
    return mask, silhouette.reshape(shape)
