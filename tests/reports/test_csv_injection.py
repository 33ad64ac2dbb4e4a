"""CSV formula injection (OWASP, "CSV Injection"): every string cell, index label and column header
that starts with ``=``, ``+``, ``-``, ``@``, a tab or a carriage return is written with a ``'`` in
front, by :func:`csv_safe` itself, by the reports' CSV writer and by the relighting report; numbers
(a negative one included) are left as they are."""

import csv
import math

import numpy as np
import pandas as pd

from snell_bench.experiment.relighting import write_report
from snell_bench.reports.writers import csv_safe, to_csv

DANGEROUS = ("=", "+", "-", "@", "\t", "\r")
#: One hostile label per leading character, then a benign one.
HOSTILE = [f"{c}2+5+cmd|' /C calc'!A0" for c in DANGEROUS]
BENIGN = "snellcaster"


def _table() -> pd.DataFrame:
    """A table whose index, column headers and string cells hold every hostile label."""
    n = len(HOSTILE) + 1
    return pd.DataFrame(
        {
            "method": [*HOSTILE, BENIGN],
            "psnr": np.linspace(-1.5, 3.0, n),
            HOSTILE[0]: [BENIGN] * n,
            "-delta": [-2] * n,
        },
        index=pd.Index([*HOSTILE, BENIGN], name="@scene"),
    )


def _rows(path) -> list[list[str]]:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.reader(f))


def _is_number(field: str) -> bool:
    try:
        float(field)
    except ValueError:
        return False
    return True


def _assert_no_formula(rows: list[list[str]]) -> None:
    """No field starts like a formula, unless it is a number (``-1.5`` is not a formula)."""
    for r, row in enumerate(rows):
        for c, field in enumerate(row):
            assert _is_number(field) or not field.startswith(DANGEROUS), (r, c, field)


def test_csv_safe_quotes_strings_that_start_like_a_formula():
    table = _table()
    safe = csv_safe(table)
    assert safe["method"].tolist() == [*("'" + h for h in HOSTILE), BENIGN]
    assert safe.index.tolist() == [*("'" + h for h in HOSTILE), BENIGN]
    assert safe.index.name == "'@scene"
    assert safe.columns.tolist() == ["method", "psnr", "'" + HOSTILE[0], "'-delta"]
    # numbers are not formulas: the numeric columns keep their dtype and values
    assert safe["psnr"].dtype == table["psnr"].dtype
    assert safe["psnr"].tolist() == table["psnr"].tolist()
    assert safe["'-delta"].tolist() == [-2] * len(table)
    # a pure function: the table itself is unchanged
    assert table["method"].tolist() == [*HOSTILE, BENIGN]
    assert table.index.name == "@scene"


def test_csv_safe_multiindex_and_missing_values():
    index = pd.MultiIndex.from_tuples([("=a", 1), ("b", 2)], names=["+level", "n"])
    table = pd.DataFrame({("@x", "-y"): ["-1", None], ("z", "w"): [-1.0, math.nan]}, index=index)
    safe = csv_safe(table)
    assert safe.index.tolist() == [("'=a", 1), ("b", 2)]
    assert list(safe.index.names) == ["'+level", "n"]
    assert safe.columns.tolist() == [("'@x", "'-y"), ("z", "w")]
    assert safe.iloc[0, 0] == "'-1" and pd.isna(safe.iloc[1, 0])
    assert safe.iloc[0, 1] == -1.0 and math.isnan(safe.iloc[1, 1])


def test_to_csv_writes_no_formula(tmp_path):
    path = tmp_path / "table.csv"
    to_csv(_table(), path)
    text = path.read_bytes().decode("utf-8")  # no newline translation
    rows = _rows(path)
    _assert_no_formula(rows)
    assert rows[0] == ["'@scene", "method", "psnr", "'" + HOSTILE[0], "'-delta"]
    assert all(f"'{h},'{h}," in text for h in HOSTILE)  # index and cell, each with its quote
    # numbers are written as numbers; the row of the carriage return is split by CSV readers
    # (Python's csv writer does not quote a lone CR under a "\n" line terminator), so read others
    by_label = {r[0]: r for r in rows[1:]}
    assert by_label["'" + HOSTILE[0]][2:] == ["-1.5", BENIGN, "-2"]
    assert by_label[BENIGN][4] == "-2"


def test_relighting_report_writes_no_formula(tmp_path):
    # every method missing: no image is read, only the table and an empty figure are written
    rows = [
        {"scene": label, "object": "=sphere", "method": "none", "missing": "-no image", "seconds": -1.5}
        for label in [*HOSTILE, BENIGN]
    ]
    write_report(rows, tmp_path / "runs", tmp_path / "reports")
    path = tmp_path / "reports" / "relighting.csv"
    text = path.read_bytes().decode("utf-8")  # no newline translation
    table = _rows(path)
    header = table[0]
    seconds = header.index("seconds")
    _assert_no_formula(table)
    assert all(f"'{h},'=sphere,none," in text for h in HOSTILE)
    whole = [r for r in table[1:] if r[0] in {"'" + h for h in HOSTILE} | {BENIGN, "mean"}]
    assert len(whole) == len(HOSTILE) + 1  # every row but the carriage return's (split by readers)
    assert {r[header.index("missing")] for r in whole if r[0] != "mean"} == {"'-no image"}
    assert {r[seconds] for r in whole} == {"-1.5"}
    assert not list(path.parent.glob(".relighting.csv.*"))  # written atomically, no temporary left


def test_a_carriage_return_inside_a_label_starts_no_row():
    import csv
    import io

    from snell_bench.reports.writers import csv_safe

    text = csv_safe(pd.DataFrame({"label": ["a\r=cmd|' /C calc'!A0", "b\r\n@x"]})).to_csv(index=False)
    rows = list(csv.reader(io.StringIO(text)))
    assert len(rows) == 3 and all(not r[0].startswith(("=", "@")) for r in rows)
