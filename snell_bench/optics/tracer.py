"""Ray tracing through a glass object in a depth-map scene, on Open3D's ``RaycastingScene``.

Convention:
    - Everything is in the camera frame (OpenCV; camera at the origin), float64 numpy arrays at
      the interface; rays are cast in float32 (Open3D's only ray type).
    - Two acceleration structures are built once: the *background* (the depth mesh, geometry 0,
      and the bounding box of unobserved space, geometry 1) and the *object* alone. Every ray is
      cast against both, so an object that cuts into the background is handled (a ray inside the
      glass that reaches the background ends there).
    - Object normals point outwards. Shading normals are interpolated from the object's per-corner
      normals (``normals="interpolated"``, the default), are the flat face normals
      (``normals="face"``), or point from the centre of the hit shell's bounding box
      (``normals="radial"``: exact for a sphere or concentric spherical shells, whatever the mesh's
      tessellation; wrong for any other shape). Which side of the surface a ray is on is always decided by the
      *geometric* (face) normal, and where an interpolated normal would send a ray to the wrong
      side of the geometric surface (near silhouettes) the face normal is used for that
      interaction.
    - Self-intersection: a new ray starts ``eps`` away from the surface along the geometric normal,
      on the side it travels to (default ``eps = 1e-5 x`` the object's diameter, at least
      ``1e-6 x`` its distance from the camera, so float32 coordinates cannot round it away).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from snell_bench.optics.functional import adjoint_correction, interact
from snell_bench.optics.media import trace_nested
from snell_bench.optics.trace_types import (
    BACKGROUND_ID,
    BOX_ID,
    BackgroundHit,
    ExitRecord,
    HitKind,
    RefractionTrace,
    dot_rows,
    end_rays,
    o3d_rays,
)
from snell_bench.scene.depth_mesh import BackgroundMesh
from snell_bench.scene.objects import GlassObject

__all__ = ["HitKind", "BackgroundHit", "RefractionTrace", "SceneTracer"]


class SceneTracer:
    """Casts rays against a :class:`BackgroundMesh` and a placed :class:`GlassObject`.

    Args:
        background: the depth mesh and the box of unobserved space
            (:func:`~snell_bench.scene.depth_mesh.build_background`).
        obj: the placed glass object.
        max_bounces: surface interactions per path before it is marked ``TRAPPED`` (>= 1).
        normals: ``"interpolated"``, ``"face"`` or ``"radial"`` shading normals (module docstring).
        eps: self-intersection offset; default scaled to the object (module docstring).
        nthreads: Open3D threads (0: all cores).

    Raises:
        ValueError: ``normals`` or ``max_bounces`` is invalid.

    Examples:
        A glass sphere of radius 0.5 at z = 3 in front of a plane at z = 5:

        >>> from snell_bench.scene.camera import Camera
        >>> from snell_bench.scene.depth_mesh import build_background
        >>> cam = Camera.from_fov(8, 6, 60.0)
        >>> T = np.eye(4); T[:3, 3] = [0.0, -0.5, 3.0]  # the unit-diameter sphere centred at z = 3
        >>> obj = GlassObject.sphere(subdivisions=2).transformed(T)
        >>> tracer = SceneTracer(build_background(np.full(cam.shape, 5.0), cam), obj)
        >>> axis = np.array([[0.0, 0.0, 1.0]])
        >>> round(float(tracer.cast_camera_object(axis)[0]), 4)
        2.5
        >>> hit = tracer.cast_background(np.zeros((1, 3)), np.array([[0.3, 0.0, 1.0]]))
        >>> HitKind(int(hit.kind[0])).name, round(float(hit.point[0, 2]), 4)
        ('OBSERVED', 5.0)

        The central ray enters and leaves the sphere (two interactions), reflects 4 % at the
        first surface and ends on the plane:

        >>> tr = tracer.trace(np.zeros((1, 3)), axis)
        >>> HitKind(int(tr.kind[0])).name, int(tr.bounces[0]), round(float(tr.fresnel[0]), 4)
        ('OBSERVED', 2, 0.04)
        >>> round(float(tr.point[0, 2]), 4)
        5.0
    """

    def __init__(
        self,
        background: BackgroundMesh,
        obj: GlassObject,
        *,
        max_bounces: int = 8,
        normals: str = "interpolated",
        eps: float | None = None,
        nthreads: int = 0,
    ) -> None:
        if normals not in ("interpolated", "face", "radial"):
            raise ValueError(f"normals must be 'interpolated', 'face' or 'radial', got {normals!r}")
        if int(max_bounces) != max_bounces or max_bounces < 1:
            raise ValueError(f"max_bounces must be an integer >= 1, got {max_bounces!r}")
        self.obj = obj
        self.max_bounces = int(max_bounces)
        self.normals = normals
        self.nthreads = int(nthreads)
        dist = float(np.linalg.norm(obj.center))
        self.eps = float(eps) if eps is not None else max(1e-5 * obj.diameter, 1e-6 * dist, 1e-7)

        self._bg = o3d.t.geometry.RaycastingScene(nthreads=self.nthreads)
        if len(background.faces):
            gid = self._bg.add_triangles(
                o3d.core.Tensor.from_numpy(np.ascontiguousarray(background.vertices, np.float32)),
                o3d.core.Tensor.from_numpy(np.ascontiguousarray(background.faces, np.uint32)),
            )
        else:  # keep geometry ids fixed: an unreachable degenerate triangle stands in
            gid = self._bg.add_triangles(
                o3d.core.Tensor(np.zeros((3, 3), np.float32)), o3d.core.Tensor(np.array([[0, 1, 2]], np.uint32))
            )
        bid = self._bg.add_triangles(
            o3d.core.Tensor.from_numpy(np.ascontiguousarray(background.box_vertices, np.float32)),
            o3d.core.Tensor.from_numpy(np.ascontiguousarray(background.box_faces, np.uint32)),
        )
        assert (gid, bid) == (BACKGROUND_ID, BOX_ID)
        self._obj = o3d.t.geometry.RaycastingScene(nthreads=self.nthreads)
        self._obj.add_triangles(
            o3d.core.Tensor.from_numpy(np.ascontiguousarray(obj.vertices, np.float32)),
            o3d.core.Tensor.from_numpy(np.ascontiguousarray(obj.faces, np.uint32)),
        )
        self._corner_normals = obj.corner_normals() if normals == "interpolated" else None
        self._centres = None
        if normals == "radial":  # the centre of each shell's bounding box, per face
            centres = np.array([b.mean(0) for b in obj.shell_bounds()])
            shell = obj.face_medium if obj.media is not None else np.zeros(len(obj.faces), np.int64)
            self._centres = centres[shell]

    # ------------------------------------------------------------------ casting
    def cast_background(self, origins: np.ndarray, directions: np.ndarray) -> BackgroundHit:
        """First hit on the background or the box.

        A hit on the back side of the background surface (seen from where the camera is not)
        counts as unobserved.

        Args:
            origins: ``(N, 3)`` ray origins.
            directions: ``(N, 3)`` ray directions.

        Returns:
            The :class:`BackgroundHit` of each ray.
        """
        n = len(origins)
        if n == 0:
            return BackgroundHit(
                np.zeros(0), np.zeros(0, np.int8), np.zeros((0, 3)), np.zeros(0, bool), np.zeros((0, 3))
            )
        r = self._bg.cast_rays(o3d_rays(origins, directions), nthreads=self.nthreads)
        t = r["t_hit"].numpy().astype(np.float64)
        gid = r["geometry_ids"].numpy()
        fn = r["primitive_normals"].numpy().astype(np.float64)
        hit = np.isfinite(t)
        kind = np.full(n, HitKind.ESCAPED, np.int8)
        front = dot_rows(fn, directions) < 0  # depth-mesh faces are wound to face the camera
        kind[hit & (gid == BACKGROUND_ID) & front] = HitKind.OBSERVED
        kind[hit & ((gid == BOX_ID) | ((gid == BACKGROUND_ID) & ~front))] = HitKind.UNOBSERVED
        point = np.where(hit[:, None], origins + np.where(hit, t, 0.0)[:, None] * directions, np.nan)
        return BackgroundHit(np.where(hit, t, np.inf), kind, point, hit & (gid == BOX_ID), fn)

    def cast_object(self, origins: np.ndarray, directions: np.ndarray) -> dict[str, np.ndarray]:
        """First hit on the object.

        Args:
            origins: ``(N, 3)`` ray origins.
            directions: ``(N, 3)`` ray directions.

        Returns:
            ``t`` (inf if none), ``face``, ``uv`` (barycentrics) and ``normal`` (outward face
            normal) of each ray's hit.
        """
        r = self._obj.cast_rays(o3d_rays(origins, directions), nthreads=self.nthreads)
        return {
            "t": r["t_hit"].numpy().astype(np.float64),
            "face": r["primitive_ids"].numpy().astype(np.int64),
            "uv": r["primitive_uvs"].numpy().astype(np.float64),
            "normal": r["primitive_normals"].numpy().astype(np.float64),
        }

    def shading_normals(
        self, face: np.ndarray, uv: np.ndarray, face_normal: np.ndarray, points: np.ndarray | None = None
    ) -> np.ndarray:
        """Outward unit shading normals at hits.

        Args:
            face: ``(N,)`` face indices.
            uv: ``(N, 2)`` barycentrics ``(u, v)`` in those faces.
            face_normal: ``(N, 3)`` outward face normals (returned as they are with
                ``normals="face"``, and where the interpolated normal vanishes).
            points: ``(N, 3)`` the hit points (``normals="radial"`` needs them).

        Returns:
            ``(N, 3)`` unit normals.
        """
        if self._centres is not None:
            r = np.asarray(points, np.float64) - self._centres[face]
            norm = np.linalg.norm(r, axis=-1, keepdims=True)
            return np.where(norm > 1e-12, r / np.maximum(norm, 1e-300), face_normal)
        if self._corner_normals is None:
            return face_normal
        cn = self._corner_normals[face]  # (N, 3, 3)
        w = np.stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], -1)
        n = np.einsum("nc,ncd->nd", w, cn)
        norm = np.linalg.norm(n, axis=-1, keepdims=True)
        return np.where(norm > 1e-12, n / np.maximum(norm, 1e-300), face_normal)

    def visible_from_camera(self, points: np.ndarray, rel_tol: float = 1e-3) -> np.ndarray:
        """Whether background points are seen by the camera (not hidden behind other background).

        Args:
            points: ``(N, 3)`` points (camera frame).
            rel_tol: a camera ray may stop this fraction of the distance short of the point.

        Returns:
            ``(N,)`` bool (False for non-finite points and the camera centre).
        """
        dist = np.linalg.norm(points, axis=-1)
        ok = np.isfinite(dist) & (dist > 0)
        out = np.zeros(len(points), bool)
        if ok.any():
            d = points[ok] / dist[ok, None]
            hit = self.cast_background(np.zeros_like(d), d)
            out[ok] = hit.t >= dist[ok] * (1.0 - rel_tol)
        return out

    def unoccluded_from(self, origin: np.ndarray, points: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        """Whether background points are seen from ``origin`` through the glass-free scene.

        A straight ray is cast from ``origin`` towards each point, against the background and the
        box (not the object). The point is seen unless the ray hits something more than ``tol``
        before it, or ``origin`` is behind the surface at the point (it would see the back side of
        the depth mesh, the inside of whatever solid I⁻ shows the front of). A ray that slips past
        the point (a hit beyond it: a ray aimed at a mesh vertex may pass between its triangles)
        has nothing in front of it.

        Tolerance (from float32 rounding, ``u = 2⁻²⁴``): the point ``p`` is exact (a float32 mesh
        vertex); rounding the origin ``c`` and the unit direction to float32 moves the ray across
        itself by at most ``√3 u (|c| + |p - c|)`` at ``p``, and Embree's float32 intersection adds a
        few ulps of the coordinates, together below ``8 u (|c| + |p|)``. Along the ray that becomes
        that over ``|n · r|``, the sine of the angle between the ray and the triangle it hits; with
        a factor 2 of margin, ``tol = 16 u (|c| + |p|) / max(|n · r|, 2⁻⁶)`` (grazing hits, below
        about 0.9°, get the cap: at most ``1024 u (|c| + |p|)``, about ``6e-5 (|c| + |p|)``).

        Args:
            origin: ``(3,)`` the viewpoint (camera frame).
            points: ``(N, 3)`` finite background points.
            normals: ``(N, 3)`` normals of the surface at the points, on its front side (the side
                the camera sees; zero where unknown); ``None``: the side is that of the triangle the
                ray hits at the point (unknown where it slips past).

        Returns:
            ``(N,)`` bool (False for non-finite points and points at ``origin``).
        """
        c = np.asarray(origin, np.float64).reshape(3)
        p = np.asarray(points, np.float64)
        v = p - c
        dist = np.sqrt(dot_rows(v, v))
        ok = np.isfinite(dist) & (dist > 0)
        out = np.zeros(len(v), bool)
        if not ok.any():
            return out
        r = dist[ok]
        d = v[ok] / r[:, None]
        hit = self._bg.cast_rays(o3d_rays(np.broadcast_to(c, d.shape), d), nthreads=self.nthreads)
        t = hit["t_hit"].numpy()  # float32, inf where nothing is hit
        cos = dot_rows(hit["primitive_normals"].numpy().astype(np.float64), d)
        scale = float(np.linalg.norm(c)) + np.sqrt(dot_rows(p[ok], p[ok]))
        tol = 16.0 * 2.0**-24 * scale / np.maximum(np.abs(cos), 2.0**-6)
        seen = t >= r - tol
        if normals is None:  # the side of the triangle hit at the point (faces wound towards the camera)
            at = seen & (t <= r + tol)
            seen &= ~at | ((hit["geometry_ids"].numpy() == BACKGROUND_ID) & (cos < 0))
        else:
            seen &= dot_rows(np.asarray(normals, np.float64)[ok], d) <= 0  # zero normal: unknown, seen
        out[ok] = seen
        return out

    # ------------------------------------------------------------------ one interaction
    def _interact(
        self, d: np.ndarray, ns: np.ndarray, ng: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:func:`~snell_bench.optics.functional.interact` between the object (``obj.ior``) and the air
        around it (IOR 1)."""
        from_inside = dot_rows(d, ng) > 0
        ior = self.obj.ior
        return interact(d, ns, ng, np.where(from_inside, ior, 1.0), np.where(from_inside, 1.0, ior))

    # ------------------------------------------------------------------ full trace
    def trace(
        self, origins: np.ndarray, directions: np.ndarray, start_inside: bool = False, from_light: bool = False
    ) -> RefractionTrace:
        """Trace rays that start outside the object and are known to hit it first (or, with
        ``start_inside``, rays that start inside it, just off its surface).

        Each ray refracts in, bounces (refraction out, total internal reflection, re-entry for
        non-convex shapes) until it leaves the object for the background, or until
        ``max_bounces`` interactions (then it is marked ``TRAPPED``). Its length inside the object
        is summed over the segments it travels there (``path_length``; a segment starts ``eps``
        off the surface, so the sum is short by at most ``eps`` per segment).

        Args:
            origins: ``(N, 3)`` ray origins outside the object (inside with ``start_inside``).
            directions: ``(N, 3)`` ray directions (normalised here).
            start_inside: the rays start inside the object (one medium only): the first
                segment counts in ``path_length`` and the first interface in
                ``interface_transmission``, as any later one.
            from_light: the rays carry a light's light: fill ``adjoint`` and the :class:`ExitRecord`
                (camera rays need neither; they cost about 15 %).

        Returns:
            The :class:`RefractionTrace`.
        """
        if self.obj.media is not None:  # several media: the medium stack (optics.media)
            if start_inside:
                raise ValueError("start_inside traces one medium; an object of several media starts from outside")
            return trace_nested(self, origins, directions)
        o = np.asarray(origins, np.float64).copy()
        d = np.asarray(directions, np.float64)
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        N = len(o)
        res = RefractionTrace.empty(N)
        res.exit = ExitRecord.empty(N) if from_light else None
        inside = np.full(N, bool(start_inside))
        active = np.arange(N)
        for it in range(self.max_bounces + 1):
            if len(active) == 0:
                break
            oa, da = o[active], d[active]
            ho = self.cast_object(oa, da)
            hb = self.cast_background(oa, da)
            hit_obj = np.isfinite(ho["t"]) & (ho["t"] < hb.t)
            seg = np.where(hit_obj, ho["t"], hb.t)  # to the next surface: the object's or the background's
            res.path_length[active] += np.where(inside[active] & np.isfinite(seg), seg, 0.0)
            end_rays(res, active[~hit_obj], inside, hb, ~hit_obj, oa, da)
            act = active[hit_obj]
            if len(act) == 0:
                active = act
                break
            if it == self.max_bounces:
                res.kind[act] = HitKind.TRAPPED
                res.origin[act] = o[act]
                res.direction[act] = d[act]
                break
            t = ho["t"][hit_obj]
            p = oa[hit_obj] + t[:, None] * da[hit_obj]
            ng = ho["normal"][hit_obj]
            ns = self.shading_normals(ho["face"][hit_obj], ho["uv"][hit_obj], ng, p)
            d_new, goes_inside, R, mirror, nf = self._interact(d[act], ns, ng)
            if it == 0:  # the first surface (for a trace from inside: an interface like any other, too)
                res.first_point[act] = p
                res.first_normal[act] = nf
                res.first_geometric_normal[act] = ng
                res.fresnel[act] = R
                res.reflected[act] = mirror
            if from_light:  # an exit's record (the running products before it), then the adjoint factor
                out = inside[act] & ~goes_inside
                res.exit.record(act[out], out, res, p, ng, nf, mirror, R)
                res.adjoint[act] *= adjoint_correction(d[act], d_new, nf, ng)
            if it > 0 or start_inside:  # a later interface: the refracted path keeps 1 - R where it crosses
                res.interface_transmission[act] *= np.where(goes_inside != inside[act], 1.0 - R, 1.0)
            side = np.where(goes_inside, -1.0, 1.0)
            o[act] = p + (self.eps * side)[:, None] * ng
            d[act] = d_new
            inside[act] = goes_inside
            res.bounces[act] += 1
            active = act
        res.optical_depth = res.path_length[:, None] * np.asarray(self.obj.absorption, np.float64)
        return res

    def trace_reflection(self, trace: RefractionTrace) -> BackgroundHit:
        """Cast the first-bounce mirror rays of a trace against the background.

        The object itself is not hit again (first-bounce reflection only).

        Args:
            trace: the result of :meth:`trace`.

        Returns:
            The :class:`BackgroundHit` of each mirror ray (``t = inf``, kind ``NONE`` for rays
            that never hit the object).
        """
        ok = np.isfinite(trace.first_point).all(axis=1)
        out = BackgroundHit(
            np.full(len(ok), np.inf), np.zeros(len(ok), np.int8), np.full((len(ok), 3), np.nan), np.zeros(len(ok), bool)
        )
        if ok.any():
            ng = trace.first_geometric_normal[ok]
            side = np.where(dot_rows(trace.reflected[ok], ng) >= 0, 1.0, -1.0)
            o = trace.first_point[ok] + (self.eps * side)[:, None] * ng
            h = self.cast_background(o, trace.reflected[ok])
            out.t[ok], out.kind[ok], out.point[ok], out.on_box[ok] = h.t, h.kind, h.point, h.on_box
        return out

    def cast_camera_object(self, directions: np.ndarray) -> np.ndarray:
        """Distance to the object along camera rays.

        Args:
            directions: ``(N, 3)`` ray directions from the camera centre.

        Returns:
            ``(N,)`` distances in units of ``|direction|`` (inf where the object is missed).
        """
        return self.cast_object(np.zeros_like(directions), directions)["t"]
