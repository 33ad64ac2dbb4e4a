"""MkDocs hooks (mkdocs.yml ``hooks:``): the parts of the documentation generated at build time.

A page asks for a generated part with a marker on a line of its own (an HTML comment, invisible
where the hook does not run; indented, for a tab or an admonition, the part is indented alike):

- ``<!-- snell:config-schema -->``: every node of the config schema (the dataclasses of
  ``snell_bench/config/``): each key's type, default and the ``#:`` comment above it;
- ``<!-- snell:config-node NAME -->``: one node of it (``sampler``, ``tracker``, ...);
- ``<!-- snell:config-groups -->``: every config group of ``snell_bench/conf/`` with its options,
  what each is (the comment at the top of its file) and the keys it sets;
- ``<!-- snell:config-group NAME -->``: one group (``tracker``, ``hydra/launcher``, ...);
- ``<!-- snell:metrics -->``: every metric of the registry (built-in and installed), its label,
  direction, format and what it needs;
- ``<!-- snell:method-kinds -->``: every method kind of the registry and its class;
- ``<!-- snell:kit-fields -->``: the benchmark kit's fields and schema version;
- ``<!-- snell:results EXPERIMENT TABLE -->``: a table of ``reports/EXPERIMENT/`` from its committed
  snapshot in ``docs/results/data/EXPERIMENT/`` (``tools/docs_results.py`` makes it), with the
  report's provenance line, its notes and the commands that regenerate it; a clear note where the
  snapshot is missing.

An unknown marker fails the build. The schema is read from the source (``ast``), the groups from
their YAML files, the tables with pandas; the registries (metrics, method kinds, the kit's fields)
are imported from snell_bench itself, so what the docs list is what the code registers.
"""

from __future__ import annotations

import ast
import importlib.util
import io
import json
import math
import os
import re
import sys
import tokenize
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
import yaml
from mkdocs.exceptions import PluginError

__all__ = [
    "Field",
    "Node",
    "config_group",
    "config_groups",
    "config_node",
    "config_schema",
    "kit_fields_table",
    "method_kinds_table",
    "metrics_table",
    "on_page_markdown",
    "read_schema",
    "results_table",
]

ROOT = Path(__file__).resolve().parents[1]
CONFIG_SRC = ROOT / "snell_bench" / "config"
CONF_DIR = ROOT / "snell_bench" / "conf"
DATA_DIR = ROOT / "docs" / "results" / "data"

_MARKER = re.compile(r"^([ \t]*)<!--\s*snell:([a-z_-]+)((?:[ \t]+[^\s>]+)*)[ \t]*-->[ \t]*$", re.MULTILINE)


