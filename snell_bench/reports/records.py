"""What a cell's record file must hold to count as a cell: the JSON Schemas of a grid cell's
``metrics.json`` (:data:`GRID_RECORD`), and :func:`load_record`, which reads one and says what is wrong with it.

The reports and the cell loop read a record only through :func:`load_record`: a file that is not
UTF-8, not JSON, not an object, or that breaks its schema is *not a cell*. The reports leave it out
with a warning naming its path and the problem, and count it (their "files skipped" section); the
cell loop computes that cell again. A record is data only: nothing in it is ever run.

Conventions:
    - ``status`` is ``"ok"``, ``"failed"``, ``"skipped"`` or ``"degenerate"`` (a result that could
      not mean anything, :class:`~snell_bench.pipeline.Degenerate`); ``reason`` is a string (why) or
      null, and a string for the last three.
    - The identity keys are required: ``scene`` (string) and ``variation`` (integer >= 0), then
      ``object`` and ``method``, strings; a cell of a setting (``grid.axes``) also names its
      ``setting``, ``method_name`` and ``setting_overrides``.
    - An ``ok`` record holds ``metrics``, a mapping of metric name to a number or null (a JSON
      ``NaN`` or ``Infinity`` is a number here; the reports show it as missing, "not finite in the
      record").
    - A PSNR is at most the scorer's ceiling (80 dB; identical pixels are recorded there), with
      the reason in ``notes`` (metric name -> string).
    - Every other key the reports read has its type (``missing``: strings or null; ``timings_s``:
      numbers or null; ``model_calls``: integers or null; nested groups: objects). Keys the
      schemas do not name are allowed (records of newer versions).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from snell_bench.utils.io import file_sha256
from snell_bench.utils.trust import UntrustedPath, read_json, safe_path

__all__ = ["GRID_RECORD", "files_problem", "load_record", "record_problem", "non_finite"]

_STR = {"type": "string"}
_OPT_STR = {"type": ["string", "null"]}
_NUMBERS = {"type": "object", "additionalProperties": {"type": ["number", "null"]}}
_REASONS = {"type": "object", "additionalProperties": {"type": ["string", "null"]}}
_COUNTS = {"type": "object", "additionalProperties": {"type": ["integer", "null"]}}
_OBJECT = {"type": "object"}
_OPT_OBJECT = {"type": ["object", "null"]}

_COMMON_PROPERTIES = {
    "status": {"enum": ["ok", "failed", "skipped", "degenerate"]},
    "reason": _OPT_STR,
    "experiment": _STR,
    "scene": _STR,
    "variation": {"type": "integer", "minimum": 0},
    "object": _STR,
    "method": _STR,
    "model": _STR,
    "scene_source": _STR,
    "generator_on_procedural": {"type": "boolean"},
    "initial_noise": _OBJECT,
    "protocol": _OPT_STR,
    "metrics": _NUMBERS,
    "missing": _REASONS,
    "notes": _REASONS,
    "timings_s": _NUMBERS,
    "sampler_timings_s": _NUMBERS,
    "model_calls": _COUNTS,
    "reference": _OPT_OBJECT,
    "decisions": _OBJECT,
    "settings_hash": _STR,
    "input_sha256": {"type": "object", "additionalProperties": _STR},
    "traceback": _STR,
    "files": {
        "type": "object",
        "additionalProperties": {
            "type": "object",
            "properties": {"bytes": {"type": "integer", "minimum": 0}, "sha256": _STR},
        },
    },
}

#: A reason is a string where the cell did not finish ok.
_REASON_WHEN_NOT_OK = {
    "if": {"properties": {"status": {"enum": ["failed", "skipped", "degenerate"]}}, "required": ["status"]},
    "then": {"required": ["reason"], "properties": {"reason": _STR}},
}


def _ok_requires(*keys: str) -> dict:
    return {"if": {"properties": {"status": {"const": "ok"}}, "required": ["status"]}, "then": {"required": list(keys)}}


#: JSON Schema (draft 2020-12) of a grid cell's ``metrics.json``.
GRID_RECORD: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "metrics.json of a grid cell",
    "type": "object",
    "required": ["status", "scene", "variation", "object", "method"],
    "properties": {
        **_COMMON_PROPERTIES,
        "object_spec": _STR,
        "method_label": _STR,
        "method_kind": _STR,
        "images": _OBJECT,
        "recipe": _OPT_STR,
        "random_weights": {"type": "boolean"},
        "warps": _OBJECT,
        "scene_info": _OBJECT,
        # a cell of a setting (grid.axes, grid.presets): snell_bench.experiment.sweep
        "setting": _STR,
        "method_name": _STR,
        "slug": _STR,
        "order": {"type": "integer"},
        "axis": _OPT_STR,
        "overrides": _OBJECT,
        "setting_overrides": {"type": "array", "items": _STR},
        "knobs": _OBJECT,
        "inputs_key": _STR,
        "inputs_dir": _STR,
        "converged_reference": _OPT_OBJECT,
    },
    "allOf": [
        _REASON_WHEN_NOT_OK,
        _ok_requires("metrics"),
        {"if": {"required": ["setting"]}, "then": {"required": ["method_name", "setting_overrides"]}},
    ],
}

_VALIDATORS: dict[int, Any] = {}


def _validator(schema: dict):
    """The compiled validator of ``schema`` (compiled once)."""
    key = id(schema)
    if key not in _VALIDATORS:
        from jsonschema import Draft202012Validator

        Draft202012Validator.check_schema(schema)
        _VALIDATORS[key] = Draft202012Validator(schema)
    return _VALIDATORS[key]


def _where(error) -> str:
    path = ".".join(str(p) for p in error.absolute_path)
    return f"{path}: " if path else ""


def record_problem(record: Any, schema: dict | None) -> str | None:
    """What is wrong with a parsed record, or ``None``.

    Args:
        record: the parsed JSON value.
        schema: :data:`GRID_RECORD` or ``None`` (only "an object" is
            checked).

    Returns:
        ``None`` for a valid record; else one line: the JSON type where an object is needed
        (``"a JSON array, not an object"``), or the schema's errors, each with the key it concerns
        (``"missing the keys scene, variation"``, ``"metrics.psnr: 'high' is not of type 'number',
        'null'"``; at most three, then how many more).

    Examples:
        >>> record_problem([1, 2], GRID_RECORD)
        'a JSON array, not an object'
        >>> record_problem({"status": "ok"}, GRID_RECORD)
        'missing the keys scene, variation, object, method, metrics'
        >>> record_problem({"status": "ok", "scene": "k", "variation": 0, "object": "sphere", "method": "t2i",
        ...                 "metrics": {"psnr": "high"}}, GRID_RECORD)
        "metrics.psnr: 'high' is not of type 'number', 'null'"
    """
    if not isinstance(record, dict):
        kinds = {list: "array", str: "string", bool: "boolean", int: "number", float: "number", type(None): "null"}
        return f"a JSON {kinds.get(type(record), type(record).__name__)}, not an object"
    if schema is None:
        return None
    missing: dict[str, list[str]] = {}
    other: list[str] = []
    for e in sorted(
        _validator(schema).iter_errors(record),
        key=lambda e: (list(map(str, e.absolute_path)), len(e.schema_path), e.message),
    ):
        if e.validator == "required":  # one error per absent key: said once, in the schema's order
            keys = missing.setdefault(_where(e), [])
            keys += [k for k in e.validator_value if k not in e.instance and k not in keys]
        else:
            other.append(f"{_where(e)}{e.message}")
    lines = [f"{where}missing the key{'s' if len(k) > 1 else ''} {', '.join(k)}" for where, k in missing.items()]
    lines += other
    if not lines:
        return None
    more = f"; and {len(lines) - 3} more" if len(lines) > 3 else ""
    return "; ".join(lines[:3]) + more


def load_record(path: str | Path, schema: dict | None = None) -> tuple[dict | None, str | None]:
    """Read a record file and check it against its schema.

    Args:
        path: the file (``metrics.json``).
        schema: its schema (:data:`GRID_RECORD`); ``None``: any JSON
            object is a record.

    Returns:
        ``(record, None)`` for a valid record; ``(None, problem)`` otherwise, the problem in one
        line: ``"cannot be read: ..."``, ``"not UTF-8 text: ..."``, ``"not valid JSON: ..."``, too
        large or too deeply nested (:func:`~snell_bench.utils.trust.read_json`), or
        :func:`record_problem`'s. A missing file is ``(None, "cannot be read: ...")`` too.
    """
    record, problem = read_json(path)  # bounded: size and nesting (snell_bench.utils.trust)
    if problem is not None:
        return None, problem
    problem = record_problem(record, schema)
    return (None, problem) if problem else (record, None)


def non_finite(values: Any) -> dict[str, float]:
    """The entries of a mapping of numbers that are numbers but not finite (NaN, ±inf).

    Args:
        values: a record's ``metrics`` (or any mapping); anything else has none.

    Returns:
        ``{name: value}`` of the non-finite ones, in the mapping's order.

    Examples:
        >>> non_finite({"psnr": float("inf"), "mae": 0.1, "lpips": None})
        {'psnr': inf}
    """
    if not isinstance(values, dict):
        return {}
    return {
        k: v
        for k, v in values.items()
        if isinstance(v, (int, float)) and not isinstance(v, bool) and not math.isfinite(v)
    }


def files_problem(folder: str | Path, record: dict) -> str | None:
    """Why the files ``record["files"]`` lists do not match the cell ``folder`` (a file missing, or
    of another size or content, or an entry that leaves the folder or names a link: the record is
    damaged, :func:`~snell_bench.utils.trust.safe_path`), or ``None``. The one check of a finished
    cell's files that the runner (:func:`~snell_bench.experiment.cell_state.cell_state`) and the
    reports share; nothing outside the folder is read or hashed."""
    for rel, want in (record.get("files") or {}).items():
        try:
            path = safe_path(folder, rel, "metrics.json files entry")
        except UntrustedPath as e:
            return str(e)
        if not path.is_file():
            return f"{rel} is missing"
        if path.stat().st_size != want.get("bytes") or file_sha256(path) != want.get("sha256"):
            return f"{rel} has changed since the cell finished"
    return None
