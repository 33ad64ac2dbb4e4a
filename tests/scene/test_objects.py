"""Glass objects: primitives, files, materials, validation, shading normals."""

import doctest
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from snell_bench.scene import mesh_checks, mesh_format
from snell_bench.scene.mesh_checks import self_crossings
from snell_bench.scene.mesh_format import sniff_mesh_format
from snell_bench.scene.objects import MATERIALS, GlassObject, resolve_ior

MESHES = Path(__file__).resolve().parents[2] / "snell_bench" / "datasets" / "meshes"


@pytest.mark.parametrize("module", [mesh_checks, mesh_format])
def test_doctests(module):
    result = doctest.testmod(module)
    assert result.failed == 0 and result.attempted > 0


@pytest.mark.parametrize("make", [GlassObject.sphere, GlassObject.cylinder, GlassObject.pyramid])
def test_primitives_are_canonical_and_closed(make):
    obj = make()
    lo, hi = obj.mesh.bounds
    assert obj.mesh.is_watertight and obj.mesh.volume > 0
    assert lo[1] == pytest.approx(0.0, abs=1e-12)  # stands on y = 0
    assert (hi - lo).max() == pytest.approx(1.0)
    np.testing.assert_allclose([(lo[0] + hi[0]) / 2, (lo[2] + hi[2]) / 2], 0, atol=1e-12)
    assert not obj.placed


def test_materials_and_numbers():
    assert resolve_ior("glass") == 1.5 and resolve_ior("Water") == 1.333 and resolve_ior("diamond") == 2.42
    assert resolve_ior(1.0) == 1.0 and resolve_ior("1.7") == 1.7
    assert MATERIALS["acrylic"] == 1.49
    for bad in (0.0, -1.5, float("nan"), float("inf"), "unobtainium", None, True):
        with pytest.raises(ValueError):
            resolve_ior(bad)
    with pytest.raises(ValueError, match="ior must be finite and > 0"):
        GlassObject.sphere(ior=float("nan"))


def test_from_mesh_validation():
    box = trimesh.creation.box()
    GlassObject.from_mesh(box.vertices, box.faces)  # fine
    with pytest.raises(ValueError, match="empty"):
        GlassObject.from_mesh(np.zeros((0, 3)), np.zeros((0, 3), int))
    with pytest.raises(ValueError, match="watertight"):
        GlassObject.from_mesh(box.vertices, box.faces[:-1])
    open_obj = GlassObject.from_mesh(box.vertices, box.faces[:-1], allow_open=True)
    assert len(open_obj.faces) == 11
    with pytest.raises(ValueError, match="out of range"):
        GlassObject.from_mesh(box.vertices, box.faces + 100)


def test_degenerate_faces_are_removed_and_winding_fixed():
    box = trimesh.creation.box()
    faces = np.vstack([box.faces[:, ::-1], [[0, 0, 1]], [[2, 2, 2]]])  # inside-out plus two degenerate faces
    obj = GlassObject.from_mesh(box.vertices, faces)
    assert len(obj.faces) == 12
    assert obj.mesh.volume > 0  # outward normals again


def test_mesh_files():
    spot = GlassObject.from_file(MESHES / "spot.obj", ior="acrylic")
    assert spot.mesh.is_watertight and spot.ior == 1.49 and spot.name == "spot"
    with pytest.raises(ValueError, match="not watertight"):
        GlassObject.from_file(MESHES / "stanford-bunny.obj")
    with pytest.raises(FileNotFoundError):
        GlassObject.from_file(MESHES / "no-such-mesh.ply")


def test_mesh_file_formats(tmp_path):
    m = trimesh.creation.icosphere(subdivisions=2)
    for ext in ("ply", "stl", "glb", "obj"):
        m.export(tmp_path / f"s.{ext}")
        obj = GlassObject.from_file(tmp_path / f"s.{ext}")
        assert obj.mesh.is_watertight and len(obj.faces) == len(m.faces)
    z_up = trimesh.creation.cylinder(radius=0.1, height=1.0)  # tall along z
    z_up.export(tmp_path / "c.ply")
    tall = GlassObject.from_file(tmp_path / "c.ply", up_axis="z")
    ext = np.ptp(tall.mesh.bounds, axis=0)
    assert ext[1] == pytest.approx(1.0) and ext[0] < 0.3
    with pytest.raises(ValueError, match="up_axis"):
        GlassObject.from_file(tmp_path / "c.ply", up_axis="w")


