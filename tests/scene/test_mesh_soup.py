"""A triangle soup (every face with its own jittered copies of its corners, plus degenerate and
duplicate faces) loads through ``GlassObject.from_file`` as the closed solid it is."""

import logging
import math

import numpy as np
import pytest
import trimesh

from snell_bench.scene.mesh_checks import _weld_groups
from snell_bench.scene.objects import GlassObject

#: the soup's jitter, per coordinate, as a fraction of its bounding-box diagonal
JITTER = 1e-12
N_DEGENERATE, N_DUPLICATE = 5, 10


def _soup(scale: float, rng: np.random.Generator, drop: int = 0) -> tuple[np.ndarray, np.ndarray, trimesh.Trimesh]:
    """An icosphere of radius ``scale`` off the origin (without its first ``drop`` faces) as a
    soup: ``(vertices, faces, the icosphere)``; the vertices appended for the degenerate and
    duplicate faces are jittered copies too, bar one midpoint."""
    ico = trimesh.creation.icosphere(subdivisions=3, radius=scale)
    ico.apply_translation([2.0 * scale, -scale, 0.5 * scale])
    eps = JITTER * float(np.linalg.norm(np.ptp(ico.vertices, axis=0)))
    corners = ico.vertices[ico.faces[drop:]].reshape(-1, 3)
    faces = np.arange(len(corners)).reshape(-1, 3)
    a, b = faces[0, 0], faces[0, 1]  # the two ends of an edge
    extra = [np.repeat(corners[[a]], 3, axis=0), np.repeat(corners[[b]], 3, axis=0), (corners[[a]] + corners[[b]]) / 2]
    n = len(corners)
    degenerate = [[a, a, b], [b, b, b], [n, n + 1, n + 2], [n + 3, n + 4, n + 5], [a, b, n + 6]]  # the last: collinear
    picked = rng.choice(len(faces), N_DUPLICATE, replace=False)
    extra.append(corners[faces[picked]].reshape(-1, 3))  # their own copies of the corners
    copies = n + 7 + np.arange(3 * N_DUPLICATE).reshape(-1, 3)
    copies[::2] = copies[::2, ::-1]  # half of them wound the other way
    vertices = np.concatenate([corners, *extra])
    vertices = vertices + rng.uniform(-eps, eps, vertices.shape)
    return vertices, np.concatenate([faces, degenerate, copies]), ico


def _write_obj(path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """An OBJ file with every digit of the coordinates (so the jitter survives the file)."""
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in vertices.tolist()]
    lines += [f"f {i + 1} {j + 1} {k + 1}" for i, j, k in faces.tolist()]
    path.write_text("\n".join(lines) + "\n")


def _load(path, repair: bool = False) -> GlassObject:
    """The object as the config builds it (``conf/object/*.yaml``: path, up axis, repair, allow_open)."""
    return GlassObject.from_file(path, up_axis="y", repair=repair, allow_open=False)


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_a_triangle_soup_loads_as_the_closed_sphere(scale, tmp_path, caplog):
    """Merged, degenerate and duplicate faces dropped, without ``repair``: the icosphere's faces and
    volume, and one log line that counts what was cleaned.

    The soup's corners lie within ``eps`` (per coordinate) of the icosphere's, so its volume within
    ``area * sqrt(3) eps`` (``3 sqrt(3) eps / r`` relative) and its largest side within ``2 eps``
    (the canonical scale ``(1 + eps / r)^3``, ``3 eps / r``) of the icosphere's.
    """
    vertices, faces, ico = _soup(scale, np.random.default_rng(0))
    path = tmp_path / "soup.obj"
    _write_obj(path, vertices, faces)
    with caplog.at_level(logging.INFO, logger="snell_bench.scene.mesh_checks"):
        obj = _load(path)
    mesh = obj.mesh
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert len(mesh.faces) == len(ico.faces) and len(mesh.vertices) == len(ico.vertices)
    eps_over_r = JITTER * float(np.linalg.norm(np.ptp(ico.vertices, axis=0))) / scale
    expected = ico.volume / float(np.ptp(ico.vertices, axis=0).max()) ** 3  # canonical: largest side 1
    assert mesh.volume == pytest.approx(expected, rel=(3 * math.sqrt(3) + 3) * eps_over_r + 1e-13)
    merged = len(vertices) - len(ico.vertices) - 1  # all but the icosphere's and the (unused) midpoint
    line = f"merged {merged:,} duplicate vertices, dropped {N_DEGENERATE} degenerate and {N_DUPLICATE} duplicate faces"
    assert any(r.getMessage() == f"{path}: {line}" for r in caplog.records), caplog.text


def test_a_soup_with_a_hole_names_its_boundary_edges_and_the_repair(tmp_path):
    """One face missing: refused without ``repair``, naming the three edges around the hole, what was
    cleaned and ``object.repair``; with it, the hole is filled."""
    vertices, faces, ico = _soup(1.0, np.random.default_rng(1), drop=1)
    path = tmp_path / "holed.obj"
    _write_obj(path, vertices, faces)
    pattern = r"not watertight \(3 boundary edges, .*already cleaned: merged .* duplicate vertices.*object\.repair=true"
    with pytest.raises(ValueError, match=pattern) as e:
        _load(path)
    assert "non-manifold" not in str(e.value)
    repaired = _load(path, repair=True)
    assert repaired.mesh.is_watertight and len(repaired.mesh.faces) == len(ico.faces)


def test_vertices_merge_across_a_cell_edge_but_not_beyond_the_tolerance():
    """Rounding to one grid splits two points on either side of a cell's edge, however close: every
    pair within the tolerance shares a group, and points several tolerances apart do not."""
    tol = 1e-3
    base = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])  # sets the grids' origin
    points = []
    for k in range(1, 40):  # pairs astride each cell edge (multiples of tol), 10 tol from each other
        for d in (-1e-12, 1e-12):
            points.append([k * tol + d, 0.1 + k * 10 * tol, k * tol - d])
    group = _weld_groups(np.concatenate([base, points]), tol)[2:].reshape(-1, 2)
    assert np.all(group[:, 0] == group[:, 1]) and len(set(group[:, 0].tolist())) == len(group)
    apart = np.array([[0.0, 0.0, 0.0], [4 * tol, 0.0, 0.0], [0.2, 0.2, 0.2], [0.2, 0.2, 0.2 + 4 * tol]])
    assert len(set(_weld_groups(apart, tol).tolist())) == 4