def _load_path(name: str, path: Path):
    """A module by file, without importing its package (``tools/`` is not one; the reports' spec
    module needs neither torch nor the rest of snell_bench)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


_griffe_ext = _load_path("snell_docs_griffe", ROOT / "tools" / "docs_griffe.py")
_results = _load_path("snell_docs_results", ROOT / "tools" / "docs_results.py")


def _md(text: str) -> str:
    """Docstring or comment text as Markdown (Sphinx roles and double backticks as code spans)."""
    return _plain(_griffe_ext.markdown_roles(" ".join(text.split())))


def _plain(text: str) -> str:
    """Prose from a comment or docstring, safe as Markdown: outside code spans, ``<`` is not a tag
    (``<experiment>``) and ``*`` is not emphasis (``offline-run-*``)."""
    parts = re.split(r"(`[^`]*`)", text)
    return "".join(p if p.startswith("`") else p.replace("<", "&lt;").replace("*", r"\*") for p in parts)


def _cell(text: str) -> str:
    """Text for a Markdown table cell: one line, ``|`` escaped outside code spans."""
    parts = re.split(r"(`[^`]*`)", " ".join(str(text).split()))
    return "".join(p if p.startswith("`") else p.replace("|", r"\|") for p in parts)


def _code(text: str) -> str:
    """A code span that holds any text (backticks inside it get a longer fence)."""
    text = str(text)
    fence = "``" if "`" in text else "`"
    pad = " " if text.startswith("`") or text.endswith("`") else ""
    return f"{fence}{pad}{text}{pad}{fence}"


def _table(head: list[str], rows: Iterable[list[str]], align: list[str] | None = None) -> str:
    """A Markdown pipe table (cells already Markdown)."""
    align = align or ["---"] * len(head)
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(align) + "|"]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------
# The config schema, read from the source
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Field:
    """One key of a schema node.

    Attributes:
        name: the key.
        type: its annotation as Markdown (an enum's values listed; ``or null`` where optional).
        default: its default as written in the YAML sense (``null``, ``true``, a list).
        doc: the ``#:`` comment above it (Markdown); for a key right below a commented key with no
            comment of its own, a pointer to that key.
    """

    name: str
    type: str
    default: str
    doc: str


@dataclass(frozen=True)
class Node:
    """A schema dataclass.

    Attributes:
        cls: the class name.
        module: the file it is defined in, relative to the checkout.
        doc: its docstring (Markdown).
        fields: its keys, in source order.
    """

    cls: str
    module: str
    doc: str
    fields: tuple[Field, ...]


def _comments(source: str) -> dict[int, str]:
    """The ``#:`` comment lines of a source file: line number -> text."""
    out = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT and tok.string.startswith("#:"):
            out[tok.start[0]] = tok.string[2:].strip()
    return out


def _enums(tree: ast.Module) -> dict[str, list[str]]:
    """Enum classes of a module: name -> the values of its members (string constants)."""
    out = {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            values = [
                s.value.value
                for s in node.body
                if isinstance(s, ast.Assign) and isinstance(s.value, ast.Constant) and isinstance(s.value.value, str)
            ]
            if values and any(getattr(b, "id", "") in ("Choice", "Enum", "str") for b in node.bases):
                out[node.name] = values
    return out


def _yaml_value(node: ast.expr, enums: dict[str, list[str]]) -> str:
    """A default as it reads in YAML."""
    if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "field":
        for kw in node.keywords:
            if kw.arg == "default_factory":
                f = kw.value
                if isinstance(f, ast.Lambda):
                    return _yaml_value(f.body, enums)
                name = ast.unparse(f)
                return {"list": "[]", "dict": "{}"}.get(name, f"({name})")
            if kw.arg == "default":
                return _yaml_value(kw.value, enums)
    if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in enums:
        return node.attr
    if isinstance(node, ast.Name) and node.id == "MISSING":
        return "??? (required)"
    try:
        value = ast.literal_eval(node)
    except ValueError:
        return ast.unparse(node)
    return json.dumps(value, ensure_ascii=False) if isinstance(value, (list, dict)) else _scalar(value)


def _scalar(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    return str(value)


def read_schema(paths: Iterable[Path] | None = None) -> dict[str, Node]:
    """Every dataclass of the config modules, with its fields, defaults and ``#:`` comments.

    Args:
        paths: the modules to read; default every ``snell_bench/config/*.py``.

    Returns:
        Class name -> :class:`Node`.
    """
    paths = sorted(CONFIG_SRC.glob("*.py")) if paths is None else list(paths)
    trees = {p: ast.parse(p.read_text(encoding="utf-8")) for p in paths}
    enums: dict[str, list[str]] = {}
    for tree in trees.values():
        enums.update(_enums(tree))
    nodes = {}
    for path, tree in trees.items():
        comments = _comments(path.read_text(encoding="utf-8"))
        for cls in tree.body:
            is_dc = isinstance(cls, ast.ClassDef) and any(
                ast.unparse(d).split("(")[0] in ("dataclass", "dataclasses.dataclass") for d in cls.decorator_list
            )
            if not is_dc:
                continue
            fields, prev_line, prev_name, prev_doc = [], None, None, ""
            for stmt in cls.body:
                if not (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)):
                    prev_line = None
                    continue
                lines, n = [], stmt.lineno - 1
                while n in comments:
                    lines.insert(0, comments[n])
                    n -= 1
                doc = _md(" ".join(lines))
                if not doc and prev_doc and prev_line == stmt.lineno - 1:
                    doc = f"See `{prev_name}`."
                else:
                    prev_name, prev_doc = stmt.target.id, doc
                prev_line = stmt.end_lineno
                ann = ast.unparse(stmt.annotation)
                base = re.sub(r"^Optional\[(.*)\]$", r"\1", ann)
                typ = " | ".join(_code(v) for v in enums[base]) if base in enums else _code(base)
                ann = typ + (" or `null`" if ann != base else "")
                default = "" if stmt.value is None else _yaml_value(stmt.value, enums)
                fields.append(Field(stmt.target.id, ann, default, doc))
            nodes[cls.name] = Node(
                cls.name, path.relative_to(ROOT).as_posix(), _md(ast.get_docstring(cls) or ""), tuple(fields)
            )
    return nodes


def _node_names(nodes: dict[str, Node]) -> dict[str, str]:
    """Config key -> dataclass name, from the root ``Config``'s ``field(default_factory=X)``."""
    out = {}
    root = nodes.get("Config")
    if root is None:
        raise PluginError("snell_bench/config/: no dataclass Config (the root of the schema)")
    for f in root.fields:
        m = re.fullmatch(r"\((\w+)\)", f.default)
        if m and m.group(1) in nodes:
            out[f.name] = m.group(1)
    return out


def _node_table(node: Node, prefix: str) -> str:
    rows = []
    for f in node.fields:
        rows.append([_code(f"{prefix}{f.name}"), f.type, _code(f.default) if f.default else "", f.doc])
    return _table(["key", "type", "default", "meaning"], rows)


def config_node(name: str, level: int = 3) -> str:
    """One node of the schema as Markdown: a heading, its docstring and a table of its keys.

    Args:
        name: the node's key in the root config (``scene``, ``sampler``, ``tracker``, ...).
        level: the heading level.

    Returns:
        The Markdown.

    Raises:
        PluginError: no node of that name.
    """
    nodes = read_schema()
    names = _node_names(nodes)
    if name not in names:
        raise PluginError(f"snell:config-node {name}: not a node of the schema; nodes: {sorted(names)}")
    node = nodes[names[name]]
    head = f"{'#' * level} `{name}` {{ #{name} }}"
    source = f"`{node.cls}` in `{node.module}`."
    return "\n\n".join([head, f"{node.doc} ({source})" if node.doc else source, _node_table(node, f"{name}.")])


def config_schema() -> str:
    """Every node of the schema: the root's own keys, then each node in the root's order."""
    nodes = read_schema()
    names = _node_names(nodes)
    root = nodes["Config"]
    own = Node(root.cls, root.module, "", tuple(f for f in root.fields if f.name not in names))
    parts = [
        "### Top-level keys { #top-level }",
        f"Keys of the root (`Config` in `{root.module}`); each node below is a key of it too.",
        _node_table(own, ""),
    ]
    parts += [config_node(name) for name in names]
    return "\n\n".join(parts)


# ------------------------------------------------------------------------------------------------
# The config groups, read from snell_bench/conf/
# ------------------------------------------------------------------------------------------------


def _file_comment(text: str) -> str:
    """The comment block at the top of a YAML file, without Hydra's ``@package`` line."""
    lines = []
    for line in text.splitlines():
        if not line.startswith("#"):
            break
        body = line[1:].strip()
        if body.startswith("@package"):
            continue
        lines.append(line[1:])
    return " ".join(x.strip() for x in lines if x.strip())


def _package(text: str, group: str) -> str:
    """The key prefix a group file writes to (``# @package _global_``: the root)."""
    m = re.search(r"^#\s*@package\s+(\S+)", text, re.MULTILINE)
    package = m.group(1) if m else group.replace("/", ".")
    return "" if package == "_global_" else package.replace("_group_", group.replace("/", ".")) + "."


def _flatten(value: Any, prefix: str) -> list[tuple[str, Any]]:
    """Dotted keys of a YAML mapping; a ``_target_`` node stays one entry (its target)."""
    if isinstance(value, dict):
        if "_target_" in value:
            return [(prefix.rstrip("."), {"_target_": value["_target_"]})]
        if not value:
            return [(prefix.rstrip("."), {})]
        out = []
        for k, v in value.items():
            out += _flatten(v, f"{prefix}{k}.")
        return out
    return [(prefix.rstrip("."), value)]


_MAX_VALUE = 60


def _override_text(key: str, value: Any) -> str:
    """``key=value`` as a group file sets it (a ``_target_`` node as its target; long values cut)."""
    if isinstance(value, dict) and "_target_" in value:
        return f"{key}: {value['_target_']}"
    text = (
        json.dumps(value, ensure_ascii=False, separators=(",", ":"))
        if isinstance(value, (list, dict))
        else _scalar(value)
    )
    if len(text) > _MAX_VALUE:
        text = text[: _MAX_VALUE - 1].rstrip() + "…"
    return f"{key}={text}"


def _defaults_overrides(defaults: list) -> list[str]:
    """The group choices of a defaults list (``override /preset: balanced`` -> ``preset=balanced``)."""
    out = []
    for d in defaults or []:
        if isinstance(d, dict):
            for k, v in d.items():
                k = re.sub(r"^override\s+", "", str(k)).lstrip("/")
                out.append(f"{k}={_scalar(v)}")
    return out


#: Groups that are no choice of a run (the text of ``--help``).
_HIDDEN_GROUPS = ("hydra/help",)


def _group_dirs() -> list[str]:
    """Every config group under ``snell_bench/conf/`` (folders holding YAML files), in the order of
    the root's defaults list, the others after it by name."""
    groups = sorted(
        p.parent.relative_to(CONF_DIR).as_posix()
        for p in CONF_DIR.rglob("*.yaml")
        if p.parent != CONF_DIR and p.name == sorted(p.parent.glob("*.yaml"))[0].name
    )
    groups = [g for g in groups if g not in _HIDDEN_GROUPS]
    order = [g for g in _root_defaults() if g in groups]
    return order + [g for g in groups if g not in order]


def _root_defaults() -> dict[str, str]:
    """Group -> default option of ``conf/config.yaml``'s defaults list."""
    cfg = yaml.safe_load((CONF_DIR / "config.yaml").read_text(encoding="utf-8"))
    out = {}
    for d in cfg.get("defaults", []):
        if isinstance(d, dict):
            for k, v in d.items():
                out[re.sub(r"^override\s+", "", str(k)).lstrip("/")] = _scalar(v)
    return out


_MAX_KEYS = 14


def config_group(group: str, level: int = 3) -> str:
    """One config group as Markdown: its options, what each is and the keys each sets.

    Args:
        group: the group's folder under ``snell_bench/conf/`` (``scene``, ``hydra/launcher``).
        level: the heading level.

    Returns:
        The Markdown; a note where the group has no file in this checkout.
    """
    folder = CONF_DIR / group
    files = sorted(folder.glob("*.yaml")) if folder.is_dir() else []
    head = f"{'#' * level} `{group}` {{ #group-{group.replace('/', '-')} }}"
    if not files:
        return f'{head}\n\n!!! note "Not in this checkout"\n    `snell_bench/conf/{group}/` holds no option yet.'
    default = _root_defaults().get(group)
    choose = f"`{group}=NAME`" + (" (with `-m`)" if group == "hydra/launcher" else "")
    intro = f"Options of `snell_bench/conf/{group}/`: choose one with {choose}"
    intro += f"; the default is `{default}`." if default not in (None, "null") else "; none is chosen by default."
    if group == "experiment":
        intro = "Options of `snell_bench/conf/experiment/`: add one with `+experiment=NAME` (none by default)."
    rows = []
    for path in files:
        text = path.read_text(encoding="utf-8")
        data = yaml.safe_load(text) or {}
        prefix = _package(text, group)
        keys = _defaults_overrides(data.pop("defaults", []) if isinstance(data, dict) else [])
        for k, v in _flatten(data, prefix) if isinstance(data, dict) else []:
            keys.append(_override_text(k, v))
        shown = keys[:_MAX_KEYS]
        more = f" … and {len(keys) - _MAX_KEYS} more (see the file)" if len(keys) > _MAX_KEYS else ""
        about = _md(_file_comment(text))
        if not about and isinstance(data, dict):
            label = data.get("label")
            about = f"“{label}”" if label else ""
        sets = " ".join(_code(k) for k in shown) + more
        name = f"**`{path.stem}`**" if path.stem == default else f"`{path.stem}`"
        rows.append([name, f"{about}<br>Sets: {sets}" if about and sets else about or f"Sets: {sets}"])
    return "\n\n".join([head, intro, _table(["option", "what it is, and the keys it sets"], rows)])


def config_groups() -> str:
    """Every config group of ``snell_bench/conf/`` (:func:`config_group`), the root's first."""
    return "\n\n".join(config_group(g) for g in _group_dirs())


# ------------------------------------------------------------------------------------------------
# Result tables from the committed snapshots of reports/
# ------------------------------------------------------------------------------------------------


def _metric_specs() -> dict[str, tuple[str, bool, str]]:
    """Column key -> (label, higher is better, format), from the metric registry and the reports'
    measures (:mod:`snell_bench.metrics.registry`, :mod:`snell_bench.reports.spec`)."""
    from snell_bench.metrics.registry import BUILTIN_METRICS
    from snell_bench.reports.spec import MEASURES

    out = {m.name: (f"{m.label} {m.arrow}", m.higher_is_better, m.format) for m in BUILTIN_METRICS}
    out.update({m.name: (m.label, None, m.format) for m in MEASURES.values()})
    return out


def _tradeoff_columns() -> dict[str, tuple[str, bool | None, str]]:
    """The sweep table's columns: stage times, the metrics (labels and formats from the registry),
    the reference's figures."""
    from snell_bench.metrics.registry import metric_spec

    metrics = {}
    for name in ("psnr", "psnr_converged", "psnr_true", "lpips"):
        m = metric_spec(name)
        metrics[name] = (f"{m.label} {m.arrow}", m.higher_is_better, m.format)
    return {
        "timings_s.warps": ("warps (s)", None, "{:.1f}"),
        "timings_s.sampling": ("sampling (s)", None, "{:.1f}"),
        "timings_s.reference": ("reference (s)", None, "{:.1f}"),
        "timings_s.metrics": ("metrics (s)", None, "{:.2f}"),
        "timings_s.total": ("total (s) ↓", False, "{:.1f}"),
        **metrics,
        "reference_self_noise_db": ("ref. self-noise (dB)", None, "{:.1f}"),
        "reference_psnr_vs_max_spp": ("ref. vs max spp (dB)", None, "{:.1f}"),
    }


# ------------------------------------------------------------------------------------------------
# The registries: metrics, method kinds, the benchmark kit's fields
# ------------------------------------------------------------------------------------------------


def metrics_table() -> str:
    """Every metric of the registry (built-in, and users' metrics installed here): its key, label,
    direction, format, what it needs, the protocols that report it and what it is."""
    from snell_bench.metrics.registry import BUILTIN_METRICS, installed_metrics, load_metric

    specs = list(BUILTIN_METRICS) + [load_metric(n) for n in installed_metrics()]
    rows = [
        [
            _code(m.name),
            _plain(m.label),
            m.arrow,
            _code(m.format),
            ", ".join(m.needs),
            ", ".join(m.protocols),
            _plain(m.description),
        ]
        for m in specs
    ]
    return _table(["key", "label", "better", "format", "needs", "protocols", "what it is"], rows)


def method_kinds_table() -> str:
    """Every method kind of the registry (built-in, and installed plugins): ``method.kind``, its
    class and what it runs."""
    from snell_bench.methods import method_class, method_kinds

    rows = []
    for kind in method_kinds():
        cls = method_class(kind)
        rows.append([_code(kind), _code(f"{cls.__module__}.{cls.__qualname__}"), _plain(cls.description)])
    return _table(["method.kind", "class", "what it runs"], rows)


def kit_fields_table() -> str:
    """The benchmark kit's fields (``snell_bench.kit.schema.FIELDS``) and its schema version."""
    from snell_bench.kit.schema import FIELDS, KIT_VERSION

    rows = [
        [_code(f.name), f.type + (", nullable" if f.optional else ""), _plain(f.unit), _plain(f.description)]
        for f in FIELDS
    ]
    return f"Schema version **{KIT_VERSION}**.\n\n" + _table(
        ["field", "type", "unit / convention", "description"], rows
    )


def _fmt(value: Any, fmt: str) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "—"
    try:
        return fmt.format(value)
    except (ValueError, TypeError):
        return str(value)


def _render_frame(
    df: pd.DataFrame, specs: dict[str, tuple[str, bool | None, str]], keys: list[str]
) -> tuple[str, list[str]]:
    """A table as Markdown.

    Args:
        df: the table, label columns first.
        specs: column -> (header, higher is better or None for an unranked column, format).
        keys: the label columns, each shown once per run of equal values (a block).

    Returns:
        The pipe table, with the best value of each ranked column in bold within each block (rows
        sharing every key but the last), and the headers of the columns that have no value at all
        (left out of the table).
    """
    values = [c for c in df.columns if c not in keys]
    empty = [c for c in values if df[c].isna().all()]
    values = [c for c in values if c not in empty]
    outer = keys[:-1]
    blocks = df.groupby(outer, sort=False, dropna=False) if outer else [(None, df)]
    best = set()
    for c in values:
        hib = specs.get(c, (c, None, ""))[1]
        if hib is None or not pd.api.types.is_numeric_dtype(df[c]):
            continue
        for _, g in blocks:
            col = g[c].dropna()
            if len(col) > 1:
                target = col.max() if hib else col.min()
                best.update((i, c) for i in col.index[col == target])
    rows, prev = [], None
    for i, r in df.iterrows():
        labels = ["" if isinstance(r[k], float) and math.isnan(r[k]) else _scalar(r[k]) for k in keys]
        shown, same = [], prev is not None
        for j, text in enumerate(labels):
            same = same and j < len(keys) - 1 and prev[j] == text
            shown.append("" if same else text)
        prev = labels
        cells = shown
        for c in values:
            fmt = specs.get(c, (c, None, "{:.4g}"))[2]
            text = _fmt(r[c], fmt)
            cells.append(f"**{text}**" if (i, c) in best else text)
        rows.append(cells)
    head = keys + [specs.get(c, (c, None, ""))[0] for c in values]
    align = ["---"] * len(keys) + ["--:"] * len(values)
    return _table(head, rows, align), [specs.get(c, (c,))[0].rstrip(" ↑↓") for c in empty]


def _label_columns(frame: pd.DataFrame, specs: dict) -> list[str]:
    """The leading label columns of a report CSV (its index, written first): the columns before the
    first metric, or where there is none, the leading columns that are not numbers."""
    cols = list(frame.columns)
    first = next((i for i, c in enumerate(cols) if c in specs), None)
    if first is not None:
        return cols[:first]
    n = 0
    while n < len(cols) and not pd.api.types.is_numeric_dtype(frame[cols[n]]):
        n += 1
    return cols[:n]


def _delta_to_full(frame: pd.DataFrame, outer: list[str]) -> pd.Series:
    """An ablation's PSNR minus the full method's (the ``Full`` row), within each block of ``outer``."""
    full = frame["psnr"].where(frame["Variant"] == "Full")
    if outer:
        return frame["psnr"] - full.groupby([frame[k] for k in outer], sort=False).transform("max")
    return frame["psnr"] - full.max()


def results_table(experiment: str, table: str, page_dir: str) -> str:
    """A report table from its snapshot, as Markdown.

    Args:
        experiment: the experiment (``reports/<experiment>/``).
        table: the table's file stem (``method_table``, ``ablation_table``, ``tradeoff``, ...).
        page_dir: the folder of the page it goes into, relative to ``docs/`` (for the CSV link).

    Returns:
        The table with its title, the report's provenance line, a link to the CSV, the report's
        notes (folded) and the commands that regenerate it; where the snapshot lacks the table, a
        note saying so and how to make it.
    """
    known = _results.EXPERIMENTS
    if experiment not in known:
        raise PluginError(f"snell:results {experiment}: not in tools/docs_results.py EXPERIMENTS ({sorted(known)})")
    command = known[experiment]["command"]
    folder = DATA_DIR / experiment
    csv = folder / f"{table}.csv"
    regen = f"Regenerate: `{command}`, then `make docs-results`."
    if not csv.is_file():
        return (
            f'!!! warning "No snapshot of `reports/{experiment}/{table}.csv` yet"\n'
            f"    The numbers of this table are generated from the experiment's report, and this checkout has no "
            f"snapshot of it (`docs/results/data/{experiment}/`).\n"
            f"    {regen} (`make docs-results` copies the report's tables into `docs/results/data/`.)"
        )
    meta = (
        json.loads((folder / "report.json").read_text(encoding="utf-8")) if (folder / "report.json").is_file() else {}
    )
    info = meta.get("tables", {}).get(table, {})
    frame = pd.read_csv(csv)
    if table == "tradeoff_settings":
        specs = {**_tradeoff_columns(), "n": ("n (scenes)", None, "{}"), "pareto": ("Pareto", None, "{}")}
        frame["n"] = frame["n"].astype(str)
        frame["pareto"] = frame["pareto"].fillna("").astype(str)
        keys = [k for k in ("axis", "setting") if k in frame.columns]
        frame = frame[keys + [c for c in specs if c in frame.columns]]
    else:
        specs = {**_metric_specs(), "n": ("n", None, "{:.0f}")}
        keys = _label_columns(frame, specs)
        if keys[-1:] == ["Variant"] and "psnr" in frame and (frame["Variant"] == "Full").any():
            frame.insert(frame.columns.get_loc("psnr") + 1, "psnr_delta", _delta_to_full(frame, keys[:-1]))
            specs["psnr_delta"] = ("Δ PSNR vs Full", None, "{:+.2f}")
    link = Path(os.path.relpath(folder / f"{table}.csv", ROOT / "docs" / page_dir)).as_posix()
    provenance = info.get("provenance") or meta.get("provenance", "")
    body, empty = _render_frame(frame, specs, keys)
    caption = [info.get("caption", ""), "**Bold**: best per column" + (" within each block." if len(keys) > 1 else ".")]
    if empty:
        caption.append(f"No cell has a value of {', '.join(empty)} (the notes say why): those columns are left out.")
    if table == "tradeoff_settings":
        src = f"From `reports/{experiment}/tradeoff.csv` (per-setting means; [snapshot]({link}))"
    else:
        src = f"From `reports/{experiment}/{table}.csv` ([snapshot]({link}))"
    caption.append(f"{src}: {provenance}." if provenance else f"{src}.")
    caption.append(regen)
    parts = [f"**{info['title']}**"] if info.get("title") else []
    parts += [body, " ".join(c for c in caption if c) + "\n{: .snell-caption }"]
    notes = info.get("notes") or []
    if notes:
        parts.append('??? note "Notes of the report"\n' + "\n".join(f"    - {_md(n)}" for n in notes))
    return "\n\n".join(parts)


# ------------------------------------------------------------------------------------------------
# The hook
# ------------------------------------------------------------------------------------------------


def _expand(kind: str, args: list[str], page_dir: str) -> str:
    if kind == "config-schema" and not args:
        return config_schema()
    if kind == "config-node" and len(args) == 1:
        return config_node(args[0])
    if kind == "config-groups" and not args:
        return config_groups()
    if kind == "config-group" and len(args) == 1:
        return config_group(args[0])
    if kind == "results" and len(args) == 2:
        return results_table(args[0], args[1], page_dir)
    if kind == "metrics" and not args:
        return metrics_table()
    if kind == "method-kinds" and not args:
        return method_kinds_table()
    if kind == "kit-fields" and not args:
        return kit_fields_table()
    raise PluginError(f"unknown marker snell:{kind} {' '.join(args)} (see tools/docs_hooks.py)")


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 - MkDocs' hook signature
    """Replace every ``<!-- snell:... -->`` marker of a page with what it asks for.

    Args:
        markdown: the page's Markdown.
        page: the page (its source path locates the snapshot links).
        config: MkDocs' config.
        files: the site's files.

    Returns:
        The Markdown with the generated parts in place.
    """
    page_dir = Path(page.file.src_uri).parent.as_posix()

    def expand(m: re.Match) -> str:
        indent = m.group(1)
        text = _expand(m.group(2), m.group(3).split(), page_dir)
        return "\n".join(indent + line if line else line for line in text.splitlines())

    return _MARKER.sub(expand, markdown)
