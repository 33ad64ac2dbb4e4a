"""A traced soft shadow of the glass object under a jittered directional light: the CPU stand-in for
the relighting model (no weights, no GPU).

What it models, and what it does not: a traced soft shadow of the object under a jittered
directional light; no caustics, no light transport through the glass. The object is an opaque
occluder whose shadow is lightened by ``strength`` (glass casts a lighter shadow than an opaque
object); the light focused through the glass, the caustics FLUX Kontext is asked to paint, is not
there. Each seed jitters the light's direction, so the N candidates of the selection differ.

Convention:
    - Frame: the camera frame (OpenCV: x right, y down, z forward), metres or the depth map's unit.
      The background is I⁻'s depth map back-projected at pixel centres
      (:meth:`~snell_bench.scene.camera.Camera.unproject`); only pixels with finite depth > 0 can be
      shadowed.
    - Light: a directional light; a *light direction* is the unit vector from the scene *towards*
      the light. ``up`` is the placed object's up direction (the fitted support plane's normal,
      ``GlassObject.up``), else the scene's (``SceneInputs.up``), else ``(0, -1, 0)``. ``forward`` is
      the camera's optical axis projected onto the horizontal plane (the image's up direction for a
      camera looking straight down), ``right = forward x up``. Elevation is the angle above the
      horizontal plane (90: overhead); azimuth turns about ``up`` from the camera's side:
      0 = the light behind the camera (shadows fall away from it), 90 = from the camera's right
      (shadows fall to the left), 180 = against the camera (shadows fall towards it).
    - Jitter: seed ``s`` turns the configured direction by a direction drawn uniformly over the cap
      of half-angle ``jitter_deg`` around it (``numpy.random.default_rng(s)``); a direction below the
      horizon is mirrored above it.
    - Softness: an area light of angular radius ``softness_deg``: ``samples`` rays per point on a
      fixed spiral over that cone (one ray for 0: a hard shadow). The occluded fraction ``f`` of a
      point is the fraction of its rays that hit the object's mesh (Open3D any-hit ray casting).
    - Shading, in linear RGB (:mod:`snell_bench.imaging.color`): a background pixel is multiplied by
      ``1 - strength * f``; an object pixel, which sees the background through the glass, by
      ``1 - strength * (1 - F) * f(π^R(p))``, ``f`` sampled bilinearly at the refraction warp's I⁻
      pixel and ``F`` the Fresnel reflectance (the reflected part is not shadowed); where π^R is
      invalid it is left as it is. Pixels with ``f = 0`` keep their exact values.
    - Deterministic: the output depends on the image, the scene, the object, the warps, the settings
      and the seed only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import open3d as o3d
import torch

from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear
from snell_bench.imaging.remap import remap
from snell_bench.relight.base import check_image
from snell_bench.scene.camera import Camera

__all__ = [
    "DEFAULT_UP",
    "Occluder",
    "ShadowRelighter",
    "apply_shadow",
    "cone_directions",
    "horizontal_frame",
    "jitter_direction",
    "light_direction",
    "occluded_fraction",
    "orthonormal_basis",
    "unit_vector",
    "scene_up",
    "shadow_fraction_map",
]

#: The up direction when neither the object nor the scene gives one (OpenCV: y points down).
DEFAULT_UP = np.array([0.0, -1.0, 0.0])
#: Rays cast per Open3D call (bounds the memory of a large image).
_CHUNK = 1 << 22
_GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))


def unit_vector(v) -> np.ndarray:
    """``v`` as a unit float64 3-vector (ValueError for a zero or non-finite one)."""
    v = np.asarray(v, np.float64).reshape(3)
    n = float(np.linalg.norm(v))
    if not math.isfinite(n) or n == 0.0:
        raise ValueError(f"expected a non-zero finite 3-vector, got {v.tolist()}")
    return v / n


def orthonormal_basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors that complete the unit ``d`` to a right-handed orthonormal basis."""
    a = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(d, a)
    u /= np.linalg.norm(u)
    return u, np.cross(d, u)


def scene_up(obj: Any = None, scene: Any = None) -> np.ndarray:
    """The up direction in camera coordinates: ``obj.up`` (the support plane's normal), else
    ``scene.up``, else :data:`DEFAULT_UP`; unit, float64."""
    for src in (obj, scene):
        up = getattr(src, "up", None)
        if up is not None:
            return unit_vector(up)
    return DEFAULT_UP.copy()


