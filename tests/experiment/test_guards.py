"""Guards against inputs too large to run, each refused before any work with one line naming the key,
the size, the limit and the fix: the object's mesh in the memory guard (its faces from the file's
header), sample counts above what the renderers take, and photos above the pixel limit."""

import json
import struct
import subprocess
import sys
import warnings
import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from snell_bench.config import ConfigError, check_config, compose
from snell_bench.config.errors import MAX_SPP
from snell_bench.config.schema_eval import ReferenceConfig
from snell_bench.experiment import memory
from snell_bench.experiment.memory import HostMemoryError, check_memory, estimate_memory
from snell_bench.experiment.memory_mesh import MESH_BYTES_PER_FACE
from snell_bench.scene.image_source import load_frame
from snell_bench.scene.mesh_header import FaceCount, mesh_face_count
from snell_bench.scene.photo_file import MAX_PHOTO_PIXELS, PhotoTooLargeError, load_image, read_photo_header

ROOT = Path(__file__).resolve().parents[2]
SCAN_FACES = 5_242_880


# ---------------------------------------------------------------------------------------------- mesh files
def _ply_header_only(path: Path, faces: int) -> Path:
    """A binary PLY whose header declares ``faces`` faces, with a few bytes of body: the count must
    come from the header (loading it would fail)."""
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {faces // 2 + 2}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {faces}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    path.write_bytes(header.encode() + b"\0" * 64)
    return path


def test_a_ply_gives_its_faces_from_its_header(tmp_path):
    assert mesh_face_count(_ply_header_only(tmp_path / "scan.ply", SCAN_FACES)) == FaceCount(SCAN_FACES, True)


def test_a_binary_stl_gives_its_count_at_byte_80(tmp_path):
    p = tmp_path / "part.stl"
    p.write_bytes(b"solid but binary".ljust(80, b" ") + struct.pack("<I", 3) + b"\0" * 150)
    assert mesh_face_count(p) == FaceCount(3, True)


def test_an_ascii_stl_and_an_obj_are_counted_streaming(tmp_path):
    facet = "facet normal 0 0 1\n outer loop\n  vertex 0 0 0\n  vertex 1 0 0\n  vertex 0 1 0\n endloop\nendfacet\n"
    (tmp_path / "a.stl").write_text("solid a\n" + facet * 4 + "endsolid a\n")
    assert mesh_face_count(tmp_path / "a.stl") == FaceCount(4, True)
    # a triangle, a quad (two triangles, as trimesh splits it) and a pentagon (three)
    obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 2 0\nf 1 2 3\nf 1/1 2/2 3/3 4/4\nf\t1 2 3 4 5\n# f 1 2 3\n"
    (tmp_path / "m.obj").write_text(obj)
    assert mesh_face_count(tmp_path / "m.obj") == FaceCount(6, True)


def test_another_format_is_bounded_by_its_size(tmp_path):
    p = tmp_path / "m.glb"
    p.write_bytes(b"glTF" + b"\0" * 1196)
    assert mesh_face_count(p) == FaceCount(100, False)


# ---------------------------------------------------------------------------------------------- the memory guard
def _scan_cfg(tmp_path, *more):
    ply = _ply_header_only(tmp_path / "scan.ply", SCAN_FACES)
    return compose(["+experiment=smoke", "object=dog", f"object.path={ply}", *more])


def test_a_5m_face_mesh_stops_the_run_naming_the_mesh_and_the_faces_that_fit(tmp_path):
    cfg = _scan_cfg(tmp_path, "models.host_memory_gb=8")
    with pytest.raises(HostMemoryError) as e:
        check_memory([cfg])
    msg = str(e.value)
    assert "\n" not in msg
    assert f"object.path={tmp_path / 'scan.ply'} has 5,242,880 faces: about 14.5 GB" in msg
    assert "more than the budget of 8.0 GB" in msg and "raise models.host_memory_gb" in msg
    most = int(msg.split("simplified copy of the mesh with at most ")[1].split()[0].replace(",", ""))
    est = e.value.estimate
    assert est.faces == SCAN_FACES and est.mesh_bytes == pytest.approx(memory.MARGIN * MESH_BYTES_PER_FACE * SCAN_FACES)
    # the count named fits, and is the largest that does
    assert replace(est, faces=most).peak_bytes <= 8e9 < replace(est, faces=most + 1).peak_bytes


def test_the_mesh_is_counted_in_every_stage(tmp_path):
    est = estimate_memory(_scan_cfg(tmp_path))
    bare = replace(est, faces=0)
    for stage, b in est.stages.items():
        assert b - bare.stages[stage] == pytest.approx(memory.MARGIN * MESH_BYTES_PER_FACE * SCAN_FACES)
    assert est.as_dict()["faces"] == SCAN_FACES


def test_a_procedural_object_counts_the_faces_its_factory_makes():
    assert estimate_memory(compose(["+experiment=smoke"])).faces == 20 * 4**5  # GlassObject.sphere's default
    fine = estimate_memory(compose(["+experiment=smoke", "+object.factory.subdivisions=9"]))
    assert fine.faces == SCAN_FACES and "object=sphere has 5,242,880 faces" in fine.describe()
    assert estimate_memory(compose(["+experiment=smoke", "object=cylinder"])).faces == 512


@pytest.mark.slow
def test_the_bytes_per_face_bound_a_measured_load_and_trace(tmp_path):
    """A 327,680-face icosphere read, placed and traced in a process of its own: its peak
    (ru_maxrss) above the process's resident memory just before (psutil: the current size, not an
    earlier peak of the imports) is covered by the guard's estimate (MESH_BYTES_PER_FACE a face
    times the margin), and is not a small fraction of it (a coefficient far too pessimistic)."""
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=7, radius=0.5)
    mesh.export(tmp_path / "ico.ply")
    code = f"""
import json, resource
import numpy as np
import psutil
from snell_bench.scene.objects import GlassObject
from snell_bench.optics.tracer import SceneTracer
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import build_background
rss = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
base = psutil.Process().memory_info().rss
T = np.eye(4); T[:3, 3] = [0.0, -0.5, 3.0]
obj = GlassObject.from_file({str(tmp_path / "ico.ply")!r}).transformed(T)
cam = Camera.from_fov(64, 48, 60.0)
SceneTracer(build_background(np.full(cam.shape, 5.0), cam), obj).trace(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))
print(json.dumps({{"faces": len(obj.faces), "bytes": rss() - base}}))
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = json.loads(proc.stdout.strip().splitlines()[-1])
    assert run["faces"] == len(mesh.faces)
    assert (
        0.3 * MESH_BYTES_PER_FACE * run["faces"] <= run["bytes"] <= memory.MARGIN * MESH_BYTES_PER_FACE * run["faces"]
    ), run


# ---------------------------------------------------------------------------------------------- sample counts
@pytest.mark.parametrize(
    "key, example",
    [
        ("reference.spp", 242),
        ("reference.cycles_spp", 1024),
        ("reference.unobserved_spp", 25),
        ("reference.true_spp", 4),
        ("relight.truth_spp", 512),
        ("grid.converged_spp", 1058),
    ],
)
def test_a_sample_count_past_the_renderers_is_refused_naming_the_limit(key, example):
    with pytest.raises(ConfigError) as e:
        check_config(compose([f"{key}=1000000000"]))
    msg = str(e.value)
    assert msg.startswith(f"{key}=1000000000: must be an integer <= {MAX_SPP} (") and msg.endswith(
        f"; e.g. {key}={example}"
    )
    check_config(compose([f"{key}={example}"]))
    check_config(compose([f"{key}={MAX_SPP}"]))
    with pytest.raises(ConfigError, match=rf"{key}={MAX_SPP + 1}: must be an integer <= {MAX_SPP}"):
        check_config(compose([f"{key}={MAX_SPP + 1}"]))


def test_the_schema_itself_refuses_a_typo():
    with pytest.raises(ConfigError, match=r"reference\.spp=1000000000: must be an integer <= 65536"):
        ReferenceConfig(spp=1_000_000_000)


# ---------------------------------------------------------------------------------------------- photos
def _png_header(path: Path, width: int, height: int, *, whole: bool = False) -> Path:
    """A PNG whose header claims ``width x height`` pixels: RGB with one tiny IDAT (decoding it would
    fail, its header reads), or with ``whole`` black 1-bit pixels, all of them (a few kB)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    depth, colour, data = 8, 2, b"\0" * 16
    if whole:
        depth, colour, data = 1, 0, b"\0" * ((1 + (width + 7) // 8) * height)
    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(data)) + chunk(b"IEND", b"")
    )
    return path


