"""The bundled meshes (snell_bench/datasets/meshes/SOURCES.md) as configured objects: built from their config,
placed on a procedural scene's table, upright, on the surface, at the configured size, and seen."""

import json
import math

import numpy as np
import pytest

from snell_bench.config import compose
from snell_bench.pipeline import build_object, prepare_inputs
from snell_bench.scene.placement import find_support_plane

SMALL = [
    "scene=living_room",
    "scene.width=160",
    "scene.height=96",
    "scene.supersample=1",
    "warps.pano_height=32",
    "warps.cache_dir=null",
]

#: object config -> (prompt noun, vertices, faces) after merging, as snell_bench/datasets/meshes/SOURCES.md gives them
MESHES = {
    "fox": ("fox", 290, 576),
    "dog": ("dog", 977, 1950),
    "sculpture": ("sculpture", 35002, 70000),
    "spot": ("cow", 2930, 5856),
}


@pytest.mark.parametrize("name", list(MESHES))
def test_bundled_mesh_stands_on_the_table_at_its_size(name, tmp_path):
    noun, n_vertices, n_faces = MESHES[name]
    cfg = compose([f"object={name}", *SMALL, f"output_dir={tmp_path}"])
    assert cfg.object.noun == noun and cfg.object.up_axis == "y"

    canon = build_object(cfg.object)
    assert (len(canon.vertices), len(canon.faces)) == (n_vertices, n_faces)
    assert canon.mesh.is_watertight and canon.mesh.volume > 0
    assert len(canon.mesh.split(only_watertight=False)) == 1  # one body
    assert canon.mesh.euler_number == 2  # genus 0
    lo, hi = canon.mesh.bounds
    assert lo[1] == pytest.approx(0.0, abs=1e-12) and (hi - lo).max() == pytest.approx(1.0, rel=1e-12)

    inputs = prepare_inputs(cfg, references=False)
    obj, scene = inputs.obj, inputs.scene
    assert obj.placed and len(obj.vertices) == n_vertices

    # the supporting plane fitted independently on the same depth and camera, with the same seed
    hint = {} if scene.up is None else {"up_hint": scene.up}
    plane = find_support_plane(scene.depth, scene.camera, seed=int(cfg.seed), **hint)
    n = plane.normal
    assert n @ scene.up > math.cos(math.radians(3.0))  # the table top is level
    size = float(cfg.object.relative_size) * float(np.linalg.norm(plane.point))

    # (a) upright: the object's up is the plane normal, and canonical y runs along it
    np.testing.assert_allclose(obj.up, n, atol=1e-12)
    heights = obj.vertices @ n - plane.point @ n
    np.testing.assert_allclose(heights - heights[0], size * (canon.vertices[:, 1] - canon.vertices[0, 1]), atol=1e-9)

    # (b) on the surface: the lowest point a hair (the 1e-3 x size lift) above the plane, under 1 cm
    bottom = float(heights.min())
    assert 0.0 < bottom < 0.01
    assert bottom == pytest.approx(1e-3 * size, abs=1e-6)

    # (c) its size, measured in its own frame: y along the normal, z horizontal towards the camera
    z = -plane.point + (plane.point @ n) * n
    z /= np.linalg.norm(z)
    frame = np.stack([np.cross(n, z), n, z], axis=1)  # right-handed: a rotation, no mirror
    local = (obj.vertices - plane.point) @ frame
    assert np.ptp(local, axis=0).max() == pytest.approx(size, rel=1e-6)
    np.testing.assert_allclose(local, size * canon.vertices + [0.0, 1e-3 * size, 0.0], atol=1e-9)

    # (d) the camera sees it, and the placed surface is still closed
    assert inputs.warps.object_mask.sum() > 20
    assert obj.mesh.is_watertight


@pytest.mark.slow
def test_grid_with_the_bundled_meshes(tmp_path):
    from snell_bench.experiment.runner import run_grid

    cfg = compose(
        [
            "+experiment=smoke",
            "scene.width=160",
            "scene.height=96",
            "warps.pano_height=64",
            "warps.cache_dir=null",
            "sampler.steps=4",
            "reference.spp=2",
            "reference.true_spp=1",
            "grid.scenes=[living_room]",
            "grid.objects=[fox,dog,sculpture]",
            "grid.methods=[snellcaster]",
            f"runs_dir={tmp_path / 'runs'}",
            f"reports_dir={tmp_path / 'reports'}",
            f"output_dir={tmp_path}",
        ]
    )
    summary = run_grid(cfg)
    assert summary["ok"] == 3 and summary["failed"] == 0, summary

    for name in ("fox", "dog", "sculpture"):
        rec = json.loads(
            (tmp_path / "runs" / "smoke" / "living_room-0" / name / "snellcaster" / "metrics.json").read_text()
        )
        assert rec["status"] == "ok", (name, rec.get("reason"))
        assert rec["metrics"]["psnr"] is not None and math.isfinite(rec["metrics"]["psnr"]), (name, rec["metrics"])


@pytest.mark.parametrize("name", list(MESHES))
def test_a_configured_mesh_that_crosses_itself_is_refused_until_allowed(name, tmp_path):
    """``object.allow_self_intersecting`` reaches the factory of every bundled mesh object: a file of
    two overlapping closed boxes is refused naming ``object.path`` and the key, and built with it."""
    import trimesh

    path = tmp_path / "boxes.ply"
    moved = trimesh.creation.box(transform=trimesh.transformations.translation_matrix([0.5, 0.3, 0.2]))
    trimesh.util.concatenate([trimesh.creation.box(), moved]).export(path)
    cfg = compose([f"object={name}", f"object.path={path}", *SMALL, f"output_dir={tmp_path}"])
    with pytest.raises(
        ValueError, match=r"object.path=.*boxes.ply.*crosses itself.*object.allow_self_intersecting=true"
    ):
        build_object(cfg.object)
    cfg = compose([f"object={name}", f"object.path={path}", "object.allow_self_intersecting=true", *SMALL])
    assert len(build_object(cfg.object).faces) == 24
