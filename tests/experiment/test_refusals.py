"""Refusals on the command line (:mod:`snell_bench.__main__`): each is ``Error:`` and one line naming
the key (or the folder) and the fix, with the documented exit status and no traceback: a photo or
depth file refused before any work (1), intrinsics whose field of view no camera check allows (1),
a report the system cannot write (``job=report``: 1; a grid keeps the status of its cells, 3)."""

import errno
import json
import os

import numpy as np
import pytest
from PIL import Image

from snell_bench.config import ConfigError, check_config, compose
from snell_bench.config.camera import MAX_FOV_DEG, focal_for_fov, implied_fov_deg, min_fov_deg
from tests.experiment.test_exit_status import CHEAP
from tests.experiment.test_photo import FRAME


def one_error_line(err: str) -> str:
    """The only line of ``err`` (stderr), which starts with ``Error:``."""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: ") and "Traceback" not in err, err
    return lines[0]


# ---------------------------------------------------------------------------------------------- photo
def _depth_of_another_size(tmp):
    Image.fromarray(np.full((240, 320), 10000, np.uint16)).save(tmp / "small.png")
    return [f"scene.depth={tmp / 'small.png'}"]


def _one_pixel_photo(tmp):
    Image.fromarray(np.zeros((1, 1, 3), np.uint8)).save(tmp / "one.png")
    return [f"scene.image={tmp / 'one.png'}", "scene.depth=null", "scene.intrinsics=null", "scene.fov_deg=60"]


def _negative_depth(tmp):
    np.save(tmp / "opengl.npy", np.full((480, 640), -1.5, np.float32))  # z < 0 in front of an OpenGL camera
    return [f"scene.depth={tmp / 'opengl.npy'}", "scene.depth_scale=null"]


@pytest.mark.parametrize(
    "make, expected",
    [
        (_depth_of_another_size, ["scene.depth=", "has shape (240, 320)", "resize or re-register it to 640x480"]),
        (_one_pixel_photo, ["scene.image=", "is 1x1 pixels, smaller than one", "set scene.image to a photo of at"]),
        (
            _negative_depth,
            ["scene.depth=", "all 307200 pixels are negative: if the file stores depth as negative z (OpenGL), negate"],
        ),
    ],
    ids=["depth-of-another-size", "1x1-photo", "all-negative-depth"],
)
def test_a_refused_photo_is_one_line_and_exit_status_1(run_cli, tmp_path, capsys, make, expected):
    assert run_cli("scene=tum_office", *make(tmp_path), "job=preview", f"output_dir={tmp_path / 'out'}") == 1
    line = one_error_line(capsys.readouterr().err)
    for part in expected:
        assert part in line, line
    assert not (tmp_path / "out").exists()  # refused before any work


def test_a_refused_photo_stays_a_value_error_and_a_bug_keeps_its_traceback(tmp_path, monkeypatch):
    """The refusals are :class:`ConfigError` (a ``ValueError``: callers catching that still do);
    an exception that is not one is not turned into a line."""
    from snell_bench.scene.image_source import inspect_photo

    Image.fromarray(np.zeros((1, 1, 3), np.uint8)).save(tmp_path / "one.png")
    with pytest.raises(ConfigError, match=r"is 1x1 pixels, smaller than one 16x16 block"):
        inspect_photo(tmp_path / "one.png", fov_deg=60.0, block=16)
    np.save(tmp_path / "some.npy", np.where(np.arange(6).reshape(2, 3) % 2, -1.0, 0.0))
    with pytest.raises(ValueError, match=r"3 of its 6 pixels are negative \(the others 0, NaN or infinite\)"):
        from snell_bench.scene.image_source import load_depth

        load_depth(tmp_path / "some.npy")

    def broken(*args, **kwargs):
        raise ValueError("a bug")

    monkeypatch.setattr("snell_bench.scene.image_source.photo_info", broken)
    Image.open(FRAME / "color.png").save(tmp_path / "color.png")
    with pytest.raises(ValueError, match="a bug") as e:
        inspect_photo(tmp_path / "color.png", fov_deg=60.0)
    assert not isinstance(e.value, ConfigError)


# ---------------------------------------------------------------------------------------------- intrinsics
@pytest.mark.parametrize("fov", [179.9, 0.01])
def test_intrinsics_of_an_unusable_field_of_view_are_refused_like_fov_deg(fov):
    """fx from the angle over the bundled photo's 640-pixel width; before, these passed the checks
    and the run ended in the unrelated "no horizontal supporting surface"."""
    fx = focal_for_fov(fov, 640)
    assert implied_fov_deg(fx, 640) == pytest.approx(fov)
    with pytest.raises(ConfigError) as e:
        check_config(compose(["scene=tum_office", f"scene.intrinsics=[{fx!r},{fx!r},319.5,239.5]"]))
    line = str(e.value)
    assert len(line.splitlines()) == 1 and line.startswith("scene.intrinsics=[")
    assert f"over the 640-pixel width of scene.image='{compose(['scene=tum_office']).scene.image}'" in line
    assert f"implies a horizontal field of view of {fov:g} degrees" in line
    if fov > MAX_FOV_DEG:
        assert f"more than {MAX_FOV_DEG:g}" in line and "set scene.intrinsics with fx >= 85.75" in line
        fits = 85.75
    else:
        assert "at object.relative_size=0.25 the object" in line and "it fits with fx <= 2560" in line
        fits = 2560
    assert min_fov_deg(0.25) <= implied_fov_deg(fits, 640) <= MAX_FOV_DEG  # the fx it names fits
    check_config(compose(["scene=tum_office", f"scene.intrinsics=[{fits},{fits},319.5,239.5]"]))


