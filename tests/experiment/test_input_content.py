"""Inputs known by content: a photo edited in place and a mesh replaced under its path are changed
settings (refused naming the file, or computed again), not old results for new inputs; a file is
hashed once per (path, size, modification time)."""

import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from snell_bench.config import compose
from snell_bench.experiment.cell_state import SettingsChanged

FRAME = Path(__file__).resolve().parents[2] / "snell_bench" / "datasets" / "rgbd" / "tum_fr3_office"
CHEAP = [
    "scene.width=160",
    "scene.height=96",
    "warps.pano_height=32",
    "warps.cache_dir=null",
    "sampler.steps=4",
    "reference.enabled=false",
    "reference.true_render=false",
    "grid.methods=[t2i]",
    "grid.report=false",
]


def _cfg(tmp_path, *more):
    return compose(["+experiment=smoke", *CHEAP, f"runs_dir={tmp_path / 'runs'}", f"output_dir={tmp_path}", *more])


def test_a_photo_edited_in_place_is_a_changed_setting(tmp_path):
    from snell_bench.experiment.runner import run_grid

    photo = tmp_path / "color.png"
    shutil.copy(FRAME / "color.png", photo)
    frame = ["grid.scenes=[tum_office]", f"scene.image={photo}", f"scene.depth={FRAME / 'depth.png'}"]
    assert run_grid(_cfg(tmp_path, *frame))["ok"] == 1
    assert run_grid(_cfg(tmp_path, *frame))["cached"] == 1  # unchanged: done
    pixels = np.asarray(Image.open(photo)).copy()
    pixels[:40] = 255 - pixels[:40]
    Image.fromarray(pixels).save(photo)  # same path, new pixels
    with pytest.raises(SettingsChanged, match=r"scene.image \(content sha256\)"):
        run_grid(_cfg(tmp_path, *frame))
    assert run_grid(_cfg(tmp_path, *frame, "grid.on_change=recompute"))["ok"] == 1


def test_a_mesh_replaced_by_another_shape_is_a_changed_setting(tmp_path):
    from snell_bench.experiment.runner import run_grid

    mesh = tmp_path / "thing.ply"
    trimesh.creation.icosphere(subdivisions=2).export(mesh)
    one = ["grid.scenes=[living_room]", "grid.objects=[spot]", f"object.path={mesh}"]  # spot reads object.path
    assert run_grid(_cfg(tmp_path, *one))["ok"] == 1
    trimesh.creation.box().export(mesh)
    with pytest.raises(SettingsChanged, match=r"object.path \(content sha256\)"):
        run_grid(_cfg(tmp_path, *one))


def test_a_file_is_hashed_once_per_path_size_and_time(tmp_path, monkeypatch):
    from snell_bench.experiment import input_content as ic

    photo = tmp_path / "p.png"
    shutil.copy(FRAME / "color.png", photo)
    cfg = compose(["scene=tum_office", f"scene.image={photo}", f"runs_dir={tmp_path / 'runs'}", "output_dir=/tmp/x"])
    calls = []
    monkeypatch.setattr(ic, "file_sha256", lambda p: calls.append(p) or "h")
    ic._MEMO.clear()
    first = ic.input_content(cfg)
    ic._MEMO.clear()  # a new process: the cache file answers
    assert ic.input_content(cfg) == first and len(calls) == 2  # color.png and depth.png, once each
    assert (tmp_path / "runs" / ".content-hashes.json").is_file()
