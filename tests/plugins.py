"""A fake installed plugin for the registries' tests: a module and a ``.dist-info`` folder with its
entry points, on ``sys.path`` as ``pip install`` would leave them, and the registries' caches cleared
before and after (so no later test sees it)."""

from __future__ import annotations

import contextlib
import importlib
import sys
from collections.abc import Callable, Iterator
from pathlib import Path


@contextlib.contextmanager
def installed_plugin(
    folder: Path, monkeypatch, module: str, source: str, entry_points: dict[str, str], caches: list[Callable]
) -> Iterator[None]:
    """Within the block, ``module`` (``source``) is importable from ``folder`` and its distribution
    declares ``entry_points`` (``{group: "name = module:attr"}``); ``caches`` (``functools`` caches
    of entry points) are cleared on entry and exit."""
    (folder / f"{module}.py").write_text(source)
    dist = folder / f"{module}-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {module.replace('_', '-')}\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("".join(f"[{g}]\n{line}\n" for g, line in entry_points.items()))
    monkeypatch.syspath_prepend(str(folder))
    importlib.invalidate_caches()
    for c in caches:
        c.cache_clear()
    try:
        yield
    finally:
        sys.modules.pop(module, None)
        for c in caches:
            c.cache_clear()