def horizontal_frame(up) -> tuple[np.ndarray, np.ndarray]:
    """``(forward, right)``: the camera's horizontal viewing direction and its right, both unit
    and perpendicular to ``up``.

    Args:
        up: the up direction (camera frame).

    Returns:
        ``forward``, the optical axis ``(0, 0, 1)`` projected onto the plane perpendicular to
        ``up`` (for a camera looking along ``up`` or against it, the image's up direction
        ``(0, -1, 0)`` projected), and ``right = forward x up``.

    Examples:
        >>> f, r = horizontal_frame([0.0, -1.0, 0.0])
        >>> (f + 0.0).tolist(), (r + 0.0).tolist()  # + 0.0 turns -0.0 into 0.0
        ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    """
    up = unit_vector(up)
    for axis in (np.array([0.0, 0.0, 1.0]), np.array([0.0, -1.0, 0.0])):
        f = axis - (axis @ up) * up
        if np.linalg.norm(f) > 1e-6:
            f = f / np.linalg.norm(f)
            return f, np.cross(f, up)
    raise AssertionError("unreachable: the two axes are perpendicular")


def light_direction(elevation_deg: float, azimuth_deg: float, up) -> np.ndarray:
    """The unit direction towards a directional light (module convention for the angles).

    Args:
        elevation_deg: the angle above the horizontal plane, in [-90, 90] (90: overhead).
        azimuth_deg: the turn about ``up`` from the camera's side (0: from behind the camera,
            90: from its right).
        up: the up direction (camera frame).

    Returns:
        ``(3,)`` float64, unit.

    Examples:
        >>> up = [0.0, -1.0, 0.0]
        >>> [(np.round(light_direction(el, az, up), 6) + 0.0).tolist() for el, az in [(90, 0), (0, 90)]]
        [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0]]
    """
    up = unit_vector(up)
    forward, right = horizontal_frame(up)
    el, az = math.radians(float(elevation_deg)), math.radians(float(azimuth_deg))
    horizontal = math.cos(az) * -forward + math.sin(az) * right
    return unit_vector(math.cos(el) * horizontal + math.sin(el) * up)


def jitter_direction(direction, jitter_deg: float, seed: int, up=None) -> np.ndarray:
    """``direction`` turned by a random angle up to ``jitter_deg``, deterministic in ``seed``.

    Args:
        direction: the unit direction towards the light.
        jitter_deg: the cap's half-angle in degrees (0: ``direction`` itself).
        seed: seeds ``numpy.random.default_rng``.
        up: if given, a jittered direction below the horizon (``d . up < 0``) is mirrored above it.

    Returns:
        ``(3,)`` float64, unit, uniformly distributed over the cap (solid angle).
    """
    d = unit_vector(direction)
    if jitter_deg < 0:
        raise ValueError(f"jitter_deg must be >= 0, got {jitter_deg}")
    if jitter_deg == 0:
        return d
    rng = np.random.default_rng(int(seed))
    cos_t = 1.0 - rng.random() * (1.0 - math.cos(math.radians(float(jitter_deg))))
    phi = 2.0 * math.pi * rng.random()
    sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
    u, v = orthonormal_basis(d)
    out = unit_vector(cos_t * d + sin_t * (math.cos(phi) * u + math.sin(phi) * v))
    if up is not None:
        up = unit_vector(up)
        if out @ up < 0:
            out = unit_vector(out - 2.0 * (out @ up) * up)
    return out


def cone_directions(direction, half_angle_deg: float, samples: int) -> np.ndarray:
    """Directions spread evenly over a cone: the rays of an area light of angular radius
    ``half_angle_deg``.

    Args:
        direction: the cone's axis (unit direction towards the light).
        half_angle_deg: the cone's half-angle (0: the axis alone, one direction).
        samples: the number of directions (>= 1).

    Returns:
        ``(S, 3)`` float64 unit vectors on a Fibonacci spiral equal in solid angle (stratified,
        deterministic), ``S = samples`` (``1`` for a zero angle).

    Examples:
        >>> cone_directions([0.0, 0.0, 1.0], 0.0, 16).tolist()
        [[0.0, 0.0, 1.0]]
        >>> d = cone_directions([0.0, 0.0, 1.0], 10.0, 32)
        >>> d.shape, bool((d[:, 2] >= np.cos(np.radians(10.0)) - 1e-12).all())
        ((32, 3), True)
    """
    d = unit_vector(direction)
    if int(samples) != samples or samples < 1:
        raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
    if half_angle_deg < 0 or half_angle_deg >= 90:
        raise ValueError(f"the light's angular radius must be in [0, 90) degrees, got {half_angle_deg}")
    if half_angle_deg == 0:
        return d[None].copy()
    i = np.arange(int(samples), dtype=np.float64)
    cos_t = 1.0 - (1.0 - math.cos(math.radians(float(half_angle_deg)))) * (i + 0.5) / samples
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t**2))
    phi = i * _GOLDEN_ANGLE
    u, v = orthonormal_basis(d)
    out = cos_t[:, None] * d + sin_t[:, None] * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)
    return out / np.linalg.norm(out, axis=1, keepdims=True)


