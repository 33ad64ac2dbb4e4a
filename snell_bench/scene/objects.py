"""Glass objects: procedural primitives and mesh files (materials: :mod:`snell_bench.config.materials`).

Convention:
    - A *canonical* object (``sphere``, ``cylinder``, ``pyramid``, ``from_file``) lives in its own
      local frame: y up, its bottom centre at the origin, its largest bounding-box side 1 (unit size).
      :func:`snell_bench.scene.placement.place_object` moves it into the camera frame.
    - A *placed* object is in camera coordinates (OpenCV frame, metres or the depth map's unit);
      :meth:`GlassObject.from_mesh` takes a mesh that is already there.
    - Faces wind counter-clockwise seen from outside, so face normals point out of the object.
    - A mesh (:meth:`GlassObject.from_file`, :meth:`GlassObject.from_mesh`) must enclose a volume
      (not flat, not sheets on top of each other), be closed (else ``allow_open``), orientable,
      and not cross itself (else ``allow_self_intersecting``); a file must hold the format its
      suffix names (:func:`sniff_mesh_format`).
    - Shading normals are per face corner (``corner_normals``): vertex normals averaged only over the
      faces whose normal is within ``crease_angle_deg`` of the corner's face, so smooth parts
      interpolate while sharp edges (a cylinder's rim, a pyramid's edges) keep their face normals.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import trimesh

from snell_bench.config.materials import CLEAR, MATERIALS, check_sigma, resolve_ior
from snell_bench.scene.mesh_checks import Crossings, _clean_mesh, self_crossings
from snell_bench.scene.mesh_format import MESH_SUFFIXES, _check_format, sniff_mesh_format

__all__ = ["MATERIALS", "Crossings", "GlassObject", "resolve_ior", "self_crossings", "sniff_mesh_format"]


def _canonicalize(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Bottom centre to the origin and the largest bounding-box side to 1 (y is up)."""
    lo, hi = mesh.bounds
    extent = float((hi - lo).max())
    if extent <= 0:
        raise ValueError("the mesh has zero extent")
    T = np.eye(4)
    T[:3, 3] = -np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    S = np.diag([1 / extent] * 3 + [1.0])
    mesh = mesh.copy()
    mesh.apply_transform(S @ T)
    return mesh


_Z_TO_Y_UP = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=float)


