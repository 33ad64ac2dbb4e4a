"""Files a config names: found as given, else inside the checkout (where ``datasets/`` lies)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["data_path", "CHECKOUT"]

#: The checkout's root (``datasets/`` is found there when a relative path is not found in the
#: working folder).
CHECKOUT = Path(__file__).resolve().parents[2]


def data_path(value: str, key: str, what: str = "file") -> str:
    """A file a config names: as given (absolute or relative to the working folder), else relative
    to the checkout (where ``datasets/`` lies).

    Raises:
        FileNotFoundError: no such file (the message names ``key`` and the fix).
        IsADirectoryError: a folder, not a file (the message lists a few of its files).
    """
    path = Path(str(value))
    if not path.is_absolute() and not path.exists():
        path = CHECKOUT / path
    if path.is_dir():
        inside = sorted(p.name for p in path.iterdir() if p.is_file() and not p.name.startswith("."))[:5]
        raise IsADirectoryError(
            f"{key}={str(value)!r} is a folder, not a {what}; set {key} to a file"
            + (f" (it holds {', '.join(inside)}{', ...' if len(inside) == 5 else ''})" if inside else "")
        )
    if not path.is_file():
        raise FileNotFoundError(f"{key}={str(value)!r}: no such {what}; set {key} to an existing {what}")
    return str(path)
