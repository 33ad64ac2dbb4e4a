"""Inputs known by content: the files a cell reads (its photo, depth, surface mask, mesh) enter its
settings as content hashes, so a file edited in place or replaced under the same path is a changed
setting (``grid.on_change``: refuse naming the file, or compute again), never an old result standing
for a new input.

Convention:
    - The keys: :data:`INPUT_FILE_KEYS`, each found as the cell would find it
      (:func:`~snell_bench.utils.paths.data_path`); a key that is unset or names no file adds
      nothing (the cell fails with that file's own message).
    - A setting ``"<key> (content sha256)"`` holds the file's SHA-256; the record keeps them
      (``input_sha256``) to compare with on the next run. A cell recorded before they existed
      has none: its inputs are taken as unchanged.
    - A file is hashed once per (real path, size, modification time): the hashes are kept in
      ``<runs_dir>/.content-hashes.json``, so a large photo is not read again on every run.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from snell_bench.utils.io import file_sha256, write_text
from snell_bench.utils.paths import data_path
from snell_bench.utils.trust import read_json

__all__ = ["CONTENT", "INPUT_FILE_KEYS", "input_content"]

#: The keys that name a file a cell reads.
INPUT_FILE_KEYS = ("scene.image", "scene.depth", "segment.mask", "object.path")
#: The suffix of a content setting's key.
CONTENT = " (content sha256)"

_MEMO: dict[tuple, str] = {}


def input_content(cfg: DictConfig) -> dict[str, str]:
    """``{"scene.image (content sha256)": "...", ...}`` for the input files ``cfg`` names."""
    out = {}
    for key in INPUT_FILE_KEYS:
        value = OmegaConf.select(cfg, key, default=None)
        if not value:
            continue
        try:
            path = Path(data_path(str(value), key)).resolve()
            stat = path.stat()
        except OSError:
            continue
        out[key + CONTENT] = _sha256(path, stat, Path(str(cfg.runs_dir)) / ".content-hashes.json")
    return out


def _sha256(path: Path, stat: os.stat_result, cache: Path) -> str:
    key = (str(path), stat.st_size, stat.st_mtime_ns)
    if key in _MEMO:
        return _MEMO[key]
    name = "\t".join(map(str, key))
    saved, _ = read_json(cache) if cache.is_file() else ({}, None)
    saved = saved if isinstance(saved, dict) else {}
    if isinstance(saved.get(name), str):
        _MEMO[key] = saved[name]
        return saved[name]
    _MEMO[key] = digest = file_sha256(path)
    try:  # a cache: another process may write it too (the last one wins), a failure costs a re-hash
        cache.parent.mkdir(parents=True, exist_ok=True)
        write_text(cache, json.dumps({**saved, name: digest}, indent=0))
    except OSError:
        pass
    return digest