@dataclass(frozen=True, eq=False)
class GlassObject:
    """A closed triangle mesh of a transparent material.

    Attributes:
        mesh: the surface (see the module's conventions for its frame).
        ior: index of refraction of the material (the surroundings are air, IOR 1).
        absorption: σ, the material's absorption coefficients per metre of the mesh's units (linear
            R, G, B; :func:`~snell_bench.config.materials.absorption_coefficients`): a path of length
            ``L`` inside transmits ``exp(-σ L)``. ``(0, 0, 0)``: clear.
        media: an object of several closed shells (:meth:`nested`): the medium of each shell, the
            first the outermost (``ior`` and ``absorption`` are its); ``None``: one material.
        face_medium: ``(F,)`` the shell (index into ``media``) each face bounds, with ``media``.
        name: a short label (``sphere``, a file stem, ...).
        placed: whether ``mesh`` is in camera coordinates.
        up: the scene's up direction in camera coordinates, set by placement (``None`` if unknown).
        crease_angle_deg: faces meeting at a sharper angle than this do not share shading normals.
        pose: ``(4, 4)`` float64, the transform that took the canonical object (as its constructor
            built it) to ``mesh`` (:meth:`transformed` composes it; camera from object once placed),
            or None for a mesh given already placed.
    """

    mesh: trimesh.Trimesh
    ior: float = 1.5
    name: str = "object"
    placed: bool = False
    up: np.ndarray | None = None
    crease_angle_deg: float = 30.0
    absorption: tuple[float, float, float] = CLEAR
    media: tuple | None = None
    face_medium: np.ndarray | None = field(default=None, repr=False, compare=False)
    pose: np.ndarray | None = field(default=None, repr=False, compare=False)
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "ior", resolve_ior(self.ior))
        object.__setattr__(self, "absorption", check_sigma(self.absorption))
        if self.media is not None:
            fm = np.asarray(self.face_medium, np.int64) if self.face_medium is not None else None
            if fm is None or fm.shape != (len(self.mesh.faces),) or fm.min() < 0 or fm.max() >= len(self.media):
                raise ValueError("an object of several media needs face_medium: one index into media per face")
            if len(self.media) > 62:
                raise ValueError(f"at most 62 shells in one object, got {len(self.media)}")
            object.__setattr__(self, "face_medium", fm)
        if self.up is not None:
            up = np.asarray(self.up, np.float64).reshape(3)
            object.__setattr__(self, "up", up / np.linalg.norm(up))
        if not (0.0 <= self.crease_angle_deg <= 180.0):
            raise ValueError(f"crease_angle_deg must be in [0, 180], got {self.crease_angle_deg}")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def sphere(cls, ior: str | float = "glass", subdivisions: int = 5) -> GlassObject:
        """Unit-diameter icosphere (``subdivisions=5``: 20,480 faces)."""
        m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.5)
        return cls(mesh=_canonicalize(m), ior=ior, name="sphere")

    @classmethod
    def cylinder(cls, ior: str | float = "glass", radius: float = 0.35, sections: int = 128) -> GlassObject:
        """Upright cylinder of height 1 before normalisation (``radius`` relative to the height)."""
        m = trimesh.creation.cylinder(radius=radius, height=1.0, sections=sections)
        m.apply_transform(_Z_TO_Y_UP)
        return cls(mesh=_canonicalize(m), ior=ior, name="cylinder")

    @classmethod
    def pyramid(cls, ior: str | float = "glass", base: float = 1.0, height: float = 1.0) -> GlassObject:
        """Square pyramid (a 4-sided cone, the edges of its base along the diagonals)."""
        m = trimesh.creation.cone(radius=base / math.sqrt(2.0), height=height, sections=4)
        m.apply_transform(_Z_TO_Y_UP)
        return cls(mesh=_canonicalize(m), ior=ior, name="pyramid")

    @classmethod
    def from_file(
        cls,
        path: str | Path,
        ior: str | float = "glass",
        *,
        up_axis: str = "y",
        allow_open: bool = False,
        repair: bool = False,
        allow_self_intersecting: bool = False,
    ) -> GlassObject:
        """Any mesh trimesh reads (.ply, .obj, .glb, .stl, ...), normalised to the canonical frame.

        Vertices at the same point are merged and zero-area faces removed; the faces are wound
        outwards (a mesh wound inside-out is turned over). Refused, each with what to do: a file whose
        first bytes show another format than its suffix (:func:`sniff_mesh_format`), an empty or
        unreadable file, a mesh that encloses no volume (flat, or thinner than
        :data:`~snell_bench.scene.mesh_checks.MIN_RELATIVE_THICKNESS` of its size), an open one
        (unless ``allow_open``), a closed surface that cannot be oriented, and one that crosses itself
        (:func:`self_crossings`, unless ``allow_self_intersecting``).

        Args:
            path: the mesh file.
            ior: a material name or the index of refraction.
            up_axis: the file's up axis (``y``, ``z``, ``-y``, ...).
            allow_open: trace a mesh that is not watertight (rays may leak through its holes).
            repair: fill simple holes (trimesh's ``fill_holes``) first.
            allow_self_intersecting: trace a mesh whose surface crosses itself (rays then refract at
                its surfaces inside the glass).

        Returns:
            The canonical object, named after the file's stem.

        Raises:
            IsADirectoryError: ``path`` is a folder.
            FileNotFoundError: there is no such file.
            ValueError: the file or its mesh is refused (see above).
        """
        path = Path(path)
        if path.is_dir():
            meshes = sorted(p.name for p in path.iterdir() if p.suffix.lower() in MESH_SUFFIXES)[:5]
            raise IsADirectoryError(
                f"{path} is a folder, not a mesh file; give a file"
                + (f" (it holds {', '.join(meshes)})" if meshes else f" ({', '.join(MESH_SUFFIXES)})")
            )
        if not path.is_file():
            raise FileNotFoundError(f"mesh file not found: {path}")
        _check_format(path)
        try:
            loaded = trimesh.load(path, force="mesh", process=False)
        except Exception as e:  # trimesh raises many kinds
            first = str(e).strip().splitlines()[0][:160] if str(e).strip() else type(e).__name__
            raise ValueError(
                f"{path} could not be read as a mesh ({type(e).__name__}: {first}); the file is damaged or not a "
                f"{path.suffix or 'mesh'} file: re-export it from a mesh editor or choose another file"
            ) from e
        if not isinstance(loaded, trimesh.Trimesh) or len(getattr(loaded, "faces", [])) == 0:
            raise ValueError(
                f"{path} holds no triangle mesh (0 faces read); the file is empty, damaged or holds only points or "
                "lines: re-export it with faces"
            )
        mesh = _clean_mesh(
            loaded,
            allow_open=allow_open,
            repair=repair,
            allow_self_intersecting=allow_self_intersecting,
            what=str(path),
        )
        mesh.apply_transform(_up_axis_transform(up_axis))
        return cls(mesh=_canonicalize(mesh), ior=ior, name=path.stem)

    @classmethod
    def from_mesh(
        cls,
        vertices: np.ndarray,
        faces: np.ndarray,
        ior: str | float = "glass",
        *,
        name: str = "mesh",
        up=None,
        allow_open: bool = False,
        repair: bool = False,
        allow_self_intersecting: bool = False,
    ) -> GlassObject:
        """A mesh already in camera coordinates (placed as given), cleaned and checked as
        :meth:`from_file` does.

        Args:
            vertices: ``(V, 3)`` coordinates.
            faces: ``(F, 3)`` vertex indices.
            ior: a material name or the index of refraction.
            name: a short label.
            up: the scene's up direction in camera coordinates, if known.
            allow_open: trace a mesh that is not watertight.
            repair: fill simple holes first.
            allow_self_intersecting: trace a mesh whose surface crosses itself.

        Returns:
            The placed object.

        Raises:
            ValueError: the arrays are malformed or the mesh is refused (see :meth:`from_file`).
        """
        vertices = np.asarray(vertices, dtype=np.float64)
        faces = np.asarray(faces)
        if vertices.ndim != 2 or vertices.shape[1:] != (3,) or faces.ndim != 2 or faces.shape[1:] != (3,):
            if vertices.size == 0 or faces.size == 0:
                raise ValueError("from_mesh: the mesh is empty (0 faces); a glass object needs a closed surface")
            raise ValueError(
                f"from_mesh: expected vertices (V, 3) and faces (F, 3), got {vertices.shape} and {faces.shape}"
            )
        if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
            raise ValueError(f"from_mesh: face indices out of range [0, {len(vertices)})")
        mesh = trimesh.Trimesh(vertices=vertices, faces=faces.astype(np.int64), process=False)
        mesh = _clean_mesh(
            mesh,
            allow_open=allow_open,
            repair=repair,
            allow_self_intersecting=allow_self_intersecting,
            what="from_mesh",
        )
        return cls(mesh=mesh, ior=ior, name=name, placed=True, up=up)

    # ------------------------------------------------------------------ derived objects
    def with_ior(self, ior: str | float) -> GlassObject:
        """The same object of another IOR (of several media: its first shell's, the object's own)."""
        if self.media is not None:
            return self._with_first_medium(ior=resolve_ior(ior))
        return replace(self, ior=ior, _cache={})

    def _with_first_medium(self, **change) -> GlassObject:
        media = (replace(self.media[0], **change), *self.media[1:])
        return replace(self, media=media, ior=media[0].ior, absorption=media[0].absorption, _cache={})

    def shell_bounds(self) -> list[np.ndarray]:
        """``(2, 3)`` bounding box of each shell of a nested object (the whole mesh's otherwise)."""
        if self.media is None:
            return [np.asarray(self.mesh.bounds, np.float64)]
        v = np.asarray(self.vertices, np.float64)
        return [
            np.stack([v[f].reshape(-1, 3).min(0), v[f].reshape(-1, 3).max(0)])
            for f in (self.faces[self.face_medium == k] for k in range(len(self.media)))
        ]

    @classmethod
    def nested(cls, shells, name: str = "nested", *, placed: bool | None = None) -> GlassObject:
        """An object of several closed shells, each filled with its own medium: ``shells`` is a
        sequence of ``(GlassObject or trimesh.Trimesh, Medium)``, the outermost first, in one frame
        (placed or canonical alike; ``placed``: whether that frame is the camera's, by default the
        shells' own, and False for bare meshes). A glass of water: the vessel's shell (glass) and
        the water's; a straw: a third shell; a hollow vessel: an inner shell of air (IOR 1).

        Raises:
            ValueError: no shell, or shells some placed and some not.
        """
        if not shells:
            raise ValueError("nested needs at least one (mesh, Medium) shell")
        meshes = [s.mesh if isinstance(s, GlassObject) else s for s, _ in shells]
        frames = {s.placed for s, _ in shells if isinstance(s, GlassObject)}
        if len(frames) > 1:
            raise ValueError("nested shells must all be placed, or none")
        placed = frames == {True} if placed is None else bool(placed)
        media = tuple(m for _, m in shells)
        mesh = trimesh.util.concatenate(meshes)
        face_medium = np.concatenate([np.full(len(m.faces), i, np.int64) for i, m in enumerate(meshes)])
        outer = media[0]
        return cls(
            mesh=mesh,
            ior=outer.ior,
            absorption=outer.absorption,
            name=name,
            placed=placed,
            media=media,
            face_medium=face_medium,
        )

    def with_absorption(self, sigma) -> GlassObject:
        """The same object of a material with absorption coefficients ``sigma`` (per metre); of
        several media, its first shell's material (the object's own: a glass of water's glass)."""
        if self.media is not None:
            return self._with_first_medium(absorption=check_sigma(sigma))
        return replace(self, absorption=sigma, _cache={})

    @property
    def absorbs(self) -> bool:
        """Whether any channel is absorbed (σ > 0) by the material, or by any medium of a nested object."""
        sigmas = [self.absorption] + [m.absorption for m in self.media or ()]
        return any(s > 0.0 for sigma in sigmas for s in sigma)

    def transformed(self, matrix: np.ndarray, *, up=None) -> GlassObject:
        """Apply a 4x4 rigid or similarity transform; the result is a placed object."""
        m = self.mesh.copy()
        matrix = np.asarray(matrix, dtype=np.float64)
        m.apply_transform(matrix)
        before = np.eye(4) if self.pose is None and not self.placed else self.pose
        pose = None if before is None else matrix @ before
        return replace(self, mesh=m, placed=True, up=up if up is not None else self.up, pose=pose, _cache={})

    # ------------------------------------------------------------------ geometry
    @property
    def vertices(self) -> np.ndarray:
        return np.asarray(self.mesh.vertices)

    @property
    def faces(self) -> np.ndarray:
        return np.asarray(self.mesh.faces)

    @property
    def center(self) -> np.ndarray:
        """Centre of the axis-aligned bounding box (the panorama is centred here)."""
        lo, hi = self.mesh.bounds
        return (lo + hi) / 2.0

    @property
    def diameter(self) -> float:
        lo, hi = self.mesh.bounds
        return float(np.linalg.norm(hi - lo))

    def corner_normals(self) -> np.ndarray:
        """Unit shading normals per face corner, ``(F, 3, 3)`` float64 (see module docs)."""
        if "corner_normals" not in self._cache:
            self._cache["corner_normals"] = _corner_normals(self.mesh, self.crease_angle_deg)
        return self._cache["corner_normals"]

    def content_hash(self) -> str:
        h = hashlib.sha256()
        h.update(np.ascontiguousarray(self.vertices, dtype=np.float64).tobytes())
        h.update(np.ascontiguousarray(self.faces, dtype=np.int64).tobytes())
        h.update(repr((round(self.ior, 12), self.crease_angle_deg, self.placed)).encode())
        if self.absorbs:  # a clear object keeps the hash it had before absorption existed
            h.update(repr(tuple(round(s, 12) for s in self.absorption)).encode())
        if self.media is not None:
            h.update(repr(self.media).encode())
            h.update(np.ascontiguousarray(self.face_medium, np.int64).tobytes())
        return h.hexdigest()

    def __repr__(self) -> str:
        return (
            f"GlassObject(name={self.name!r}, ior={self.ior}, faces={len(self.mesh.faces)}, placed={self.placed}, "
            f"center={np.round(self.center, 4).tolist()})"
        )


