"""Glass objects: primitives, files, materials, validation, shading normals."""

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from snell_bench.scene.objects import MATERIALS, GlassObject, resolve_ior

MESHES = Path(__file__).resolve().parents[2] / "snell_bench" / "datasets" / "meshes"


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