def test_sphere_corner_normals_are_radial():
    obj = GlassObject.sphere(subdivisions=4)
    cn = obj.corner_normals()
    radial = obj.vertices[obj.faces] - obj.center
    radial /= np.linalg.norm(radial, axis=-1, keepdims=True)
    cos = (cn * radial).sum(-1)
    assert cos.min() > math.cos(math.radians(0.5))


def test_creased_normals_keep_sharp_edges():
    pyr = GlassObject.pyramid()
    cn = pyr.corner_normals()
    np.testing.assert_allclose(cn, np.repeat(pyr.mesh.face_normals[:, None], 3, 1), atol=1e-9)
    cyl = GlassObject.cylinder()
    cn = cyl.corner_normals()
    fn = cyl.mesh.face_normals
    caps = np.abs(fn[:, 1]) > 0.999
    np.testing.assert_allclose(cn[caps], np.repeat(fn[caps][:, None], 3, 1), atol=1e-9)  # flat caps
    assert np.abs(cn[~caps][..., 1]).max() < 1e-9  # side normals stay horizontal at the rim


def test_a_damaged_file_or_a_folder_is_a_clear_error(tmp_path):
    bad = tmp_path / "bad.obj"
    bad.write_bytes(b"v 0 0 0\nv 1 0 nan_garbage\nf 1 2 3 4\n\x00\x01")
    with pytest.raises(ValueError, match=r"bad.obj (could not be read as a mesh|holds no triangle mesh).*re-export"):
        GlassObject.from_file(bad)
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "cup.obj").write_text("")
    with pytest.raises(IsADirectoryError, match=r"is a folder, not a mesh file; give a file \(it holds cup.obj\)"):
        GlassObject.from_file(tmp_path / "meshes")


def test_an_open_mesh_names_the_config_keys():
    import trimesh

    box = trimesh.creation.box()
    box.update_faces(box.face_normals[:, 2] < 0.5)
    with pytest.raises(ValueError, match=r"object.repair=true.*object.allow_open=true"):
        GlassObject.from_mesh(box.vertices, box.faces)


# ============================================================================ meshes that enclose no volume
@pytest.mark.parametrize(
    "make",
    [
        pytest.param(lambda b: (b.vertices * [1.0, 1.0, 0.0], b.faces), id="closed-box-of-height-0"),
        pytest.param(lambda b: (b.vertices * [1.0, 1.0, 1e-5], b.faces), id="box-thinner-than-the-tracer-offset"),
        pytest.param(lambda b: ([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]]), id="open-quad"),
    ],
)
def test_a_flat_mesh_says_it_encloses_no_volume(make):
    """Flat meshes (open or closed) are not told to fill holes (``repair`` cannot give them a volume)."""
    v, f = make(trimesh.creation.box())
    for repair in (False, True):
        with pytest.raises(ValueError, match=r"flat .*encloses no volume.*closed solid") as e:
            GlassObject.from_mesh(v, f, repair=repair)
        assert "repair" not in str(e.value) and "allow_open" not in str(e.value)


def test_sheets_on_top_of_each_other_enclose_no_volume():
    """A curved sheet and its copy wound the other way: not flat, every edge used twice or more, and
    no volume between them."""
    s = trimesh.creation.icosphere(subdivisions=3)
    cap = s.faces[s.triangles_center[:, 2] > 0.3]
    with pytest.raises(ValueError, match=r"encloses almost no volume.*on top of each other.*closed solid"):
        GlassObject.from_mesh(s.vertices, np.concatenate([cap, cap[:, ::-1]]))


def test_a_thin_solid_is_a_solid():
    """A pane a thousandth of its width thick (ten times the refused thickness) is accepted, with its
    volume."""
    box = trimesh.creation.box()
    pane = GlassObject.from_mesh(box.vertices * [1.0, 1.0, 1e-3], box.faces)
    assert pane.mesh.volume == pytest.approx(1e-3, rel=1e-9)


def test_inside_out_meshes_are_turned_outwards():
    """Wound inside-out (negative volume) or half the faces flipped, closed or open: the faces end
    up wound outwards, the closed volume that of the icosphere."""
    s = trimesh.creation.icosphere(subdivisions=3)
    inverted = GlassObject.from_mesh(s.vertices, s.faces[:, ::-1])
    half = s.faces.copy()
    half[::2] = half[::2, ::-1]
    flipped = GlassObject.from_mesh(s.vertices, half)
    for obj in (inverted, flipped):
        assert obj.mesh.is_winding_consistent and obj.mesh.volume == pytest.approx(s.volume, rel=1e-12)
    open_inverted = GlassObject.from_mesh(s.vertices, s.faces[:-3, ::-1], allow_open=True)
    centres = open_inverted.mesh.triangles_center
    assert np.all(np.einsum("ij,ij->i", open_inverted.mesh.face_normals, centres) > 0)