@dataclass(eq=False)
class Occluder:
    """A mesh rays can be tested against, with its bounding sphere (for culling).

    Attributes:
        scene: Open3D's ``RaycastingScene`` holding the mesh.
        center: ``(3,)`` the bounding sphere's centre.
        radius: its radius.
        eps: the rays' start offset ``tnear`` (scaled to the mesh).
    """

    scene: Any
    center: np.ndarray
    radius: float
    eps: float

    @classmethod
    def from_mesh(cls, vertices: np.ndarray, faces: np.ndarray, nthreads: int = 0) -> Occluder:
        """An occluder of a triangle mesh ``(V, 3)`` / ``(F, 3)`` (camera frame)."""
        vertices = np.asarray(vertices, np.float64)
        faces = np.asarray(faces)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3 or not len(faces):
            raise ValueError(f"an occluder needs vertices (V, 3) and faces (F, 3), got {vertices.shape}, {faces.shape}")
        scene = o3d.t.geometry.RaycastingScene(nthreads=int(nthreads))
        scene.add_triangles(
            o3d.core.Tensor.from_numpy(np.ascontiguousarray(vertices, np.float32)),
            o3d.core.Tensor.from_numpy(np.ascontiguousarray(faces, np.uint32)),
        )
        lo, hi = vertices.min(0), vertices.max(0)
        center = (lo + hi) / 2.0
        radius = float(np.linalg.norm(vertices - center, axis=1).max())
        eps = max(1e-5 * 2.0 * radius, 1e-7)
        return cls(scene=scene, center=center, radius=radius * (1.0 + 1e-6) + eps, eps=eps)