@pytest.mark.parametrize("read", [read_photo_header, load_image])
def test_a_photo_claiming_10_gigapixels_is_refused_from_its_header(tmp_path, read):
    png = _png_header(tmp_path / "huge.png", 100_000, 100_000)
    limit = Image.MAX_IMAGE_PIXELS
    with pytest.raises(PhotoTooLargeError) as e:
        read(png)
    msg = str(e.value)
    assert "\n" not in msg and "re-save" not in msg and "not a readable image" not in msg
    assert f"scene.image='{png}' is 100000x100000 pixels (10000.0 Mpx), more than the 100 Mpx" in msg
    assert msg.endswith("downscale the file to at most 10000 pixels on its long side")
    assert Image.MAX_IMAGE_PIXELS == limit  # Pillow's own limit restored


def test_a_110_mpx_photo_is_told_the_side_that_fits_without_a_pillow_warning(tmp_path):
    png = _png_header(tmp_path / "big.png", 12000, 9200)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # Pillow warns above 89.5 Mpx
        with pytest.raises(PhotoTooLargeError, match=r"12000x9200 pixels \(110\.4 Mpx\).*at most 11420 pixels"):
            read_photo_header(png)
        assert 11420 * round(11420 * 9200 / 12000) <= MAX_PHOTO_PIXELS
        # at the limit: read, and not a warning (Pillow decodes a PNG to look for EXIF after its pixels)
        at = _png_header(tmp_path / "at.png", 10_000, 10_000, whole=True)
        assert read_photo_header(at).upright_size == (10_000, 10_000)


def test_a_modest_photo_still_loads(tmp_path):
    rng = np.random.default_rng(0)
    pixels = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    Image.fromarray(pixels).save(tmp_path / "photo.png")
    assert read_photo_header(tmp_path / "photo.png").upright_size == (64, 48)
    np.testing.assert_array_equal(np.round(load_image(tmp_path / "photo.png") * 255).astype(np.uint8), pixels)
    (tmp_path / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n not a png any more")
    with pytest.raises(ValueError, match="is not a readable image") as e:
        read_photo_header(tmp_path / "broken.png")
    assert not isinstance(e.value, PhotoTooLargeError)


def test_a_huge_photo_stops_the_run_before_any_cell(tmp_path):
    png = _png_header(tmp_path / "huge.png", 20_000, 15_000)
    cfg = compose(["+experiment=photo", f"scene.image={png}", "scene.depth=null", "scene.intrinsics=null"])
    with pytest.raises(PhotoTooLargeError, match=r"scene\.image=.*20000x15000 pixels"):
        check_memory([cfg])
    with pytest.raises(ConfigError, match=r"20000x15000 pixels.*at most 11547 pixels on its long side"):
        load_frame(png, fov_deg=60.0)
