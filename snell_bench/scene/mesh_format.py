"""What a mesh file holds, by its first bytes (:func:`sniff_mesh_format`), whatever its name says.

Convention: a mesh file is read by trimesh by its suffix (:data:`FORMAT_SUFFIXES`); a file whose
first bytes show another format than its suffix is refused with the name to rename it to, before
trimesh would call it damaged.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["FORMAT_SUFFIXES", "MESH_SUFFIXES", "sniff_mesh_format"]

#: Mesh file suffixes trimesh reads that the bundled objects use.
MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")

#: The suffix trimesh reads each format of :func:`sniff_mesh_format` by.
FORMAT_SUFFIXES = {"PLY": ".ply", "OBJ": ".obj", "STL": ".stl", "GLB": ".glb", "glTF": ".gltf", "OFF": ".off"}

#: The first word of an OBJ file's statements (a line of text starting with anything else is not OBJ).
_OBJ_STATEMENTS = frozenset(
    b"v vn vt vp f l p o g s mtllib usemtl cstype deg bmat step curv curv2 surf parm trim hole scrv sp end "
    b"con mg lod bevel c_interp d_interp ctech stech shadow_obj trace_obj".split()
)


def sniff_mesh_format(path: str | Path) -> str | None:
    """The format a mesh file's first bytes show, whatever its name says.

    Args:
        path: a file.

    Returns:
        ``"PLY"``, ``"OBJ"``, ``"STL"`` (binary or ASCII), ``"GLB"`` (binary glTF), ``"glTF"`` (JSON),
        ``"OFF"`` (keys of :data:`FORMAT_SUFFIXES`), or ``None``: empty, or none of these.

    Examples:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     p = Path(tmp) / "cube.obj"
        ...     _ = p.write_bytes(b"ply\\nformat ascii 1.0\\n")
        ...     sniff_mesh_format(p)
        'PLY'
    """
    path = Path(path)
    size = path.stat().st_size
    with path.open("rb") as f:
        head = f.read(65536)
    if not head:
        return None
    if head.startswith(b"ply") and head[3:4] in (b"\n", b"\r"):
        return "PLY"
    if head.startswith(b"glTF"):
        return "GLB"
    if size >= 84 and size == 84 + 50 * int.from_bytes(head[80:84], "little"):
        return "STL"  # a binary STL's header is free text (it may start with "solid")
    text = head.removeprefix(b"\xef\xbb\xbf").lstrip()
    if text.startswith(b"solid") and b"facet" in text:
        return "STL"
    if text.startswith(b"{"):
        return "glTF" if b'"asset"' in head or b'"meshes"' in head else None
    first = text.split(None, 1)[0] if text else b""
    if first.endswith(b"OFF") and first.isalnum():  # OFF, COFF, NOFF, STOFF, 4OFF, ...
        return "OFF"
    if b"\x00" in head:
        return None
    for line in text.splitlines():
        words = line.split()
        if words and not words[0].startswith(b"#"):
            return "OBJ" if words[0] in _OBJ_STATEMENTS else None
    return None


def _check_format(path: Path) -> None:
    """Refuse an empty file, and a file whose first bytes show another format than its suffix
    (trimesh would read it by its suffix and call it damaged)."""
    if path.stat().st_size == 0:
        raise ValueError(f"{path} is empty (0 bytes): re-export the mesh or choose another file")
    fmt = sniff_mesh_format(path)
    if fmt is None:
        return
    suffix = FORMAT_SUFFIXES[fmt]
    if path.suffix.lower() != suffix:
        named = f"its name ends in {path.suffix}" if path.suffix else "its name has no suffix"
        raise ValueError(
            f"{path} holds a {fmt} file but {named} (a mesh file is read by its suffix): rename it to "
            f"{path.with_suffix(suffix).name}"
        )
