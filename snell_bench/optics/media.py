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
    - Every surface met counts towards ``max_bounces``, false interfaces included.
    - ``path_length`` sums the segments travelled in any shell's medium; ``optical_depth`` the
      segments times that medium's absorption (``exp(-optical_depth)`` is the transmittance).
"""

from __future__ import annotations

import numpy as np

from snell_bench.optics.functional import interact
from snell_bench.optics.trace_types import HitKind, RefractionTrace, dot_rows, end_rays

__all__ = ["trace_nested", "current_medium", "nested_interfaces"]


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


def nested_interfaces(obj) -> list[tuple[int, int, int]]:
    """The interfaces of an object whose shells each lie inside the one before (listed outermost
    first, as a glass of water): ``(shell, medium inside, medium outside)`` per shell whose surface
    separates two media (``-1``: air); a shell of lower priority than its container is no interface
    and is left out.

    Raises:
        ValueError: a shell's bounding box is not inside the previous shell's (shells that overlap or
            sit side by side have no single medium outside them).

    Examples:
        Glass, then water of higher priority, then a core of lower priority than the water:

        >>> from types import SimpleNamespace
        >>> from snell_bench.config.materials import Medium
        >>> boxes = [np.array([[-s, -s, -s], [s, s, s]]) for s in (3.0, 2.0, 1.0)]
        >>> obj = SimpleNamespace(media=(Medium(1.5), Medium(1.33, priority=2), Medium(1.4, priority=1)),
        ...                       shell_bounds=lambda: boxes)
        >>> nested_interfaces(obj)
        [(0, 0, -1), (1, 1, 0)]
    """
    bounds = obj.shell_bounds()
    for k in range(1, len(bounds)):
        (lo, hi), (plo, phi) = bounds[k], bounds[k - 1]
        if not ((lo >= plo).all() and (hi <= phi).all()):
            raise ValueError(
                f"shell {k} of the object is not inside shell {k - 1}: list the shells outermost first, each "
                "inside the one before (a glass of water)"
            )
    priority = np.array([m.priority for m in obj.media], np.int64)
    out = []
    for k in range(len(obj.media)):
        outside = int(current_medium(np.array([(1 << k) - 1]), priority)[0])
        inside = int(current_medium(np.array([(1 << (k + 1)) - 1]), priority)[0])
        if inside != outside:
            out.append((k, inside, outside))
    return out


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
    for it in range(tracer.max_bounces + 1):
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
        if len(act) == 0 or it == tracer.max_bounces:
            res.kind[act] = HitKind.TRAPPED
            res.origin[act], res.direction[act] = o[act], d[act]
            break
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
    ns = tracer.shading_normals(face, ho["uv"][hit_obj], ng)
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
    side = np.where(goes_inside, -1.0, 1.0)
    o[act] = p + (tracer.eps * side)[:, None] * ng
    d[act] = d_new
    inside[act] = np.where(crossed, after, mask)
    res.bounces[act] += 1
