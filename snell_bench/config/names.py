"""The names that become folder names: ``experiment_name`` (``<runs_dir>/<experiment_name>/``,
``<reports_dir>/<experiment_name>/``, its log ``<experiment_name>.log``), ``scene.name`` and
``object.name`` (a preview's ``<scene>-<variation>/<object>``), a sweep setting's label.

Convention:
    A folder name is one path component: it cannot leave the folder it is created in. Names with
    spaces or other Unicode characters are valid (quote them on the command line:
    ``'experiment_name="my run"'``).
"""

from __future__ import annotations

import os
import re
import unicodedata
from typing import Any

__all__ = ["NAME_MAX", "folder_name_problem", "setting_slug"]

#: The longest file or folder name, in bytes of the file system's encoding, that common file
#: systems take (ext4, XFS, Btrfs, APFS, NTFS in UTF-16 units; ``NAME_MAX`` of POSIX).
NAME_MAX = 255


def folder_name_problem(value: Any, key: str, *, example: str = "my_run", suffix: str = "") -> str | None:
    """Why ``value`` (the setting ``key``) cannot name a folder, or ``None`` if it can.

    A folder name is one path component: not empty, not ``.`` or ``..``, no ``/``, ``\\``, NUL
    or other control character, no leading ``-`` (a command would read it as an option), and at
    most :data:`NAME_MAX` bytes once ``suffix`` (what the folder or file name adds to it, e.g.
    ``.log``) is appended. Spaces and other Unicode characters are fine.

    Args:
        value: the name.
        key: the setting that holds it, named in the line.
        example: a valid value, for the fix.
        suffix: what is appended to the name where it is used.

    Returns:
        One line naming ``key``, the value and the fix; ``None`` for a valid name.

    Examples:
        >>> folder_name_problem("my run", "experiment_name") is None
        True
        >>> folder_name_problem("../x", "experiment_name").split(":")[0]
        "experiment_name='../x'"
    """
    fix = f"; e.g. {key}={example}"
    if not isinstance(value, str):
        return f"{key}={value!r}: must be a name (a string){fix}"
    if value.strip() == "":
        return f"{key}={value!r}: must not be empty or blank (it names a folder){fix}"
    if value in (".", ".."):
        return f"{key}={value!r}: {value!r} is the current or the parent folder, not a name{fix}"
    if "/" in value or "\\" in value:
        what = "an absolute path" if os.path.isabs(value) or value.startswith("\\") else "a path"
        return (
            f"{key}={value!r}: a folder name, not {what}: it cannot hold '/' or '\\\\' (it would write outside its "
            f"folder){fix}"
        )
    if any(unicodedata.category(c) == "Cc" for c in value):
        return f"{key}={value!r}: must not hold NUL, newlines or other control characters{fix}"
    if value.startswith("-"):
        return f"{key}={value!r}: must not start with '-' (commands would read the folder as an option){fix}"
    size = len(os.fsencode(value + suffix))
    if size > NAME_MAX:
        return (
            f"{key}={value[:40]!r}...: {size} bytes{f' with {suffix!r}' if suffix else ''}, longer than the "
            f"{NAME_MAX} bytes a file system takes for a name; use a shorter name{fix}"
        )
    return None


#: What :func:`setting_slug` replaces by ``-``.
_SLUG_RE = re.compile(r"[^A-Za-z0-9._=+-]")


def setting_slug(label: str) -> str:
    """The folder name of a sweep setting's label: every character outside ``[A-Za-z0-9._=+-]``
    replaced by ``-`` (``preset:fast`` -> ``preset-fast``)."""
    return _SLUG_RE.sub("-", str(label))
