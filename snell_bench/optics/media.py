"""Rays through an object of several media (:meth:`~snell_bench.scene.objects.GlassObject.nested`):
a glass of water, a straw in it, a hollow vessel.

Convention:
    - Each closed shell of the object holds one :class:`~snell_bench.config.materials.Medium`;
      a ray carries the set of shells it is inside (a bitmask, shell ``s`` its bit ``s``). The
      medium it travels in is the one of highest priority among them (ties: the shell listed later),
      air (IOR 1, no absorption) when it is in none.
    - At a hit on shell ``s`` (entering it where the ray meets its face's front, leaving it at its
      back) the set after the surface toggles ``s``. Where that does not change the medium the ray
      travels in (a shell of lower priority than the current medium), the surface is no interface:
      the ray goes straight on. Otherwise it refracts between the two media's IORs, or reflects
      totally, keeping its set (:func:`~snell_bench.optics.functional.interact`).
    - ``max_bounces`` counts the interfaces a ray meets (refractions and reflections), not the false
      ones: a ray that meets the object's surface again after ``max_bounces`` interfaces is trapped. A ray is also
      trapped after ``(max_bounces + 1) * (shells + 1)`` surfaces of any kind.
    - ``path_length`` sums the segments travelled in any shell's medium; ``optical_depth`` the
      segments times that medium's absorption (``exp(-optical_depth)`` is the transmittance).
"""

from __future__ import annotations

import numpy as np

from snell_bench.optics.functional import interact
from snell_bench.optics.trace_types import HitKind, RefractionTrace, dot_rows, end_rays

__all__ = ["current_medium", "interface_faces", "trace_nested"]


def current_medium(inside: np.ndarray, priority: np.ndarray) -> np.ndarray:
    """The medium each ray travels in: ``(N,)`` index of the highest-priority shell whose bit is set
    in ``inside`` (ties: the later shell), ``-1`` (air) where none is.

    Examples:
        >>> current_medium(np.array([0b00, 0b01, 0b11, 0b10]), np.array([0, 1]))
        array([-1,  0,  1,  1])
    """
    best = np.full(inside.shape, -1, np.int64)
    best_p = np.full(inside.shape, np.iinfo(np.int64).min)
    for s, p in enumerate(priority):
        take = ((inside >> s) & 1).astype(bool) & (p >= best_p)
        best = np.where(take, s, best)
        best_p = np.where(take, p, best_p)
    return best


def interface_faces(obj) -> tuple[np.ndarray, np.ndarray]:
    """The media on the two sides of each face of an object of several media: ``(behind, front)``,
    each ``(F,)`` int64 (a shell's index into ``obj.media``, ``-1``: air); ``behind`` is the side
    inside the face's own shell (against its normal). Where the two are equal the face is no
    interface (a shell of lower priority inside another, the water inside a glass's wall).

    Each face is probed at its centroid and near each corner (a tenth of the way to the centroid),
    against every other shell (Open3D's signed distance: its sign says inside). The shells may
    overlap, nest or sit side by side, but a face must separate the same two media all over it.

    Raises:
        ValueError: a face crosses another shell's surface (mesh the shells so that their surfaces
            meet along shared edges, as :func:`~snell_bench.scene.vessels.glass_of_water` does), or
            lies on it (two coincident surfaces: let one shell overlap the other instead).

    Examples:
        Glass, then a water core of higher priority, then one of lower priority than the water:

        >>> import trimesh
        >>> from snell_bench.config.materials import Medium
        >>> from snell_bench.scene.objects import GlassObject
        >>> balls = [trimesh.creation.icosphere(2, radius=r) for r in (3.0, 2.0, 1.0)]
        >>> media = [Medium(1.5), Medium(1.33, priority=2), Medium(1.4, priority=1)]
        >>> obj = GlassObject.nested(list(zip(balls, media)), placed=True)
        >>> behind, front = interface_faces(obj)
        >>> sorted({(int(b), int(f)) for b, f in zip(behind, front)})  # the core's surface: water on both sides
        [(0, -1), (1, 0), (1, 1)]
    """
    import open3d as o3d

    v, faces, shell = np.asarray(obj.vertices, np.float64), np.asarray(obj.faces), obj.face_medium
    tri = v[faces]
    centroid = tri.mean(1)
    probes = np.concatenate([centroid[None], 0.9 * tri.transpose(1, 0, 2) + 0.1 * centroid[None]])  # (4, F, 3)
    tol = 1e-6 * float(np.linalg.norm(v.max(0) - v.min(0)))
    others = np.zeros(probes.shape[:2], np.int64)  # bit s: the probe is inside shell s (s not the face's own)
    for s in range(len(obj.media)):
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(
            o3d.core.Tensor.from_numpy(np.ascontiguousarray(v, np.float32)),
            o3d.core.Tensor.from_numpy(np.ascontiguousarray(faces[shell == s], np.uint32)),
        )
        pts = o3d.core.Tensor.from_numpy(np.ascontiguousarray(probes.reshape(-1, 3), np.float32))
        sd = scene.compute_signed_distance(pts, nsamples=3).numpy().reshape(probes.shape[:2]).astype(np.float64)
        foreign = shell != s
        on = foreign[None] & (np.abs(sd) <= tol)
        if on.any():
            f = int(np.flatnonzero(on.any(0))[0])
            raise ValueError(
                f"face {f} of shell {int(shell[f])} lies on the surface of shell {s}: two shells share a surface; "
                "let one overlap the other and give it the higher priority"
            )
        others |= np.where(foreign[None] & (sd < 0), np.int64(1) << s, 0)
    own = np.left_shift(np.int64(1), shell)
    priority = np.array([m.priority for m in obj.media], np.int64)
    behind = current_medium(others | own, priority)
    front = current_medium(others & ~own, priority)
    split = ((behind != behind[0]) | (front != front[0])).any(0)
    if split.any():
        f = int(np.flatnonzero(split)[0])
        crossed = int(np.bitwise_or.reduce(others[:, f]) & ~np.bitwise_and.reduce(others[:, f]))
        names = [s for s in range(len(obj.media)) if crossed >> s & 1]
        raise ValueError(
            f"face {f} of shell {int(shell[f])} crosses the surface of shell {names}: a face must separate the "
            "same two media all over it; mesh the shells so that their surfaces meet along shared edges"
        )
    return behind[0], front[0]


