"""A seeded fuzz of damaged and hostile cell folders (truncated, nested, linked, oversized, bombs)
fed to ``job=report`` and to the runner's resume: no traceback, no read outside the run (checked
with an audit hook), each damaged cell named once in the report, the others unchanged, and after
the resume every cell finished again."""

import json
import shutil
import struct
import sys
import zlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image
from tiny_runs import smoke_cfg

ROUNDS = 3

_OPENED: list[str] = []
sys.addaudithook(lambda event, args: _OPENED.append(str(args[0])) if event == "open" and args else None)


def _cfg(root: Path, *more):
    return smoke_cfg(root, *more)


def _png_header(path: Path, w: int, h: int) -> None:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0")) + chunk(b"IEND", b"")
    )


def _relink(path: Path, target: Path) -> None:
    path.unlink(missing_ok=True)
    path.symlink_to(target)


def _damages(outside: Path) -> dict:
    """Each damage: a function of (cell folder, rng) that breaks it."""

    def truncate(f):
        return lambda d, rng: (d / f).write_bytes((d / f).read_bytes()[: int(rng.integers(0, (d / f).stat().st_size))])

    def files_outside(d, rng):
        rec = json.loads((d / "metrics.json").read_text())
        rec["files"]["../" * int(rng.integers(1, 8)) + "outside/bait.bin"] = {"bytes": 1, "sha256": "0"}
        (d / "metrics.json").write_text(json.dumps(rec))

    def alias_bomb(d, rng):
        lines = ["a0: &a0 [" + ",".join(['"x"'] * 9) + "]"]
        lines += [f"a{k}: &a{k} [" + ",".join([f"*a{k - 1}"] * 9) + "]" for k in range(1, 9)]
        (d / "config.yaml").write_text("\n".join(lines) + "\n")

    return {
        "truncated record": truncate("metrics.json"),
        "truncated image": truncate("image.png"),
        "truncated config": truncate("config.yaml"),
        "nested record": lambda d, rng: (d / "metrics.json").write_text("[" * 50_000 + "]" * 50_000),
        "oversized record": lambda d, rng: (d / "metrics.json").open("r+b").truncate(40 * 2**20),
        "record linked outside": lambda d, rng: _relink(d / "metrics.json", outside / "metrics.json"),
        "image linked outside": lambda d, rng: _relink(d / "image.png", outside / "bait.png"),
        "folder linked outside": lambda d, rng: _relink(d / "reference.png", outside),
        "files entry outside": files_outside,
        "image bomb": lambda d, rng: _png_header(d / "image.png", 60_000, 60_000),
        "config alias bomb": alias_bomb,
        "image gone": lambda d, rng: (d / "image.png").unlink(),
    }


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    from snell_bench.experiment.runner import run_grid

    root = tmp_path_factory.mktemp("fuzz")
    assert run_grid(_cfg(root, "grid.report=false"))["ok"] == 4
    return root


def _cells(root: Path) -> list[Path]:
    return sorted(p.parent for p in (root / "runs" / "smoke").rglob("metrics.json"))


@pytest.mark.parametrize("seed", range(ROUNDS))
def test_damaged_cells_are_named_once_and_nothing_outside_is_read(finished, tmp_path, seed, caplog):
    from snell_bench.experiment import run_job
    from snell_bench.experiment.runner import run_grid
    from snell_bench.reports import collect, skipped_files

    rng = np.random.default_rng(seed)
    shutil.copytree(finished / "runs", tmp_path / "runs")
    outside = tmp_path / "outside"
    outside.mkdir()
    Image.fromarray(np.full((64, 96, 3), 7, np.uint8)).save(outside / "bait.png")
    (outside / "bait.bin").write_bytes(b"bait")
    shutil.copy(_cells(finished)[0] / "metrics.json", outside / "metrics.json")
    before = collect(tmp_path / "runs" / "smoke").set_index("cell_dir")
    cells = _cells(tmp_path)
    damages = _damages(outside)
    hit = rng.choice(len(cells), size=2, replace=False)
    names = rng.choice(sorted(damages), size=2, replace=False)
    damaged = {}
    for i, name in zip(hit, names):
        damages[name](cells[i], rng)
        damaged[cells[i].relative_to(tmp_path / "runs" / "smoke").as_posix()] = name
    start = len(_OPENED)
    assert run_job(_cfg(tmp_path, "job=report")) in (0, 1)  # a report, or one line when none is left
    df = collect(tmp_path / "runs" / "smoke")
    skipped = {Path(p).parent.as_posix() for p, _ in skipped_files(df)}
    rows = df.set_index("cell_dir") if "cell_dir" in df else pd.DataFrame()
    for cell, name in damaged.items():
        in_table = cell in rows.index and rows.loc[cell, "status"] != "ok"
        assert in_table != (cell in skipped), (name, cell)  # named once: a row not ok, or a skipped file
    for cell in before.index.difference(list(damaged)):
        assert rows.loc[cell, "status"] == "ok" and rows.loc[cell, "psnr"] == before.loc[cell, "psnr"]
    summary = run_grid(_cfg(tmp_path, "grid.report=false"))
    assert summary["ok"] == len(damaged) and summary["cached"] == 4 - len(damaged), (damaged, summary)
    read = [p for p in _OPENED[start:] if str(Path(p).resolve()).startswith(str(outside.resolve()))]
    assert read == [], (damaged, read)
    assert all(not (c / "metrics.json").is_symlink() for c in _cells(tmp_path))
