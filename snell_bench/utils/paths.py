"""Files a config names: found as given, else inside the installed package (where the bundled
``datasets/`` lie, read through :mod:`importlib.resources`).

A relative path such as ``datasets/meshes/fox.ply`` (``conf/object/fox.yaml``) is looked for first
relative to the working folder, so a file of one's own shadows a bundled one of the same name, then
relative to the ``snell_bench`` package, so the bundled meshes and RGB-D frame are found from any
folder, by a checkout and by an installed package alike.
"""

from __future__ import annotations

import os
from importlib.resources import files
from pathlib import Path

__all__ = ["PACKAGE_ROOT", "data_path", "candidates"]

#: The installed ``snell_bench`` package, the second place a relative path is looked for (its
#: ``datasets/`` folder holds the bundled meshes and RGB-D frame). pip installs a package as plain
#: files, so this is a folder on disk.
PACKAGE_ROOT = Path(os.fspath(files("snell_bench")))


def candidates(value: str | os.PathLike) -> list[Path]:
    """The places a path from a config is looked for, in order.

    Args:
        value: an absolute path, or one relative to the working folder or to the package.

    Returns:
        ``[value]`` for an absolute path; else the path in the working folder, then in
        :data:`PACKAGE_ROOT`.

    Examples:
        >>> candidates("/data/fox.ply")
        [PosixPath('/data/fox.ply')]
        >>> [p.relative_to(PACKAGE_ROOT) for p in candidates("datasets/meshes/fox.ply")[1:]]
        [PosixPath('datasets/meshes/fox.ply')]
    """
    path = Path(os.fspath(value))
    if path.is_absolute():
        return [path]
    return [Path.cwd() / path, PACKAGE_ROOT / path]


def data_path(value: str | os.PathLike, key: str, what: str = "file") -> str:
    """A file a config names, found in the first of :func:`candidates` that exists.

    Args:
        value: the path as the config gives it.
        key: the config key that set it (named in errors, e.g. ``object.path``).
        what: what the file is (named in errors, e.g. ``mesh file``).

    Returns:
        The file's path: as given when found there (absolute, or relative to the working folder),
        else its absolute path inside the package.

    Raises:
        FileNotFoundError: no such file in any of the places (the message names each place looked,
            ``key`` and the fix).
        IsADirectoryError: a folder, not a file (the message lists a few of its files).
    """
    places = candidates(value)
    found = next((p for p in places if p.exists()), None)
    if found is None:
        looked = " and ".join(str(p) for p in places)
        raise FileNotFoundError(
            f"{key}={str(value)!r}: no such {what} (looked for {looked}); set {key} to an existing {what}, "
            "an absolute path or one relative to the working folder"
        )
    if found.is_dir():
        inside = sorted(p.name for p in found.iterdir() if p.is_file() and not p.name.startswith("."))[:5]
        raise IsADirectoryError(
            f"{key}={str(value)!r} is a folder, not a {what}; set {key} to a file"
            + (f" (it holds {', '.join(inside)}{', ...' if len(inside) == 5 else ''})" if inside else "")
        )
    if not found.is_file():
        raise FileNotFoundError(f"{key}={str(value)!r}: {found} is not a regular file; set {key} to an existing {what}")
    return str(Path(os.fspath(value))) if found is places[0] else str(found)
