"""Accumulates the triangle mesh of a procedural scene, primitive by primitive."""

from __future__ import annotations

import numpy as np
import trimesh

from snell_bench.scene.procedural.noise import Noise, rot_y
from snell_bench.scene.procedural.textures import Material

__all__ = ["Builder"]


class Builder:
    """Accumulates triangles (world frame) with per-vertex normals, per-face material and tint.

    Every primitive takes a material index from :meth:`material` and an optional RGB ``tint`` that
    multiplies the material's albedo on its faces.
    """

    def __init__(self) -> None:
        self.V: list[np.ndarray] = []
        self.N: list[np.ndarray] = []
        self.F: list[np.ndarray] = []
        self.M: list[np.ndarray] = []
        self.T: list[np.ndarray] = []
        self.nv = 0
        self.materials: list[Material] = []
        self._mat_index: dict[str, int] = {}

    def material(self, mat: Material) -> int:
        """Registers ``mat`` and returns its index; a name seen before returns the first one's index."""
        if mat.name in self._mat_index:
            return self._mat_index[mat.name]
        self._mat_index[mat.name] = len(self.materials)
        self.materials.append(mat)
        return self._mat_index[mat.name]

    def add(self, V, F, N, mat: int, tint=(1.0, 1.0, 1.0)) -> None:
        """Appends raw triangles.

        Args:
            V: Vertices, (n, 3).
            F: Faces indexing ``V``, (m, 3).
            N: Vertex normals, (n, 3); normalised here.
            mat: Material index.
            tint: RGB factor on the albedo.
        """
        V = np.asarray(V, np.float64).reshape(-1, 3)
        N = np.asarray(N, np.float64).reshape(-1, 3)
        N = N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)
        F = np.asarray(F, np.int64).reshape(-1, 3)
        self.V.append(V)
        self.N.append(N)
        self.F.append(F + self.nv)
        self.M.append(np.full(len(F), mat, np.int32))
        self.T.append(np.tile(np.asarray(tint, np.float32), (len(F), 1)))
        self.nv += len(V)

    # -------------------------------------------------------------- primitives
    def box(self, center, size, mat: int, yaw: float = 0.0, tint=(1.0, 1.0, 1.0)) -> None:
        """A box with flat faces, axis-aligned after a rotation by ``yaw`` about world y."""
        c = np.asarray(center, np.float64)
        h = 0.5 * np.asarray(size, np.float64)
        R = rot_y(yaw)
        V, N, F = [], [], []
        for axis in range(3):
            for sign in (-1.0, 1.0):
                n = np.zeros(3)
                n[axis] = sign
                a, b = [(axis + 1) % 3, (axis + 2) % 3]
                quad = []
                for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                    q = np.zeros(3)
                    q[axis] = sign * h[axis]
                    q[a] = sa * h[a]
                    q[b] = sb * h[b]
                    quad.append(q)
                base = len(V)
                V.extend(quad)
                N.extend([n] * 4)
                F.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]])
        V = np.array(V) @ R.T + c
        N = np.array(N) @ R.T
        self.add(V, F, N, mat, tint)

    def quad(self, p0, p1, p2, p3, mat: int, tint=(1.0, 1.0, 1.0)) -> None:
        """A flat quadrilateral ``p0 p1 p2 p3``; its normal follows the right-hand rule."""
        V = np.array([p0, p1, p2, p3], np.float64)
        n = np.cross(V[1] - V[0], V[2] - V[0])
        self.add(V, [[0, 1, 2], [0, 2, 3]], np.tile(n, (4, 1)), mat, tint)

    def grid(
        self, P: np.ndarray, mat: int, normals: np.ndarray | None = None, wrap: bool = False, tint=(1, 1, 1)
    ) -> None:
        """A surface through a point grid.

        Args:
            P: Grid points, (rows, cols, 3).
            mat: Material index.
            normals: Vertex normals (rows, cols, 3); ``None``: area-weighted from the triangles.
            wrap: Close the column direction (the last column connects to the first).
            tint: RGB factor on the albedo.
        """
        r, c = P.shape[:2]
        idx = np.arange(r * c).reshape(r, c)
        if wrap:
            idx = np.concatenate([idx, idx[:, :1]], 1)
        a, b = idx[:-1, :-1], idx[:-1, 1:]
        d, e = idx[1:, :-1], idx[1:, 1:]
        F = np.concatenate([np.stack([a, d, e], -1).reshape(-1, 3), np.stack([a, e, b], -1).reshape(-1, 3)])
        V = P.reshape(-1, 3)
        if normals is None:
            normals = trimesh.Trimesh(V, F, process=False).vertex_normals
        self.add(V, F, normals.reshape(-1, 3), mat, tint)

    def sphere(self, center, radii, mat: int, n_lat: int = 16, n_lon: int = 32, tint=(1, 1, 1)) -> None:
        """An ellipsoid (``radii`` scalar or per axis) from an ``n_lat`` x ``n_lon`` UV grid."""
        c = np.asarray(center, np.float64)
        r = np.broadcast_to(np.asarray(radii, np.float64), (3,))
        th = np.linspace(0, np.pi, n_lat + 1)
        ph = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
        th, ph = np.meshgrid(th, ph, indexing="ij")
        u = np.stack([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)], -1)
        self.grid(u * r + c, mat, normals=u / r, wrap=True, tint=tint)

    def rock(self, center, radii, mat: int, rng: np.random.Generator, noise: Noise, tint=(1, 1, 1)) -> None:
        """A noise-displaced icosphere with random yaw (rocks and tree crowns)."""
        ico = trimesh.creation.icosphere(subdivisions=3)
        v = np.asarray(ico.vertices)
        off = rng.uniform(-50, 50, 3)
        d = noise.fbm((v * 1.3 + off).astype(np.float32), 1.0, 3)
        v = v * (0.75 + 0.5 * d)[:, None] * np.asarray(radii) @ rot_y(rng.uniform(0, 2 * np.pi)).T
        v = v + np.asarray(center)
        m = trimesh.Trimesh(v, ico.faces, process=False)
        self.add(v, ico.faces, m.vertex_normals, mat, tint)

    def cylinder(
        self,
        base,
        radius: float,
        height: float,
        mat: int,
        n: int = 32,
        caps: bool = True,
        tint=(1, 1, 1),
        top_radius: float | None = None,
    ) -> None:
        """A vertical cylinder (a cone frustum if ``top_radius`` differs) standing on ``base``."""
        b = np.asarray(base, np.float64)
        rt = radius if top_radius is None else top_radius
        ph = np.linspace(0, 2 * np.pi, n, endpoint=False)
        ring = np.stack([np.cos(ph), np.zeros(n), np.sin(ph)], -1)
        P = np.stack([ring * radius + b, ring * rt + b + [0, height, 0]])
        slope = (radius - rt) / height
        Nr = ring + np.array([0, slope, 0])
        self.grid(P, mat, normals=np.stack([Nr, Nr]), wrap=True, tint=tint)
        if caps:
            for y, r, s in ((0.0, radius, -1.0), (height, rt, 1.0)):
                V = np.concatenate([[b + [0, y, 0]], ring * r + b + [0, y, 0]])
                F = [[0, 1 + (i + 1) % n, 1 + i] for i in range(n)]
                self.add(V, F, np.tile([0, s, 0], (n + 1, 1)), mat, tint)

    def finish(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Concatenates everything added.

        Returns:
            ``(vertices (n, 3), vertex normals (n, 3), faces (m, 3), face materials (m,),
            face tints (m, 3))``.
        """
        return (
            np.concatenate(self.V),
            np.concatenate(self.N),
            np.concatenate(self.F),
            np.concatenate(self.M),
            np.concatenate(self.T),
        )
