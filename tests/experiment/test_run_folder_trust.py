"""A run folder is data: records pointing outside, links, alias bombs, deep JSON and decompression
bombs, each built here, against the runner's resume and ``job=report``; and a seeded fuzz of
damaged cell folders. Reads outside the run are checked with an audit hook, not assumed."""

import json
import shutil
import struct
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from tiny_runs import smoke_cfg

from snell_bench.utils.io import file_sha256

EXTRA = ["grid.methods=[t2i]"]
CELL = Path("living_room-0") / "sphere" / "t2i"

_OPENED: list[str] = []


def _audit(event, args):
    if event == "open" and args and isinstance(args[0], (str, bytes, Path)):
        _OPENED.append(str(args[0]))


sys.addaudithook(_audit)


def _cfg(root: Path, *more):
    return smoke_cfg(root, *EXTRA, *more)


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished two-cell run (living room and kitchen, t2i, with references)."""
    from snell_bench.experiment.runner import run_grid

    root = tmp_path_factory.mktemp("finished")
    assert run_grid(_cfg(root))["ok"] == 2
    return root


@pytest.fixture
def run(finished, tmp_path):
    """A copy of the finished run to damage, and a folder outside it holding bait files."""
    shutil.copytree(finished / "runs", tmp_path / "runs")
    outside = tmp_path / "outside"
    outside.mkdir()
    Image.fromarray(np.full((64, 96, 3), 200, np.uint8)).save(outside / "bait.png")
    (outside / "bait.bin").write_bytes(b"x" * 4096)
    return tmp_path, outside


class _Reads:
    """The files opened under ``folder`` while the block runs."""

    def __init__(self, folder: Path):
        self.folder = str(folder.resolve())

    def __enter__(self):
        self.start = len(_OPENED)
        return self

    def __exit__(self, *exc):
        self.paths = [p for p in _OPENED[self.start :] if str(Path(p).resolve()).startswith(self.folder)]


def _resume(root: Path):
    from snell_bench.experiment.runner import run_grid

    return run_grid(_cfg(root, "grid.report=false"))


def _report(root: Path):
    from snell_bench.experiment import run_job

    return run_job(_cfg(root, "job=report"))


def _record(root: Path) -> Path:
    return root / "runs" / "smoke" / CELL / "metrics.json"


def test_a_files_entry_outside_the_cell_is_damage_and_is_never_read(run, caplog):
    root, outside = run
    path = _record(root)
    rec = json.loads(path.read_text())
    rel = Path("..", "..", "..", "..", "..", "outside", "bait.bin").as_posix()
    assert (path.parent / rel).resolve() == (outside / "bait.bin").resolve()
    rec["files"][rel] = {"bytes": 4096, "sha256": "0" * 64}
    rec["files"][str(outside / "bait.bin")] = {"bytes": 4096, "sha256": "0" * 64}
    path.write_text(json.dumps(rec))
    with _Reads(outside) as reads:
        summary = _resume(root)
    assert reads.paths == []
    assert summary["ok"] == 1 and summary["cached"] == 1  # the damaged cell computed again
    assert "leaves" in caplog.text and "files entry" in caplog.text


def test_a_linked_image_is_neither_followed_nor_copied_into_the_report(run, caplog):
    root, outside = run
    cell = _record(root).parent
    (cell / "image.png").unlink()
    (cell / "image.png").symlink_to(outside / "bait.png")
    with _Reads(outside) as reads:
        assert _report(root) == 0
        summary = _resume(root)
    assert reads.paths == []
    assert "symbolic link" in caplog.text
    assert summary["cached"] == 1 and not (cell / "image.png").is_symlink()  # recomputed, its own image again


def test_a_trade_off_records_inputs_dir_outside_its_group_is_not_loaded(run, caplog):
    from snell_bench.reports.tradeoff import reference_psnr_vs_max_spp

    root, outside = run
    np.save(outside / "reference.npy", np.zeros((4, 4, 3), np.float32))
    np.save(outside / "metric_mask.npy", np.ones((4, 4), bool))
    group = root / "runs" / "group"
    group.mkdir()
    records = [
        {"_group": "group", "status": "ok", "axis": "reference.spp", "method_name": "m", "inputs_dir": str(outside)}
        | {"overrides": {"reference.spp": spp}, "_dir": f"c{spp}"}
        for spp in (4, 8)
    ]
    with _Reads(outside) as reads:
        out = reference_psnr_vs_max_spp(group.parent, records)
    assert reads.paths == []
    assert out == {"c4": None, "c8": None} and "inputs_dir" in caplog.text


def test_an_alias_bomb_config_is_refused_in_milliseconds(run, caplog):
    root, _ = run
    levels = ["a: &a [" + ",".join(['"lol"'] * 9) + "]"]
    for k in range(1, 9):
        prev, name = chr(ord("a") + k - 1), chr(ord("a") + k)
        levels.append(f"{name}: &{name} [" + ",".join([f"*{prev}"] * 9) + "]")
    bomb = "\n".join(levels) + "\n"
    assert len(bomb) < 400
    cell = _record(root).parent
    (cell / "config.yaml").write_text(bomb)
    rec = json.loads(_record(root).read_text())  # the record lists the bomb: the cell looks finished
    rec["files"]["config.yaml"] = {"bytes": len(bomb), "sha256": file_sha256(cell / "config.yaml")}
    _record(root).write_text(json.dumps(rec))
    t0 = time.perf_counter()
    assert _report(root) == 0
    summary = _resume(root)
    assert time.perf_counter() - t0 < 60
    assert summary["cached"] == 2  # its settings hash holds: the config is not needed to resume
    assert "nodes" in caplog.text  # named by the report's check of the cells' settings


def test_a_deeply_nested_record_is_damage_not_a_crash(run, caplog):
    root, _ = run
    _record(root).write_text("[" * 100_000 + "]" * 100_000)
    assert _report(root) == 0
    assert "nested more than" in caplog.text
    assert _resume(root)["cached"] == 1


def _png_header_only(path: Path, width: int, height: int) -> None:
    """A PNG whose header claims ``width x height`` pixels, with almost no pixel data (a
    decompression bomb's header, a few hundred bytes)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")
    )


@pytest.mark.parametrize("size", [(50_000, 50_000), (11_000, 10_000)], ids=["bomb", "110Mpx"])
def test_an_oversized_image_is_refused_from_its_header(run, caplog, size):
    root, _ = run
    _png_header_only(_record(root).parent / "image.png", *size)
    assert _report(root) == 0
    assert "more pixels than a run's image may have" in caplog.text


class _Payload:
    """A pickle that writes a file when it is loaded (what a planted pickle could do)."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_a_kept_pickle_runs_nothing_unless_this_user_signed_it(tmp_path, caplog):
    import pickle

    from snell_bench.experiment.files import read_inputs
    from snell_bench.utils.trust import read_signed, signed

    marker = tmp_path / "ran"
    kept = tmp_path / "_inputs" / "inputs-0.pkl"
    kept.parent.mkdir()
    kept.write_bytes(pickle.dumps({"inputs": _Payload(marker), "files": []}))  # unsigned
    assert read_inputs(kept) is None and not marker.exists()
    forged = signed(b"x")[:-1] + pickle.dumps({"inputs": _Payload(marker), "files": []})  # a signature of other bytes
    kept.write_bytes(forged)
    assert read_inputs(kept) is None and not marker.exists()
    assert "not signed with this user's key" in caplog.text
    kept.write_bytes(signed(b"payload"))
    assert read_signed(kept) == (b"payload", None)
