"""Sizes of a package's modules and functions, against the house limits.

A module over ``--max-file`` lines or a function (or method) over ``--max-function`` lines is a seam
waiting to be found. Each one still over its limit is listed in the exceptions file
(``tools/size_exceptions.txt``: ``<path> <lines>`` for a module, ``<path>::<qualified name> <lines>``
for a function, one per line, ``#`` comments), with the size it has today: it may shrink, never grow.
The check prints the package's total, each top-level package's, and the longest modules and
functions, then fails (exit status 1) when

- a module or function over its limit is not in the exceptions file,
- one that is has grown past the size recorded there,
- an exception is no longer needed (under the limit, or gone): delete its line.

Lines are physical lines (as ``wc -l`` counts them); a function's lines run from its ``def`` to its
last line, nested functions included.

Usage::

    python tools/check_size.py [PACKAGE_DIR] [--exceptions FILE] [--max-file 500] [--max-function 80]
    python tools/check_size.py --record    # today's sizes become the exceptions (review the diff)
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections import Counter
from pathlib import Path

__all__ = ["module_sizes", "function_sizes", "read_exceptions", "problems", "main"]


def module_sizes(root: Path) -> dict[str, int]:
    """``{path relative to root's parent: lines}`` for every ``.py`` file under ``root``."""
    return {
        p.relative_to(root.parent).as_posix(): len(p.read_text(encoding="utf-8").splitlines())
        for p in sorted(root.rglob("*.py"))
    }


def function_sizes(root: Path) -> dict[str, int]:
    """``{"<path>::<qualified name>": lines}`` for every function and method under ``root``."""
    sizes: dict[str, int] = {}

    def visit(node: ast.AST, path: str, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    sizes[f"{path}::{name}"] = child.end_lineno - child.lineno + 1
                visit(child, path, f"{name}.")
            else:
                visit(child, path, prefix)

    for p in sorted(root.rglob("*.py")):
        visit(ast.parse(p.read_text(encoding="utf-8"), str(p)), p.relative_to(root.parent).as_posix(), "")
    return sizes


def read_exceptions(path: Path) -> dict[str, int]:
    """The exceptions file as ``{name: recorded lines}`` (empty when the file does not exist)."""
    if not path.exists():
        return {}
    out = {}
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        try:
            name, lines = line.rsplit(None, 1)
            out[name] = int(lines)
        except ValueError:
            raise SystemExit(f"{path}:{number}: expected '<name> <lines>', got {line!r}") from None
    return out


def problems(sizes: dict[str, int], limit: int, exceptions: dict[str, int], what: str) -> list[str]:
    """What breaks the limit for one kind (``what``: "module" or "function"), one line each."""
    out = []
    for name, n in sorted(sizes.items()):
        if n <= limit:
            continue
        if name not in exceptions:
            out.append(f"{name}: {what} of {n} lines (limit {limit}); split it")
        elif n > exceptions[name]:
            out.append(f"{name}: {what} grew to {n} lines (recorded {exceptions[name]}, limit {limit})")
    for name in sorted(exceptions):
        if ("::" in name) != (what == "function"):
            continue  # the other kind's
        if name not in sizes:
            out.append(f"{name}: recorded as an exception but no such {what}: delete its exception")
        elif sizes[name] <= limit:
            out.append(f"{name}: now {sizes[name]} lines, within the limit: delete its exception")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("package", nargs="?", default="snell_bench", type=Path)
    ap.add_argument("--exceptions", type=Path, default=Path(__file__).with_name("size_exceptions.txt"))
    ap.add_argument("--max-file", type=int, default=500)
    ap.add_argument("--max-function", type=int, default=80)
    ap.add_argument("--top", type=int, default=8, help="how many of the longest to print")
    ap.add_argument("--record", action="store_true", help="write today's sizes over the limits as the exceptions")
    args = ap.parse_args(argv)
    modules, functions = module_sizes(args.package), function_sizes(args.package)
    if args.record:
        over = {**{k: v for k, v in modules.items() if v > args.max_file}}
        over |= {k: v for k, v in functions.items() if v > args.max_function}
        head = f"# over {args.max_file} lines a module or {args.max_function} a function: may shrink, never grow\n"
        args.exceptions.write_text(head + "".join(f"{k} {v}\n" for k, v in sorted(over.items())), encoding="utf-8")
    per_package = Counter()
    for name, n in modules.items():
        parts = name.split("/")
        per_package[parts[1] if len(parts) > 2 else parts[0]] += n
    print(f"{args.package}: {sum(modules.values())} lines in {len(modules)} modules")
    print("  " + ", ".join(f"{k} {v}" for k, v in per_package.most_common()))
    for title, sizes in (("modules", modules), ("functions", functions)):
        longest = sorted(sizes.items(), key=lambda kv: -kv[1])[: args.top]
        print(f"longest {title}: " + ", ".join(f"{name} {n}" for name, n in longest))
    exceptions = read_exceptions(args.exceptions)
    found = problems(modules, args.max_file, exceptions, "module")
    found += problems(functions, args.max_function, exceptions, "function")
    for line in found:
        print(line, file=sys.stderr)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
