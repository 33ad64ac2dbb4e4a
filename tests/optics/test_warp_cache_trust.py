"""The warp cache checks an entry against the key it is loaded for: another object's warps copied
under a key, or arrays whose shapes do not fit, are a logged miss and are recomputed, never used."""

import logging
import shutil

import numpy as np
import pytest

from snell_bench.optics import WarpSet, compute_warps
from snell_bench.optics.options import cache_lookup
from snell_bench.scene.camera import Camera
from snell_bench.scene.objects import GlassObject


def _placed(obj: GlassObject) -> GlassObject:
    T = np.eye(4)
    T[:3, 3] = [0.0, -0.5, 3.0]  # unit-sized, centred near the optical axis at z = 3
    return obj.transformed(T)


@pytest.fixture(scope="module")
def cam():
    return Camera.from_fov(48, 32, 60.0)


@pytest.fixture(scope="module")
def depth(cam):
    return np.full(cam.shape, 5.0, np.float32)


@pytest.fixture(scope="module")
def objects():
    return _placed(GlassObject.sphere(subdivisions=2)), _placed(GlassObject.cylinder(sections=16))


def _assert_same_warps(a: WarpSet, b: WarpSet) -> None:
    assert a.input_hash == b.input_hash
    for name in ("object_mask", "refraction", "fresnel", "pano_to_persp"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_other_objects_entry_under_a_key_is_recomputed(cam, depth, objects, tmp_path, caplog):
    """The cylinder's entry copied over the sphere's key is not used: a warning names the file, the
    key and the hash it holds; the sphere's warps are recomputed and replace the entry."""
    sphere, cylinder = objects
    a = compute_warps(depth, cam, sphere, pano_height=8, cache_dir=tmp_path)
    b = compute_warps(depth, cam, cylinder, pano_height=8, cache_dir=tmp_path)
    assert a.input_hash != b.input_hash
    assert not np.array_equal(a.object_mask, b.object_mask)  # the two objects' warps differ
    entry = tmp_path / f"{a.input_hash}.npz"
    shutil.copyfile(tmp_path / f"{b.input_hash}.npz", entry)
    with caplog.at_level(logging.WARNING):
        again = compute_warps(depth, cam, sphere, pano_height=8, cache_dir=tmp_path)
    _assert_same_warps(again, compute_warps(depth, cam, sphere, pano_height=8))
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any(str(entry) in m and a.input_hash in m and b.input_hash in m for m in warnings), warnings
    _assert_same_warps(WarpSet.load(entry), a)  # the wrong entry was replaced
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([entry.name, f"{b.input_hash}.npz"])


def test_matching_entry_is_used(cam, depth, objects, tmp_path, caplog):
    sphere, _ = objects
    a = compute_warps(depth, cam, sphere, pano_height=8, cache_dir=tmp_path)
    with caplog.at_level(logging.INFO, logger="snell_bench.optics.options"):
        path, cached = cache_lookup(tmp_path, a.input_hash, depth.shape)
    assert cached is not None and "loading cached" in caplog.text and "WARNING" not in caplog.text
    _assert_same_warps(cached, a)
    assert cache_lookup(tmp_path, a.input_hash)[1] is not None  # the old two-argument call


def test_entry_for_another_depth_size_is_a_miss(cam, depth, objects, tmp_path, caplog):
    sphere, _ = objects
    a = compute_warps(depth, cam, sphere, pano_height=8, cache_dir=tmp_path)
    with caplog.at_level(logging.WARNING):
        path, cached = cache_lookup(tmp_path, a.input_hash, (cam.height, cam.width + 1))
    assert cached is None and not path.exists()
    assert str(path) in caplog.text and "the camera is 32x48" in caplog.text


def test_inconsistent_array_shapes_are_a_miss(cam, depth, objects, tmp_path, caplog):
    """An entry whose hash fits but whose arrays disagree with its camera is unreadable."""
    sphere, _ = objects
    a = compute_warps(depth, cam, sphere, pano_height=8, cache_dir=tmp_path)
    entry = tmp_path / f"{a.input_hash}.npz"
    with np.load(entry) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["fresnel"] = arrays["fresnel"][:, :-1]
    np.savez_compressed(entry, **arrays)
    with pytest.raises(ValueError, match=r"fresnel has shape \(32, 47\), expected \(32, 48\)"):
        WarpSet.load(entry)
    with caplog.at_level(logging.WARNING):
        again = compute_warps(depth, cam, sphere, pano_height=8, cache_dir=tmp_path)
    assert str(entry) in caplog.text and "recomputing" in caplog.text
    _assert_same_warps(again, a)
    _assert_same_warps(WarpSet.load(entry), a)


def test_mismatch_names_what_differs(cam, depth, objects):
    ws = compute_warps(depth, cam, objects[0], pano_height=8)
    assert ws.mismatch() is None and ws.mismatch(ws.input_hash, cam.shape) is None
    assert "is not" in ws.mismatch("0" * 64)
    assert "depth map" in ws.mismatch(shape=(2, 2))
