"""How many faces a mesh file holds, from its header or a streamed count, without loading the mesh.

Convention: what a file holds is decided by its first bytes (:func:`sniff_mesh_format`), whatever its
name says; the count is

- PLY: the header's ``element face N`` (trimesh's header reader; a polygon counts once);
- binary STL: the count at byte 80;
- ASCII STL: its ``endfacet`` lines, streamed;
- OBJ: its ``f`` lines streamed, a polygon of ``n`` corners counting ``n - 2`` triangles (as trimesh
  splits it);
- any other file (GLB, glTF, OFF, a header that cannot be read): a bound from the file's size,
  :data:`BYTES_PER_FACE_AT_LEAST` bytes a face (three 32-bit indices; a ``.gltf``'s size includes
  the buffer files it names beside it).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

from snell_bench.scene.mesh_format import sniff_mesh_format

__all__ = ["BYTES_PER_FACE_AT_LEAST", "FaceCount", "mesh_face_count"]

#: The fewest bytes a file of another format stores a triangle in (three 32-bit vertex indices,
#: vertices not counted), so its size divided by this bounds its faces from above.
BYTES_PER_FACE_AT_LEAST = 12


class FaceCount(NamedTuple):
    """The faces of a mesh file (:func:`mesh_face_count`).

    Attributes:
        faces: the count, or a bound from above where ``exact`` is False.
        exact: whether ``faces`` was read from the file (header or count) rather than bounded by its
            size.
    """

    faces: int
    exact: bool


def mesh_face_count(path: str | Path) -> FaceCount:
    """The faces of the mesh file ``path``, without loading the mesh (module docstring).

    Args:
        path: a mesh file.

    Returns:
        The :class:`FaceCount`.

    Raises:
        OSError: the file cannot be read.

    Examples:
        >>> import struct, tempfile
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     p = Path(tmp) / "big.stl"
        ...     _ = p.write_bytes(b"\\0" * 80 + struct.pack("<I", 2) + b"\\0" * 100)
        ...     mesh_face_count(p)
        FaceCount(faces=2, exact=True)
    """
    path = Path(path)
    fmt = sniff_mesh_format(path)
    count = None
    if fmt == "PLY":
        count = _ply_faces(path)
    elif fmt == "STL":
        count = _stl_faces(path)
    elif fmt == "OBJ":
        count = _obj_faces(path)
    if count is not None:
        return FaceCount(count, True)
    return FaceCount(_size_bound(path), False)


def _ply_faces(path: Path) -> int | None:
    """The header's ``element face N`` (0 without a face element); ``None``: no readable header."""
    from trimesh.exchange.ply import _parse_header

    try:
        with path.open("rb") as f:
            elements = _parse_header(f)[0]
    except Exception:  # a damaged header: its cell reports that; the size bounds the faces
        return None
    face = elements.get("face")
    return int(face["length"]) if face else 0


def _stl_faces(path: Path) -> int:
    """A binary STL's count at byte 80, or an ASCII STL's ``endfacet`` lines."""
    with path.open("rb") as f:
        head = f.read(84)
        if path.stat().st_size == 84 + 50 * int.from_bytes(head[80:84], "little"):
            return int.from_bytes(head[80:84], "little")
        f.seek(0)
        return sum(1 for line in f if line.lstrip().startswith(b"endfacet"))


def _obj_faces(path: Path) -> int:
    """Triangles of an OBJ's ``f`` lines: ``n - 2`` for a face of ``n`` corners."""
    n = 0
    with path.open("rb") as f:
        for line in f:
            if line.startswith((b"f ", b"f\t")):
                n += max(len(line.split()) - 3, 0)
    return n


def _size_bound(path: Path) -> int:
    """The file's size (with a ``.gltf``'s buffer files) over :data:`BYTES_PER_FACE_AT_LEAST`."""
    size = path.stat().st_size
    if path.suffix.lower() == ".gltf":
        try:
            buffers = json.loads(path.read_bytes()).get("buffers", [])
        except (ValueError, AttributeError):
            buffers = []
        for buf in buffers if isinstance(buffers, list) else []:
            uri = buf.get("uri", "") if isinstance(buf, dict) else ""
            if uri and not uri.startswith("data:") and (path.parent / uri).is_file():
                size += (path.parent / uri).stat().st_size
    return size // BYTES_PER_FACE_AT_LEAST
