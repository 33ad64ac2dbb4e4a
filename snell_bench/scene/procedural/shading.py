"""Ray casting and shading: the radiance field of a procedural scene.

Shading is view-independent: diffuse albedo times ``ambient + key light · max(0, n·l) ·
visibility``, with hard shadows from shadow rays, plus emissive surfaces whose radiance is their
texture. Rays that miss every surface get the environment radiance (black without one).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from snell_bench.scene.procedural.textures import Material

__all__ = ["CHUNK", "Light", "RadianceField"]

CHUNK = 1 << 19  # rays per ray-casting batch (bounds memory)


@dataclass
class Light:
    """The key light and the hemispherical ambient light of a scene.

    Attributes:
        kind: ``"point"`` or ``"directional"``.
        vector: Position (point light) or unit direction towards the light (directional).
        color: Linear RGB intensity (point light: at 1 m).
        ambient_sky: Ambient radiance from above.
        ambient_ground: Ambient radiance from below.
        falloff: A point light falls off as ``1 / (distance² + falloff)``.
    """

    kind: str
    vector: np.ndarray
    color: np.ndarray
    ambient_sky: np.ndarray
    ambient_ground: np.ndarray
    falloff: float = 0.0


def oriented_face_normals(vertices: np.ndarray, faces: np.ndarray, vertex_normals: np.ndarray) -> np.ndarray:
    """Unit face normals, each flipped to agree with the normals of its vertices.

    Args:
        vertices: (n, 3) float64.
        faces: (m, 3) vertex indices.
        vertex_normals: (n, 3) unit normals.

    Returns:
        (m, 3) float32.
    """
    tri = vertices[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-30)
    vsum = vertex_normals[faces].sum(1)
    fn *= np.where(np.sum(fn * vsum, 1) < 0, -1.0, 1.0)[:, None]
    return fn.astype(np.float32)


class RadianceField:
    """A triangle mesh with procedural materials and one key light, queried by rays.

    Geometry, rays and the light are in one frame (the scene camera's); materials are evaluated
    in world coordinates, ``world = x @ rotation.T + origin``, then in each material's own frame.
    All ray casting goes through one :class:`open3d.t.geometry.RaycastingScene`, built on first
    use.

    Args:
        vertices: (n, 3) float64.
        vertex_normals: (n, 3) float32 unit shading normals.
        faces: (m, 3) int64 vertex indices.
        face_material: (m,) index into ``materials`` per face.
        face_tint: (m, 3) float32 RGB factor on each face's albedo.
        materials: The materials.
        light: The light, in this frame.
        rotation: (3, 3) columns are this frame's axes in world coordinates.
        origin: (3,) this frame's origin in world coordinates.
        env: Radiance of rays that miss: maps world-frame directions (N, 3) to linear RGB (N, 3);
            ``None`` for black.
    """

    def __init__(
        self,
        vertices: np.ndarray,
        vertex_normals: np.ndarray,
        faces: np.ndarray,
        face_material: np.ndarray,
        face_tint: np.ndarray,
        materials: list[Material],
        light: Light,
        rotation: np.ndarray,
        origin: np.ndarray,
        env: Callable[[np.ndarray], np.ndarray] | None = None,
    ):
        self.vertices = vertices
        self.vertex_normals = vertex_normals
        self.faces = faces
        self.face_material = face_material
        self.face_tint = face_tint
        self.materials = materials
        self.light = light
        self.rotation = rotation
        self.origin = origin
        self.env = env
        self.face_normals = oriented_face_normals(vertices, faces, vertex_normals)
        self.emissive = np.array([m.emissive for m in materials])
        self.casts_shadow = np.array([m.casts_shadow for m in materials])
        self.local_frames = []  # per material: world -> local (origin, axes)
        for m in materials:
            o = np.zeros(3) if m.origin is None else np.asarray(m.origin, np.float64)
            A = np.eye(3) if m.axes is None else np.asarray(m.axes, np.float64)
            self.local_frames.append((o, A))
        self._rc = None

    # ------------------------------------------------------------------ ray casting
    def raycaster(self):
        """The Open3D ``RaycastingScene`` of the mesh (built on the first call)."""
        if self._rc is None:
            import open3d as o3d

            rc = o3d.t.geometry.RaycastingScene()
            rc.add_triangles(
                o3d.core.Tensor(np.ascontiguousarray(self.vertices, dtype=np.float32)),
                o3d.core.Tensor(np.ascontiguousarray(self.faces, dtype=np.uint32)),
            )
            self._rc = rc
        return self._rc

    def cast(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Casts one batch of rays.

        Args:
            o: Origins, (N, 3) or broadcastable to it.
            d: Unit directions, (N, 3).

        Returns:
            ``(t (N,) float32, hit triangle (N,) int64, barycentric uv (N, 2) float32)``; ``t`` is
            ``inf`` where nothing is hit.
        """
        import open3d as o3d

        rays = np.empty((len(d), 6), np.float32)
        rays[:, :3] = o
        rays[:, 3:] = d
        out = self.raycaster().cast_rays(o3d.core.Tensor(rays))
        return out["t_hit"].numpy(), out["primitive_ids"].numpy().astype(np.int64), out["primitive_uvs"].numpy()

    def cast_t(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Hit distances along rays, in batches of :data:`CHUNK`.

        Args:
            o: Origins, broadcastable to ``d``.
            d: Directions, (N, 3), not necessarily unit (they are normalised).

        Returns:
            Float32 (N,), ``inf`` where nothing is hit.
        """
        t = np.empty(len(d), np.float32)
        o = np.broadcast_to(o, d.shape)
        for a in range(0, len(d), CHUNK):
            b = min(len(d), a + CHUNK)
            t[a:b] = self.cast(o[a:b], d[a:b] / np.linalg.norm(d[a:b], axis=1, keepdims=True))[0]
        return t

    # ------------------------------------------------------------------ shading
    def radiance(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear-RGB radiance arriving along rays, and their hit distances.

        Args:
            origins: Ray origins, (N, 3) or (3,) (broadcast).
            directions: Ray directions, (N, 3); need not be unit (they are normalised).

        Returns:
            ``(radiance (N, 3) float32, t (N,) float32)`` with ``t`` the Euclidean distance to the
            first surface (``inf`` where nothing is hit; such rays get the environment radiance).

        Raises:
            ValueError: If a direction is zero or not finite.
        """
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        o = np.asarray(origins, np.float64)
        o = np.broadcast_to(o.reshape(-1, 3) if o.ndim > 1 else o.reshape(1, 3), d.shape)
        n = len(d)
        norm = np.linalg.norm(d, axis=1, keepdims=True)
        if np.any(~np.isfinite(norm)) or np.any(norm <= 0):
            raise ValueError("directions must be finite and non-zero")
        d = d / norm
        rad = np.empty((n, 3), np.float32)
        t = np.empty(n, np.float32)
        for a in range(0, n, CHUNK):
            b = min(n, a + CHUNK)
            rad[a:b], t[a:b] = self.shade(o[a:b], d[a:b])
        return rad, t

    def shade(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Radiance and hit distance of one batch of rays (unit directions ``d``, origins ``o``)."""
        t, prim, uv = self.cast(o, d)
        n = len(d)
        rad = np.zeros((n, 3), np.float32)
        hit = np.isfinite(t)
        if self.env is not None and not hit.all():
            miss = ~hit
            rad[miss] = self.env(d[miss] @ self.rotation.T)
        if not hit.any():
            return rad, t
        hi = np.nonzero(hit)[0]
        tri = prim[hi]
        th = t[hi]
        p, ng, ns = self._hit_geometry(o[hi], d[hi], th, tri, uv[hi])
        mat = self.face_material[tri]
        col, nw = self._albedo(p, ns, tri, mat)
        lit = np.nonzero(~self.emissive[mat])[0]
        out = col.copy()
        if len(lit):
            out[lit] = col[lit] * self._irradiance(p[lit], ns[lit], ng[lit], nw[lit], th[lit])
        rad[hi] = out
        return rad, t

    def albedo(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The diffuse albedo seen along rays (one batch), and whether it is lit (a hit on a
        surface that is not emissive): ``(albedo (N, 3) float32, lit (N,) bool)``; 0 and False where
        a ray hits nothing or an emissive surface."""
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        o = np.broadcast_to(np.asarray(origins, np.float64).reshape(-1, 3), d.shape)
        t, prim, uv = self.cast(o, d)
        col = np.zeros((len(d), 3), np.float32)
        lit = np.isfinite(t)
        lit[lit] = ~self.emissive[self.face_material[prim[lit]]]
        if lit.any():
            p, _, ns = self._hit_geometry(o[lit], d[lit], t[lit], prim[lit], uv[lit])
            col[lit] = self._albedo(p, ns, prim[lit], self.face_material[prim[lit]])[0]
        return col, lit

    def direct_factor(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """:meth:`key_direct` at the surfaces rays hit (one batch; 0 where they hit nothing)."""
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        o = np.broadcast_to(np.asarray(origins, np.float64).reshape(-1, 3), d.shape)
        t, prim, uv = self.cast(o, d)
        out = np.zeros(len(d))
        hit = np.isfinite(t)
        if hit.any():
            p, ng, ns = self._hit_geometry(o[hit], d[hit], t[hit], prim[hit], uv[hit])
            out[hit] = self.key_direct(p, ns, ng, t[hit])
        return out

    def _hit_geometry(self, o, d, t, tri, uv):
        """Hit points, geometric and interpolated shading normals, both facing the ray origin."""
        p = o + t[:, None].astype(np.float64) * d
        ng = self.face_normals[tri].astype(np.float64)
        u, v = uv[:, 0:1], uv[:, 1:2]
        vn = self.vertex_normals[self.faces[tri]]
        ns = ((1.0 - u - v) * vn[:, 0] + u * vn[:, 1] + v * vn[:, 2]).astype(np.float64)
        ns /= np.maximum(np.linalg.norm(ns, axis=1, keepdims=True), 1e-12)
        flip = np.sum(ng * d, 1) > 0
        ng[flip] *= -1
        ns[flip] *= -1
        return p, ng, ns

    def _albedo(self, p, ns, tri, mat):
        """Tinted material albedo (float32) at hit points, and the world-frame shading normals."""
        pw = p @ self.rotation.T + self.origin
        nw = ns @ self.rotation.T
        col = np.empty((len(p), 3), np.float32)
        for m in np.unique(mat):
            sel = np.nonzero(mat == m)[0]
            org, A = self.local_frames[m]
            col[sel] = self.materials[m].albedo((pw[sel] - org) @ A, nw[sel] @ A)
        col *= self.face_tint[tri]
        return col, nw

    def _irradiance(self, p, ns, ng, nw, t):
        """Ambient plus shadowed key light at lit (non-emissive) hit points, float32 (N, 3).

        Args:
            p: Hit points.
            ns: Shading normals.
            ng: Geometric normals (offset the shadow-ray origins).
            nw: World-frame shading normals (their y weights sky against ground ambient).
            t: Distances of the hits from the ray origins (scale the shadow-ray offset).
        """
        L = self.light
        ny = nw[:, 1:2].astype(np.float32)
        amb = L.ambient_sky * (0.5 + 0.5 * ny) + L.ambient_ground * (0.5 - 0.5 * ny)
        return amb + L.color[None, :] * self.key_direct(p, ns, ng, t)[:, None].astype(np.float32)

    def key_direct(self, p, ns, ng, t) -> np.ndarray:
        """``cos θ × falloff × visibility`` of the key light at points ``p`` (shading normals
        ``ns``, geometric ``ng``, hit distances ``t`` scaling the shadow rays' offset): ``(N,)``."""
        L = self.light
        if L.kind == "point":
            tol = L.vector - p
            dist = np.linalg.norm(tol, axis=1)
            ldir = tol / dist[:, None]
            fall = 1.0 / (dist**2 + L.falloff)
        else:
            ldir = np.broadcast_to(L.vector, p.shape)
            dist = np.full(len(p), np.inf)
            fall = np.ones(len(p))
        cos = np.sum(ns * ldir, 1)
        cand = np.nonzero((cos > 0) & (np.sum(ng * ldir, 1) > -0.05))[0]
        direct = np.zeros(len(p))
        if len(cand):
            eps = 1e-3 + 2e-6 * t[cand]
            so = p[cand] + ng[cand] * eps[:, None]
            ts, ps, _ = self.cast(so, ldir[cand])
            blocked = np.isfinite(ts) & (ts < dist[cand] - 1e-3)
            bi = np.nonzero(blocked)[0]
            blocked[bi] = self.casts_shadow[self.face_material[ps[bi]]]
            direct[cand] = np.where(blocked, 0.0, cos[cand] * fall[cand])
        return direct