# ============================================================================ meshes that cross themselves
def _two_boxes() -> trimesh.Trimesh:
    """Two closed unit boxes, the second moved by (0.5, 0.3, 0.2), concatenated into one mesh."""
    b = trimesh.creation.box(transform=trimesh.transformations.translation_matrix([0.5, 0.3, 0.2]))
    return trimesh.util.concatenate([trimesh.creation.box(), b])


def _folded_torus() -> trimesh.Trimesh:
    """A closed torus whose two halves are pushed through each other (x moved 0.8 towards 0)."""
    t = trimesh.creation.torus(major_radius=1.0, minor_radius=0.4, major_sections=48, minor_sections=24)
    v = np.asarray(t.vertices).copy()
    v[:, 0] -= 0.8 * np.sign(v[:, 0])
    return trimesh.Trimesh(v, t.faces, process=False)


def test_crossings_of_two_overlapping_boxes_lie_on_both():
    """Each crossing point is on the surface of both boxes (closed form: the max-norm distance to
    the box's centre is its half-side), and their edges and faces belong to different boxes."""
    m = _two_boxes()
    c = self_crossings(m.vertices, m.faces)
    assert len(c.edges) > 0
    for centre in ([0.0, 0.0, 0.0], [0.5, 0.3, 0.2]):
        np.testing.assert_allclose(np.abs(c.points - centre).max(axis=1), 0.5, atol=1e-6)
    assert np.all((c.edges < 8).all(axis=1) == (m.faces[c.faces] >= 8).all(axis=1))


@pytest.mark.parametrize(
    "make",
    [_two_boxes, _folded_torus, lambda: trimesh.creation.icosphere(subdivisions=2)],
    ids=["boxes", "torus", "ico"],
)
def test_self_crossings_agree_with_open3d_all_pairs(make):
    """Against Open3D's all-pairs triangle test (exact, O(F^2)): the same answer, and every face we
    report crosses a face there too."""
    import open3d as o3d

    m = make()
    om = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(m.vertices), o3d.utility.Vector3iVector(m.faces))
    pairs = np.asarray(om.get_self_intersecting_triangles())
    c = self_crossings(m.vertices, m.faces)
    assert (len(c.edges) > 0) == om.is_self_intersecting() == (len(pairs) > 0)
    assert set(c.faces.tolist()) <= set(pairs.ravel().tolist())


def test_self_crossings_agree_with_open3d_on_random_meshes():
    """60 icospheres with random vertex noise, about half of them crossing themselves."""
    import open3d as o3d

    rng = np.random.default_rng(0)
    s = trimesh.creation.icosphere(subdivisions=2)
    answers = []
    for _ in range(60):
        v = s.vertices + rng.normal(0.0, rng.uniform(0.02, 0.12), s.vertices.shape)
        om = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(s.faces))
        answers.append((om.is_self_intersecting(), len(self_crossings(v, s.faces).edges) > 0))
    theirs, ours = np.array(answers).T
    np.testing.assert_array_equal(ours, theirs)
    assert 10 < theirs.sum() < 50


def test_neighbours_meeting_at_sharp_angles_do_not_cross():
    """Faces that share an edge or a vertex never count, however sharp the angle between them: a
    needle-thin cone (64 faces meeting at its tip) and a wedge whose faces meet at 1 degree."""
    cone = trimesh.creation.cone(radius=1e-3, height=1.0, sections=64)
    assert len(self_crossings(cone.vertices, cone.faces).edges) == 0
    h = math.tan(math.radians(0.5))  # a wedge: a triangle of apex angle 1 degree, extruded
    section = np.array([[0.0, 0.0], [1.0, -h], [1.0, h]])
    wedge = trimesh.Trimesh(
        np.concatenate([np.c_[section, np.zeros(3)], np.c_[section, np.ones(3)]]),
        [[0, 2, 1], [3, 4, 5], [0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4], [2, 0, 3], [2, 3, 5]],
        process=False,
    )
    assert wedge.is_watertight and len(self_crossings(wedge.vertices, wedge.faces).edges) == 0


def test_a_self_intersecting_file_is_refused_with_the_fix(tmp_path):
    for name, make in (("boxes", _two_boxes), ("torus", _folded_torus)):
        path = tmp_path / f"{name}.ply"
        make().export(path)
        with pytest.raises(ValueError, match=r"crosses itself.*mesh tool.*object.allow_self_intersecting=true") as e:
            GlassObject.from_file(path)
        assert str(path) in str(e.value)
        obj = GlassObject.from_file(path, allow_self_intersecting=True)
        assert obj.mesh.is_watertight and len(obj.faces) == len(make().faces)


