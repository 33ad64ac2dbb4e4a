"""Import cycles between the modules of a package.

The import graph is grimp's: one node per module (a package's ``__init__`` is the package's node),
one edge per module that another imports, whether at the top of the file, inside a function or under
``TYPE_CHECKING``. A cycle is a strongly connected component of two or more modules; for each one
the check prints its modules and one closed chain of imports through them, with the line of each
import.

Usage::

    python tools/check_imports.py [PACKAGE ...]    # default: snell_bench

The exit status is 1 when any package has a cycle, 0 otherwise.
"""

from __future__ import annotations

import argparse
import sys
from collections import deque
from dataclasses import dataclass

import grimp
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

__all__ = ["Cycle", "Import", "build_graph", "find_cycles", "format_cycle", "main"]


@dataclass(frozen=True)
class Import:
    """One edge of a chain: ``importer`` imports ``imported`` at ``line_number`` (``line``, as written)."""

    importer: str
    imported: str
    line_number: int
    line: str


@dataclass(frozen=True)
class Cycle:
    """A set of modules that import each other, directly or through one another.

    Attributes:
        modules: The modules of the strongly connected component, sorted.
        chain: A shortest closed chain of imports through ``modules[0]``: each import's
            ``imported`` is the next one's ``importer``, and the last one imports ``modules[0]``.
    """

    modules: tuple[str, ...]
    chain: tuple[Import, ...]


def build_graph(package: str) -> grimp.ImportGraph:
    """The import graph of ``package`` (importable from ``sys.path``), external packages left out, no
    cache on disk."""
    return grimp.build_graph(package, cache_dir=None)


def _import(graph: grimp.ImportGraph, importer: str, imported: str) -> Import:
    details = sorted(graph.get_import_details(importer=importer, imported=imported), key=lambda d: d["line_number"])
    if not details:
        return Import(importer, imported, 0, "")
    return Import(importer, imported, int(details[0]["line_number"]), str(details[0]["line_contents"]).strip())


def _shortest_cycle(graph: grimp.ImportGraph, start: str, members: set[str]) -> list[str]:
    """``[start, m1, ..., start]``: a shortest closed path through ``start`` inside ``members``
    (breadth-first, successors in sorted order, so the answer is deterministic)."""
    parent: dict[str, str] = {}
    queue = deque([start])
    while queue:
        node = queue.popleft()
        for nxt in sorted(graph.find_modules_directly_imported_by(node) & members):
            if nxt == start:
                path = [node]
                while path[-1] != start:
                    path.append(parent[path[-1]])
                return [start, *reversed(path[:-1]), start]
            if nxt not in parent:
                parent[nxt] = node
                queue.append(nxt)
    raise ValueError(f"{start} is on no cycle inside {sorted(members)}")


def find_cycles(graph: grimp.ImportGraph) -> list[Cycle]:
    """Every import cycle of ``graph``, one per strongly connected component of two or more modules.

    Args:
        graph: An import graph (:func:`build_graph`).

    Returns:
        The cycles, sorted by their first module (empty when the graph has none).
    """
    modules = sorted(graph.modules)
    index = {name: i for i, name in enumerate(modules)}
    rows, cols = [], []
    for name in modules:
        for imported in graph.find_modules_directly_imported_by(name):
            rows.append(index[name])
            cols.append(index[imported])
    n = len(modules)
    adjacency = csr_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n, n))
    _, labels = connected_components(adjacency, directed=True, connection="strong")
    cycles = []
    for label in np.unique(labels):
        members = [modules[i] for i in np.flatnonzero(labels == label)]
        if len(members) < 2:
            continue
        path = _shortest_cycle(graph, members[0], set(members))
        chain = tuple(_import(graph, a, b) for a, b in zip(path[:-1], path[1:]))
        cycles.append(Cycle(tuple(members), chain))
    return sorted(cycles, key=lambda c: c.modules)


def format_cycle(cycle: Cycle) -> str:
    """The modules of ``cycle``, one a line, then its chain, one import a line."""
    lines = [f"import cycle between {len(cycle.modules)} modules:"]
    lines += [f"    {name}" for name in cycle.modules]
    lines.append("  for example:")
    lines += [f"    {i.importer} -> {i.imported}  (l.{i.line_number}: {i.line})" for i in cycle.chain]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Prints the import cycles of each package; returns 1 when there is any, else 0."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("packages", nargs="*", default=["snell_bench"], help="top-level packages to check")
    args = parser.parse_args(argv)
    found = 0
    for package in args.packages:
        graph = build_graph(package)
        cycles = find_cycles(graph)
        for cycle in cycles:
            print(format_cycle(cycle), end="\n\n")
        print(f"{package}: {len(cycles)} import cycle(s) among {len(graph.modules)} modules")
        found += len(cycles)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
