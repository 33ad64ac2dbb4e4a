"""Atomic writers: strict JSON and the umask's file mode."""

import json
import math
import os
import stat

import numpy as np

from snell_bench.utils.io import json_safe, save_npy, write_json


def test_json_has_no_nan_or_infinity(tmp_path):
    obj = {
        "psnr": float("nan"),
        "self_noise_db": math.inf,
        "values": [1.0, np.float32("-inf"), np.float64(2.5), (np.nan, 3)],
        "array": np.array([0.5, np.nan]),
        "n": np.int64(4),
        "ok": np.bool_(True),
        "name": "x",
    }
    p = write_json(tmp_path / "m.json", obj)
    text = p.read_text()
    assert "NaN" not in text and "Infinity" not in text

    def strict(c):
        raise ValueError(f"non-standard JSON constant {c}")

    back = json.loads(text, parse_constant=strict)  # a strict parser accepts it
    assert back == {
        "psnr": None,
        "self_noise_db": None,
        "values": [1.0, None, 2.5, [None, 3]],
        "array": [0.5, None],
        "n": 4,
        "ok": True,
        "name": "x",
    }
    assert json_safe({"a": [1, 2.0]}) == {"a": [1, 2.0]}  # finite values pass unchanged


def test_files_get_the_umask_mode(tmp_path):
    old = os.umask(0o022)
    try:
        a = write_json(tmp_path / "a.json", {"x": 1})
        b = save_npy(tmp_path / "b.npy", np.zeros(3))
        os.umask(0o002)
        c = write_json(tmp_path / "c.json", {"x": 1})
    finally:
        os.umask(old)
    assert stat.S_IMODE(a.stat().st_mode) == 0o644 and stat.S_IMODE(b.stat().st_mode) == 0o644
    assert stat.S_IMODE(c.stat().st_mode) == 0o664
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.npy", "c.json"]  # no temporaries