def _tables(obj) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IOR ``(S + 1,)``, absorption ``(S + 1, 3)`` and priority ``(S,)`` of the object's media; the
    last row of the first two is air (index -1)."""
    ior = np.array([m.ior for m in obj.media] + [1.0], np.float64)
    sigma = np.array([m.absorption for m in obj.media] + [(0.0, 0.0, 0.0)], np.float64)
    return ior, sigma, np.array([m.priority for m in obj.media], np.int64)


def trace_nested(tracer, origins: np.ndarray, directions: np.ndarray, record: list | None = None):
    """:meth:`SceneTracer.trace` for an object of several media (module convention).

    Args:
        tracer: the scene's :class:`~snell_bench.optics.tracer.SceneTracer`; its object has ``media``.
        origins: ``(N, 3)`` ray origins outside the object.
        directions: ``(N, 3)`` ray directions (normalised here).
        record: a list to append each step's ``(rays, origins, directions, medium)`` to (the rays
            still travelling, where their segments start, and the medium each travels in).

    Returns:
        The :class:`~snell_bench.optics.tracer.RefractionTrace`, with ``optical_depth`` ``(N, 3)``
        set on it.
    """
    obj = tracer.obj
    ior, sigma, priority = _tables(obj)
    o = np.asarray(origins, np.float64).copy()
    d = np.asarray(directions, np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    res = RefractionTrace.empty(len(o))
    res.optical_depth = np.zeros((len(o), 3))
    inside = np.zeros(len(o), np.int64)  # bitmask of the shells each ray is in
    active = np.arange(len(o))
    limit = (tracer.max_bounces + 1) * (len(obj.media) + 1)
    for it in range(limit):
        if len(active) == 0:
            break
        oa, da = o[active], d[active]
        cur = current_medium(inside[active], priority)
        if record is not None:
            record.append((active.copy(), oa.copy(), da.copy(), cur))
        ho, hb = tracer.cast_object(oa, da), tracer.cast_background(oa, da)
        hit_obj = np.isfinite(ho["t"]) & (ho["t"] < hb.t)
        seg = np.where(hit_obj, ho["t"], hb.t)
        seg = np.where((cur >= 0) & np.isfinite(seg), seg, 0.0)
        res.path_length[active] += seg
        res.optical_depth[active] += seg[:, None] * sigma[cur]
        end_rays(res, active[~hit_obj], inside != 0, hb, ~hit_obj, oa, da)
        act = active[hit_obj]
        trapped = (res.bounces[act] >= tracer.max_bounces) | (it == limit - 1)
        res.kind[act[trapped]] = HitKind.TRAPPED
        res.origin[act[trapped]], res.direction[act[trapped]] = o[act[trapped]], d[act[trapped]]
        keep = ~trapped
        act = act[keep]
        if len(act) == 0:
            break
        hit_obj[hit_obj] = keep
        _cross(
            tracer,
            res,
            it,
            act,
            oa[hit_obj] + ho["t"][hit_obj, None] * da[hit_obj],
            ho,
            hit_obj,
            o,
            d,
            inside,
            ior,
            priority,
        )
        active = act
    return res


def _cross(tracer, res, it, act, p, ho, hit_obj, o, d, inside, ior, priority) -> None:
    """The rays ``act`` meet the object's surface at ``p``: a false interface, a refraction or a
    total reflection between the media on its two sides (module convention); ``o``, ``d`` and
    ``inside`` updated in place, the first surface recorded in ``res``."""
    ng = ho["normal"][hit_obj]
    face = ho["face"][hit_obj]
    ns = tracer.shading_normals(face, ho["uv"][hit_obj], ng, p)
    shell = tracer.obj.face_medium[face]
    bit = np.left_shift(np.int64(1), shell)
    da, mask = d[act], inside[act]
    entering = dot_rows(da, ng) < 0
    after = np.where(entering, mask | bit, mask & ~bit)
    before_m, after_m = current_medium(mask, priority), current_medium(after, priority)
    d_new, goes_inside, R, mirror, nf = interact(da, ns, ng, ior[before_m], ior[after_m])
    false = before_m == after_m  # no interface: straight on, into (or out of) the shell
    crossed = false | (goes_inside == entering)
    d_new = np.where(false[:, None], da, d_new)
    goes_inside = np.where(false, entering, goes_inside)
    if it == 0:
        res.first_point[act], res.first_normal[act], res.first_geometric_normal[act] = p, nf, ng
        res.fresnel[act] = np.where(false, 0.0, R)
        res.reflected[act] = mirror
    else:
        res.interface_transmission[act] *= np.where(crossed & ~false, 1.0 - R, 1.0)
    side = np.where(goes_inside, -1.0, 1.0)
    o[act] = p + (tracer.eps * side)[:, None] * ng
    d[act] = d_new
    inside[act] = np.where(crossed, after, mask)
    res.bounces[act] += ~false