@pytest.mark.parametrize("name", ["fox.ply", "dog.ply", "spot.obj", "sculpture.ply", "stanford-bunny.obj"])
def test_bundled_meshes_do_not_cross_themselves_and_are_checked_fast(name):
    """The check on the largest bundled meshes (70,000 faces) takes about 0.15 s on one CPU core;
    3 s leaves room for a loaded machine."""
    import time

    m = trimesh.load(MESHES / name, force="mesh", process=False)
    t0 = time.perf_counter()
    c = self_crossings(m.vertices, m.faces)
    assert time.perf_counter() - t0 < 3.0
    assert len(c.edges) == 0


# ============================================================================ a file's real format
@pytest.mark.parametrize(
    "fmt,export,wrong",
    [
        ("PLY", "ply", "obj"),
        ("OBJ", "obj", "ply"),
        ("STL", "stl", "obj"),  # binary
        ("STL", "stl_ascii", "ply"),
        ("GLB", "glb", "obj"),
        ("OFF", "off", "stl"),
        ("PLY", "ply", "mesh"),
    ],
)
def test_a_file_named_for_another_format_names_both(tmp_path, fmt, export, wrong):
    data = trimesh.creation.icosphere(subdivisions=2).export(file_type=export)
    path = tmp_path / f"cube.{wrong}"
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    assert sniff_mesh_format(path) == fmt
    right = {"PLY": "ply", "OBJ": "obj", "STL": "stl", "GLB": "glb", "OFF": "off"}[fmt]
    with pytest.raises(
        ValueError, match=rf"cube.{wrong} holds a {fmt} file but its name ends in .{wrong}.*rename it to cube.{right}$"
    ):
        GlassObject.from_file(path)
    renamed = path.rename(tmp_path / f"cube.{right}")
    assert sniff_mesh_format(renamed) == fmt and len(GlassObject.from_file(renamed).faces) == 320


def test_sniffing_gltf_json_no_suffix_and_empty_files(tmp_path):
    files = trimesh.creation.icosphere(subdivisions=1).export(file_type="gltf")
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    gltf = next(tmp_path.glob("*.gltf"))
    assert sniff_mesh_format(gltf) == "glTF" and len(GlassObject.from_file(gltf).faces) == 80
    bare = tmp_path / "sphere"
    bare.write_bytes(gltf.read_bytes())
    with pytest.raises(ValueError, match=r"holds a glTF file but its name has no suffix.*rename it to sphere.gltf"):
        GlassObject.from_file(bare)
    empty = tmp_path / "empty.obj"
    empty.write_bytes(b"")
    with pytest.raises(ValueError, match=r"empty.obj is empty \(0 bytes\)"):
        GlassObject.from_file(empty)
    # a binary STL whose free-text header starts with "solid" is still binary
    stl = bytearray(trimesh.creation.icosphere(subdivisions=1).export(file_type="stl"))
    stl[:5] = b"solid"
    (tmp_path / "s.stl").write_bytes(bytes(stl))
    assert sniff_mesh_format(tmp_path / "s.stl") == "STL" and len(GlassObject.from_file(tmp_path / "s.stl").faces) == 80
    # text that is none of them is left to the reader
    (tmp_path / "notes.obj").write_text("hello\n")
    assert sniff_mesh_format(tmp_path / "notes.obj") is None


def test_corner_normals_cost_each_vertexs_own_faces_not_the_largest_valence():
    """Each corner's normal is the area-weighted mean of the face normals around its vertex within
    the crease angle (checked against a loop over the vertices on a small mesh, to float64 rounding);
    a UV sphere whose poles meet 512 faces stays small (a padded (faces, corners, max valence)
    array took 12.7 GB here)."""
    import math
    import tracemalloc

    import trimesh

    from snell_bench.scene.objects import _corner_normals

    mesh = trimesh.creation.uv_sphere(count=[6, 12])
    fn, area = mesh.face_normals, mesh.area_faces
    got = _corner_normals(mesh, 30.0)
    for f, face in enumerate(mesh.faces):
        for c, v in enumerate(face):
            around = [g for g in range(len(mesh.faces)) if v in mesh.faces[g]]
            keep = [g for g in around if fn[g] @ fn[f] >= math.cos(math.radians(30.0)) - 1e-9]
            n = sum(area[g] * fn[g] for g in keep)
            np.testing.assert_allclose(got[f, c], n / np.linalg.norm(n), atol=1e-12)
    pole = trimesh.creation.uv_sphere(count=[32, 512])
    tracemalloc.start()
    try:
        _corner_normals(pole, 30.0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1e9, peak
