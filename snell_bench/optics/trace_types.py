"""What the tracer returns (:mod:`snell_bench.optics.tracer`, :mod:`snell_bench.optics.media`): the
kinds of ray ends, background hits and refracted paths, and the helpers both tracers share."""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
import open3d as o3d

__all__ = ["HitKind", "BackgroundHit", "ExitRecord", "RefractionTrace"]


class HitKind(enum.IntEnum):
    """What a traced ray ends on (stored as int8 in arrays).

    Examples:
        >>> int(HitKind.OBSERVED), HitKind(3).name
        (1, 'ESCAPED')
    """

    NONE = 0  #: not traced (e.g. a pixel that does not see the object)
    OBSERVED = 1  #: the front side of the background surface, which I⁻ observes
    UNOBSERVED = 2  #: the box of unobserved space, or the back side of the background surface
    ESCAPED = 3  #: nothing at all (the ray leaves the scene's box: only numerically possible)
    TRAPPED = 4  #: still bouncing in the object after ``max_bounces`` interactions
    LOST = 5  #: inside the object and hits nothing (a crack in an open mesh)


BACKGROUND_ID, BOX_ID = 0, 1


@dataclass
class BackgroundHit:
    """Result of casting rays against the background and the box (one row per ray;
    :meth:`SceneTracer.cast_background`)."""

    t: np.ndarray  # (N,) distance, inf where nothing is hit
    kind: np.ndarray  # (N,) int8 HitKind: OBSERVED, UNOBSERVED or ESCAPED
    point: np.ndarray  # (N, 3) hit point, NaN where nothing is hit
    on_box: np.ndarray  # (N,) bool: the hit is on the box of unobserved space (not the depth mesh)
    normal: np.ndarray | None = None  # (N, 3) unit face normal of the hit (depth mesh: towards the camera)


@dataclass
class ExitRecord:
    """The last interface where each traced path left the object (NaN / 0 / 1 where it never did):
    where the light that the exit reflects back inside (Fresnel ``R``) starts, and what the light
    carried to it. One row per ray; filled by the one-medium tracer."""

    point: np.ndarray  # (N, 3) the exit point
    geometric_normal: np.ndarray  # (N, 3) its outward face normal
    shading_normal: np.ndarray  # (N, 3) the shading normal used there, facing the arriving ray
    mirror: np.ndarray  # (N, 3) the mirror direction back into the object
    fresnel: np.ndarray  # (N,) the Fresnel reflectance there
    path_length: np.ndarray  # (N,) the path's length inside before it
    transmission: np.ndarray  # (N,) ``interface_transmission`` before it
    adjoint: np.ndarray  # (N,) ``adjoint`` before it

    @classmethod
    def empty(cls, n: int) -> ExitRecord:
        nan3 = np.full((n, 3), np.nan)
        return cls(nan3.copy(), nan3.copy(), nan3.copy(), nan3.copy(), np.zeros(n), np.zeros(n), np.ones(n), np.ones(n))

    def record(self, rows: np.ndarray, sel: np.ndarray, trace: RefractionTrace, *step: np.ndarray) -> None:
        """Store the rows ``rows`` of a tracer step (``sel`` of its arrays ``point``,
        ``geometric_normal``, ``shading_normal``, ``mirror``, ``fresnel``, in that order) with
        ``trace``'s running products."""
        for name, values in zip(
            ("point", "geometric_normal", "shading_normal", "mirror", "fresnel"), step, strict=True
        ):
            getattr(self, name)[rows] = values[sel]
        self.path_length[rows] = trace.path_length[rows]
        self.transmission[rows] = trace.interface_transmission[rows]
        self.adjoint[rows] = trace.adjoint[rows]


@dataclass
class RefractionTrace:
    """Result of tracing camera rays through the object (one row per ray; :meth:`SceneTracer.trace`)."""

    kind: np.ndarray  # (N,) int8 HitKind of where the final ray ends
    on_box: np.ndarray  # (N,) bool: it ends on the box of unobserved space
    origin: np.ndarray  # (N, 3) origin of the final ray (its last surface point)
    direction: np.ndarray  # (N, 3) unit direction of the final ray
    point: np.ndarray  # (N, 3) where the final ray ends, NaN if nowhere
    bounces: np.ndarray  # (N,) int16 surface interactions (entry, TIR, exit, re-entries)
    first_point: np.ndarray  # (N, 3) first surface point
    first_normal: np.ndarray  # (N, 3) unit shading normal there, facing the camera ray
    first_geometric_normal: np.ndarray  # (N, 3) outward face normal there
    fresnel: np.ndarray  # (N,) Fresnel reflectance at the first surface
    reflected: np.ndarray  # (N, 3) unit mirror direction at the first surface
    #: (N,) length of the path inside the object (over internal reflections and re-entries, up to
    #: where it leaves, ends on the background inside the glass, or is trapped), in scene units
    path_length: np.ndarray | None = None
    #: (N, 3) the path's length in each medium times that medium's absorption σ (linear R, G, B):
    #: its transmittance is ``exp(-optical_depth)``
    optical_depth: np.ndarray | None = None
    #: (N,) product of ``1 - R`` over the interfaces crossed after the first (TIR: 1; a trace that
    #: starts inside the object: over every interface it crosses)
    interface_transmission: np.ndarray | None = None
    #: (N,) product of the adjoint shading-normal factors over the path's interactions
    #: (:func:`~snell_bench.optics.functional.adjoint_correction`): what light traced from a light
    #: source along the path carries (1 on flat faces; 1 for camera rays, which do not use it)
    adjoint: np.ndarray | None = None
    #: the last exit of each path (:class:`ExitRecord`; ``None``: not recorded: camera rays, several media)
    exit: ExitRecord | None = None

    @classmethod
    def empty(cls, n: int) -> RefractionTrace:
        """``n`` rays not traced yet: kind NONE, no bounce, NaN points and directions, zero lengths."""
        nan3 = np.full((n, 3), np.nan)
        return cls(
            kind=np.zeros(n, np.int8),
            on_box=np.zeros(n, bool),
            origin=nan3.copy(),
            direction=nan3.copy(),
            point=nan3.copy(),
            bounces=np.zeros(n, np.int16),
            first_point=nan3.copy(),
            first_normal=nan3.copy(),
            first_geometric_normal=nan3.copy(),
            fresnel=np.zeros(n),
            reflected=nan3.copy(),
            path_length=np.zeros(n),
            interface_transmission=np.ones(n),
            adjoint=np.ones(n),
        )


def o3d_rays(origins: np.ndarray, directions: np.ndarray) -> o3d.core.Tensor:
    rays = np.empty((len(origins), 6), np.float32)
    rays[:, :3] = origins
    rays[:, 3:] = directions
    return o3d.core.Tensor.from_numpy(rays)


def dot_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", a, b)


def end_rays(res: RefractionTrace, end: np.ndarray, inside: np.ndarray, hb: BackgroundHit, sel, oa, da) -> None:
    """Record the rays ``end`` (rows ``sel`` of this step's casts) that end here: on the background,
    the box, or nowhere (``LOST`` when they were inside the object)."""
    if not len(end):
        return
    k = hb.kind[sel].copy()
    k[inside[end] & (k == HitKind.ESCAPED)] = HitKind.LOST
    res.kind[end] = k
    res.on_box[end] = hb.on_box[sel]
    res.origin[end] = oa[sel]
    res.direction[end] = da[sel]
    res.point[end] = hb.point[sel]