def occluded_fraction(occluder: Occluder, points: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """The fraction of the rays from each point along ``directions`` that hit the occluder.

    Rays whose direction cannot reach the occluder's bounding sphere are not cast: a point is
    tested only if the angle between the cone's axis and the direction to the sphere's centre is at
    most the sphere's angular radius plus the cone's half-angle (exact culling).

    Args:
        occluder: the mesh (:class:`Occluder`).
        points: ``(N, 3)`` ray origins (camera frame; finite).
        directions: ``(S, 3)`` unit ray directions (towards the light).

    Returns:
        ``(N,)`` float32 in [0, 1]: hits / S.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    dirs = np.asarray(directions, np.float64).reshape(-1, 3)
    out = np.zeros(len(points), np.float32)
    if not len(points):
        return out
    axis = unit_vector(dirs.mean(0))
    spread = float(np.arccos(np.clip(dirs @ axis, -1.0, 1.0)).max())
    q = occluder.center - points
    dist = np.linalg.norm(q, axis=1)
    inside = dist <= occluder.radius
    with np.errstate(invalid="ignore", divide="ignore"):
        theta = np.arccos(np.clip((q @ axis) / dist, -1.0, 1.0))
        alpha = np.arcsin(np.clip(occluder.radius / dist, 0.0, 1.0))
    candidates = np.flatnonzero(inside | (theta <= alpha + spread + 1e-9))
    if not len(candidates):
        return out
    S = len(dirs)
    hits = np.zeros(len(candidates), np.int64)
    step = max(1, _CHUNK // S)
    d32 = np.ascontiguousarray(dirs, np.float32)
    for start in range(0, len(candidates), step):
        idx = candidates[start : start + step]
        rays = np.empty((len(idx), S, 6), np.float32)
        rays[..., :3] = points[idx, None, :]
        rays[..., 3:] = d32[None]
        occ = occluder.scene.test_occlusions(o3d.core.Tensor.from_numpy(rays.reshape(-1, 6)), tnear=occluder.eps)
        hits[start : start + len(idx)] = occ.numpy().reshape(len(idx), S).sum(1)
    out[candidates] = hits / S
    return out


def shadow_fraction_map(depth: np.ndarray, camera: Camera, occluder: Occluder, directions: np.ndarray) -> np.ndarray:
    """The occluded fraction of every background point of a depth map.

    Args:
        depth: ``(H, W)`` camera-frame z of I⁻ (NaN, inf or <= 0 where unknown).
        camera: its camera.
        occluder: the object (:class:`Occluder`).
        directions: ``(S, 3)`` unit directions towards the light (:func:`cone_directions`).

    Returns:
        ``(H, W)`` float32 in [0, 1]; 0 where the depth is unknown.
    """
    depth = np.asarray(depth, np.float64)
    with np.errstate(invalid="ignore"):
        known = np.isfinite(depth) & (depth > 0)
    points = camera.unproject(np.where(known, depth, 0.0))
    f = np.zeros(depth.shape, np.float32)
    f[known] = occluded_fraction(occluder, points[known], directions)
    return f


def apply_shadow(
    image: torch.Tensor,
    fraction: np.ndarray,
    *,
    strength: float,
    refraction: np.ndarray | None = None,
    fresnel: np.ndarray | None = None,
) -> torch.Tensor:
    """Darken ``image`` by a shadow's occluded fraction, in linear RGB.

    Args:
        image: ``(1, 3, H, W)`` sRGB in [0, 1].
        fraction: ``(H, W)`` occluded fraction of I⁻'s pixels (:func:`shadow_fraction_map`).
        strength: the darkening of a fully occluded point (1: black, 0: none).
        refraction: ``(H, W, 2)`` π^R (object pixel -> I⁻ pixel, identity outside the object, NaN
            where invalid), or ``None`` (every pixel sees its own background point).
        fresnel: ``(H, W)`` Fresnel reflectance (the part of an object pixel the shadow does not
            reach), or ``None`` (0).

    Returns:
        ``(1, 3, H, W)`` float32 sRGB: ``image * (1 - strength * (1 - F) * f_seen)`` in linear RGB,
        ``f_seen`` the fraction at the pixel's π^R source (0 where invalid); pixels with
        ``f_seen = 0`` keep their exact values.
    """
    H, W = check_image(image)
    img = image.detach().to("cpu", torch.float32)
    f = np.array(fraction, np.float32)
    if f.shape != (H, W):
        raise ValueError(f"the shadow map is {f.shape} for a {(H, W)} image")
    seen = f.copy()
    if refraction is not None:
        coords = np.asarray(refraction, np.float32)
        if coords.shape != (H, W, 2):
            raise ValueError(f"the refraction warp is {coords.shape} for a {(H, W)} image")
        grid = np.stack(np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32)), -1)
        moved = ~(coords == grid).all(-1)  # the object's pixels (NaN included): sampled through the warp
        if moved.any():
            sampled, _ = remap(torch.from_numpy(f)[None, None], coords[moved][None])  # 0 where invalid
            seen[moved] = sampled[0, 0, 0].numpy()
    if fresnel is not None:
        seen *= 1.0 - np.clip(np.asarray(fresnel, np.float32), 0.0, 1.0)
    factor = np.clip(1.0 - float(strength) * seen, 0.0, 1.0)
    shaded = torch.from_numpy(factor < 1.0)
    out = img.clone()
    if bool(shaded.any()):  # only the shadowed pixels are converted: the others keep their exact values
        k = torch.from_numpy(factor)[shaded]
        out[0][:, shaded] = linear_to_srgb(srgb_to_linear(img[0][:, shaded]) * k)
    return out


class ShadowRelighter:
    """A traced soft shadow of the object under a jittered directional light; no caustics, no
    light transport through the glass (the CPU stand-in for the relighting model; see the module
    docstring for every convention).

    Args:
        light_elevation_deg: the light's elevation above the horizontal plane.
        light_azimuth_deg: its azimuth about up (0: from behind the camera, 90: from its right).
        jitter_deg: each seed turns the light by up to this angle.
        softness_deg: the light's angular radius (0: a hard shadow).
        samples: shadow rays per background point (one when ``softness_deg`` is 0).
        strength: the darkening of a fully shadowed point (glass casts a lighter shadow: 0.5).
        nthreads: Open3D threads (0: all cores).
    """

    name = "traced_shadow"

    def __init__(
        self,
        light_elevation_deg: float = 60.0,
        light_azimuth_deg: float = 30.0,
        jitter_deg: float = 15.0,
        softness_deg: float = 5.0,
        samples: int = 32,
        strength: float = 0.5,
        nthreads: int = 0,
    ):
        if not -90.0 <= float(light_elevation_deg) <= 90.0:
            raise ValueError(f"light_elevation_deg must be in [-90, 90], got {light_elevation_deg}")
        if float(jitter_deg) < 0:
            raise ValueError(f"jitter_deg must be >= 0, got {jitter_deg}")
        if not 0.0 <= float(softness_deg) < 90.0:
            raise ValueError(f"softness_deg must be in [0, 90), got {softness_deg}")
        if int(samples) != samples or samples < 1:
            raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
        if not 0.0 <= float(strength) <= 1.0:
            raise ValueError(f"strength must be in [0, 1], got {strength}")
        self.light_elevation_deg = float(light_elevation_deg)
        self.light_azimuth_deg = float(light_azimuth_deg)
        self.jitter_deg = float(jitter_deg)
        self.softness_deg = float(softness_deg)
        self.samples = int(samples)
        self.strength = float(strength)
        self.nthreads = int(nthreads)
        self._occluder: tuple[str, Occluder] | None = None

    def describe(self) -> str:
        """What the relighter is, for the records."""
        return (
            "a traced soft shadow of the object under a jittered directional light; no caustics, no light transport "
            f"through the glass (elevation {self.light_elevation_deg:g} deg, azimuth {self.light_azimuth_deg:g} deg, "
            f"jitter {self.jitter_deg:g} deg, softness {self.softness_deg:g} deg, {self.samples} rays per point, "
            f"strength {self.strength:g})"
        )

    def light(self, seed: int, up) -> np.ndarray:
        """The seed's unit direction towards the light (camera frame)."""
        base = light_direction(self.light_elevation_deg, self.light_azimuth_deg, up)
        return jitter_direction(base, self.jitter_deg, seed, up=up)

    def occluder(self, obj: Any) -> Occluder:
        """The object's :class:`Occluder` (kept for the last object seen)."""
        key = obj.content_hash() if hasattr(obj, "content_hash") else str(id(obj))
        if self._occluder is None or self._occluder[0] != key:
            self._occluder = (key, Occluder.from_mesh(obj.vertices, obj.faces, nthreads=self.nthreads))
        return self._occluder[1]

    def shadow(self, seed: int, *, scene: Any, obj: Any) -> np.ndarray:
        """The occluded fraction of I⁻'s pixels for a seed, ``(H, W)`` float32 in [0, 1]."""
        up = scene_up(obj, scene)
        dirs = cone_directions(self.light(seed, up), self.softness_deg, self.samples)
        return shadow_fraction_map(scene.depth, scene.camera, self.occluder(obj), dirs)

    def relight(
        self,
        image: torch.Tensor,
        *,
        prompt: str = "",
        seed: int,
        scene: Any = None,
        obj: Any = None,
        warps: Any = None,
        panorama: Any = None,
    ) -> torch.Tensor:
        """The image with the object's traced shadow for one seed (``prompt`` and ``panorama`` are not used).

        Args:
            image: ``(1, 3, H, W)`` sRGB in [0, 1], the scene's camera view with the object.
            prompt: ignored.
            seed: jitters the light.
            scene: the :class:`~snell_bench.scene.sources.SceneInputs` (I⁻'s depth and camera).
            obj: the placed :class:`~snell_bench.scene.objects.GlassObject` (camera frame).
            warps: its :class:`~snell_bench.optics.warps.WarpSet` (π^R and the Fresnel term).

        Returns:
            ``(1, 3, H, W)`` float32 sRGB in [0, 1].

        Raises:
            ValueError: if ``scene``, ``obj`` or ``warps`` is missing or their sizes differ.
        """
        if scene is None or obj is None or warps is None:
            raise ValueError("the traced-shadow relighter needs the scene, the placed object and its warps")
        H, W = check_image(image)
        if tuple(np.shape(scene.depth)) != (H, W) or tuple(warps.refraction.shape[:2]) != (H, W):
            raise ValueError(
                f"image {(H, W)}, depth {tuple(np.shape(scene.depth))} and warps {tuple(warps.refraction.shape[:2])} "
                "must have the same size"
            )
        fraction = self.shadow(seed, scene=scene, obj=obj)
        refraction = np.where(np.asarray(warps.refraction_valid)[..., None], warps.refraction, np.nan)
        return apply_shadow(image, fraction, strength=self.strength, refraction=refraction, fresnel=warps.fresnel)