def test_a_generated_scenes_intrinsics_are_read_over_scene_width():
    with pytest.raises(ConfigError, match=r"fx=0\.5 over the 1280-pixel width of scene\.width implies .* 179\.9 deg"):
        check_config(compose(["model=tiny_flux", "scene.width=1280", "scene.intrinsics=[0.5,0.5,640,360]"]))


def test_the_implied_field_of_view_follows_the_photo_files_width(tmp_path):
    """The same fx over a photo twice as wide: twice the angle's tangent (another verdict)."""
    Image.new("RGB", (64, 48)).save(tmp_path / "narrow.png")
    Image.new("RGB", (2000, 48)).save(tmp_path / "wide.png")
    k = "scene.intrinsics=[100,100,31.5,23.5]"
    check_config(compose(["scene=tum_office", "scene.depth=null", f"scene.image={tmp_path / 'narrow.png'}", k]))
    with pytest.raises(ConfigError, match=r"fx=100 over the 2000-pixel width .* 168\.6 degrees"):
        check_config(compose(["scene=tum_office", "scene.depth=null", f"scene.image={tmp_path / 'wide.png'}", k]))


# ---------------------------------------------------------------------------------------------- report
def _full_disk(calls):
    def build_reports(root, out, name, **kwargs):
        calls.append(out)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(out / "README.md"))

    return build_reports


def test_a_report_on_a_full_disk_is_one_line_naming_the_folder(run_cli, tmp_path, capsys, monkeypatch):
    record = tmp_path / "runs" / "smoke" / "living_room-0" / "sphere" / "t2i" / "metrics.json"
    record.parent.mkdir(parents=True)
    record.write_text(json.dumps({"status": "failed", "reason": "a record to report"}))
    calls = []
    monkeypatch.setattr("snell_bench.reports.build_reports", _full_disk(calls))
    assert run_cli("job=report", "experiment_name=smoke") == 1
    line = one_error_line(capsys.readouterr().err)
    out = tmp_path / "reports" / "smoke"
    assert calls == [out]
    assert line == (
        f"Error: job=report: cannot write the report folder {out} (README.md): No space left on device; free space on "
        "its disk, or set reports_dir=<a folder on another disk>"
    )


def test_a_report_refused_permission_names_the_folder_to_make_writable(tmp_path, monkeypatch):
    from snell_bench.experiment import ReportNotWritten, write_report

    def read_only(root, out, name, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(out / "images" / "a.png"))

    monkeypatch.setattr("snell_bench.reports.build_reports", read_only)
    out = tmp_path / "reports" / "smoke"
    with pytest.raises(ReportNotWritten) as e:
        write_report(tmp_path / "runs" / "smoke", out, "smoke")
    assert str(e.value) == (
        f"cannot write the report folder {out} (images/a.png): Permission denied; make {out.parent} writable, or "
        "set reports_dir=<a folder you can write>"
    )


@pytest.fixture
def open_box(tmp_path):
    """A box without its lid: a cell tracing it as ``object=fox`` fails (the mesh is not watertight)."""
    import trimesh

    box = trimesh.creation.box()
    box.update_faces(box.face_normals[:, 2] < 0.5)
    path = tmp_path / "open_box.ply"
    box.export(path)
    return path


def test_a_grid_whose_report_cannot_be_written_keeps_exit_status_3(run_cli, open_box, tmp_path, capsys, monkeypatch):
    calls = []
    monkeypatch.setattr("snell_bench.reports.build_reports", _full_disk(calls))
    assert run_cli(*CHEAP, "grid.objects=[fox]", f"object.path={open_box}") == 3
    out, err = capsys.readouterr()
    report = tmp_path / "reports" / "smoke"
    assert calls == [report]
    assert "smoke: 0 ok, 0 already done, 0 skipped, 1 failed (exit status 3: cells failed; " in out
    errors = [line for line in (out + err).splitlines() if "[snell_bench.experiment.report_job][ERROR]" in line]
    assert len(errors) == 1 and "Traceback" not in out + err, out + err
    assert errors[0].endswith(
        f"report: cannot write the report folder {report} (README.md): No space left on device; free space on its "
        "disk, or set reports_dir=<a folder on another disk>; then build it with job=report experiment_name=smoke"
    )
    assert "Error: cells of experiment_name=smoke failed" in err and "exit status 3" in err
    summary = json.loads((tmp_path / "runs" / "smoke" / "summary.json").read_text())
    assert summary["exit_status"] == 3