def _up_axis_transform(up_axis: str) -> np.ndarray:
    axis = up_axis.strip().lower()
    sign = -1.0 if axis.startswith("-") else 1.0
    axis = axis.lstrip("+-")
    if axis not in ("x", "y", "z"):
        raise ValueError(f"up_axis must be one of x, y, z (optionally signed), got {up_axis!r}")
    up = np.zeros(3)
    up["xyz".index(axis)] = sign
    # rotation taking `up` to +y by the shortest arc
    target = np.array([0.0, 1.0, 0.0])
    T = np.eye(4)
    if np.allclose(up, target):
        return T
    if np.allclose(up, -target):
        T[:3, :3] = np.diag([1.0, -1.0, -1.0])
        return T
    T[:3, :3] = trimesh.geometry.align_vectors(up, target)[:3, :3]
    return T


def _corner_normals(mesh: trimesh.Trimesh, crease_angle_deg: float) -> np.ndarray:
    """``(F, 3, 3)``: each corner's area-weighted mean of the normals of the faces around its vertex
    within the crease angle. Computed over the (corner, face around its vertex) pairs alone: their
    number is the sum of each vertex's valence squared, so a vertex that many faces meet (a UV
    sphere's pole) costs its own pairs, not the largest valence times every corner."""
    faces = np.asarray(mesh.faces, np.int64)
    fn = np.asarray(mesh.face_normals, dtype=np.float64)  # unit
    area = np.asarray(mesh.area_faces, dtype=np.float64)
    corners = faces.ravel()  # corner i is of face i // 3
    order = np.argsort(corners, kind="stable")
    counts = np.bincount(corners, minlength=len(mesh.vertices))
    starts = np.cumsum(counts) - counts
    around = order // 3  # the faces around each vertex, grouped by vertex
    rep = counts[corners]  # pairs per corner
    corner = np.repeat(np.arange(len(corners)), rep)
    offset = np.arange(len(corner)) - np.repeat(np.cumsum(rep) - rep, rep)
    nbr = around[np.repeat(starts[corners], rep) + offset]
    own = fn[corner // 3]
    cos = np.einsum("pd,pd->p", fn[nbr], own)
    w = np.where(cos >= math.cos(math.radians(crease_angle_deg)) - 1e-9, area[nbr], 0.0)
    n = np.stack([np.bincount(corner, weights=w * fn[nbr, d], minlength=len(corners)) for d in range(3)], -1)
    n = n.reshape(-1, 3, 3)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    fallback = np.broadcast_to(fn[:, None, :], n.shape)
    return np.where(norm > 1e-12, n / np.maximum(norm, 1e-300), fallback)
