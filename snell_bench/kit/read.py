"""Reading a benchmark kit and a folder of submitted images, trusting neither.

- :func:`load_kit`: a kit folder (``job=export``) as its metadata and rows, its schema version
  checked; every file a row names is read only inside the kit folder (:func:`inside`).
- :func:`submitted_images`: where the image of each group is, in a submission folder
  (``<folder>/<id>.png``, or ``.jpg``) or a manifest file (columns ``id`` and an image column, paths
  relative to the manifest's folder); nothing outside that folder is read, links included.
- :func:`read_image`: one submitted image as 8-bit RGB of the size expected, its size read from the
  header before any pixel is decoded; an unreadable file, a wrong size or a mode that is not 8-bit
  is refused naming the file and the fix.

Convention: every refusal is a :class:`KitError` (a ``ValueError``) whose message names the file,
what is wrong and what to do.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from snell_bench.kit.schema import IMAGE_SUFFIXES, KIT_JSON, KIT_VERSION, MANIFEST_JSONL

__all__ = [
    "Kit",
    "KitError",
    "MAX_IMAGE_PIXELS",
    "inside",
    "load_kit",
    "read_image",
    "submitted_images",
]

#: The most pixels a submitted image may have (a decompression bomb is refused from its header).
MAX_IMAGE_PIXELS = 64_000_000


class KitError(ValueError):
    """A kit or a submitted image that cannot be used; the message names the file and the fix."""


def inside(root: str | os.PathLike, rel: str | os.PathLike, what: str = "file") -> Path:
    """The path ``rel`` names under the folder ``root``, resolved (links followed), refused unless it
    stays inside ``root``.

    Args:
        root: the folder everything must stay inside.
        rel: a path relative to ``root`` (an absolute path, ``..`` or a link must still land inside).
        what: what the path is, for the message.

    Raises:
        KitError: naming the path and the folder, when it leads outside.

    Examples:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as d:
        ...     inside(d, "a/b.png").name
        'b.png'
        >>> inside("/tmp/kit", "../etc/passwd")
        Traceback (most recent call last):
        ...
        snell_bench.kit.read.KitError: ...
    """
    base = Path(root).resolve()
    path = (base / Path(rel)).resolve()
    if path != base and base not in path.parents:
        raise KitError(
            f"{what} {str(rel)!r} leads outside the folder {base} (to {path}); nothing outside it is read: put the "
            "file inside the folder (a copy, not a link to elsewhere)"
        )
    return path


@dataclass
class Kit:
    """A benchmark kit (see :mod:`snell_bench.kit.schema`).

    Attributes:
        folder: the kit's folder.
        meta: its ``kit.json``: ``schema_version``, ``experiment``, the scoring settings
            (``scoring``), counts.
        rows: the manifest's rows, in order (plain dicts of :data:`~snell_bench.kit.schema.FIELDS`).
    """

    folder: Path
    meta: dict
    rows: list[dict] = field(default_factory=list)

    def row(self, group: str) -> dict | None:
        """The row of the group ``group`` (its id), or None."""
        return next((r for r in self.rows if r.get("id") == group), None)

    def path(self, row: dict, name: str) -> Path | None:
        """The file field ``name`` of ``row`` under the kit folder (None where the row has none)."""
        rel = row.get(name)
        return None if rel in (None, "") else inside(self.folder, rel, f"{name} of {row.get('id')}")

    def array(self, row: dict, name: str) -> np.ndarray | None:
        """A file field of ``row`` read: ``.npy`` as stored (never a pickle), a PNG as its array
        (an 8-bit mask as ``bool``, ``> 127``)."""
        path = self.path(row, name)
        if path is None:
            return None
        if path.suffix == ".npy":
            return np.load(path, allow_pickle=False)
        from PIL import Image

        with Image.open(path) as im:
            a = np.asarray(im)
        return a > 127 if a.ndim == 2 else a


def load_kit(folder: str | os.PathLike) -> Kit:
    """The kit in ``folder``: its ``kit.json`` and the rows of ``manifest.jsonl`` (no pandas needed).

    Raises:
        KitError: naming the folder and the fix, when it is no kit (no ``kit.json``), its files do
            not parse, or its schema version is not :data:`~snell_bench.kit.schema.KIT_VERSION`.
    """
    folder = Path(folder).expanduser()
    meta_file = folder / KIT_JSON
    if not meta_file.is_file():
        raise KitError(
            f"{folder} is not a benchmark kit (no {KIT_JSON}); write one with "
            "python -m snell_bench +experiment=<name> job=export"
        )
    try:
        meta = json.loads(meta_file.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise KitError(f"{meta_file} cannot be read ({type(e).__name__}: {e}); export the kit again") from None
    version = meta.get("schema_version") if isinstance(meta, dict) else None
    if version != KIT_VERSION:
        raise KitError(
            f"the kit {folder} has schema version {version!r}; this snell_bench reads version {KIT_VERSION!r}: export "
            "the kit again with this snell_bench (job=export), or score with the snell_bench that wrote it"
        )
    rows = []
    manifest = folder / MANIFEST_JSONL
    try:
        with open(manifest, encoding="utf-8") as f:
            for i, line in enumerate(f, 1):
                if line.strip():
                    row = json.loads(line)
                    if not isinstance(row, dict) or "id" not in row:
                        raise ValueError(f"line {i} is not a row with an id")
                    rows.append(row)
    except (OSError, ValueError) as e:
        raise KitError(f"{manifest} cannot be read ({type(e).__name__}: {e}); export the kit again") from None
    return Kit(folder, meta, rows)


# ---------------------------------------------------------------------------- submitted images
def _from_folder(folder: Path) -> dict[str, Path]:
    out: dict[str, Path] = {}
    for path in sorted(folder.glob("*/*")):
        if path.suffix.lower() not in IMAGE_SUFFIXES or path.name.startswith("."):
            continue
        group = f"{path.parent.name}/{path.stem}"
        if group in out:
            raise KitError(f"two images for {group} in {folder}: {out[group].name} and {path.name}; keep one per group")
        out[group] = path
    return out


def _from_manifest(file: Path, column: str) -> dict[str, Path]:
    import pandas as pd

    try:
        if file.suffix == ".parquet":
            table = pd.read_parquet(file)
        elif file.suffix in (".jsonl", ".json"):
            table = pd.read_json(file, lines=file.suffix == ".jsonl", dtype=False)
        else:
            table = pd.read_csv(file, dtype=str, keep_default_na=False)
    except Exception as e:  # noqa: BLE001 - any unreadable table: say which and why
        raise KitError(f"method.images={str(file)!r} cannot be read as a table ({type(e).__name__}: {e})") from None
    missing = [c for c in ("id", column) if c not in table.columns]
    if missing:
        raise KitError(
            f"method.images={str(file)!r} has no column(s) {missing} (it has {list(table.columns)}); give the "
            "columns id and the image path (method.images_column)"
        )
    out: dict[str, Path] = {}
    for group, rel in zip(table["id"].astype(str), table[column]):
        if rel is None or (isinstance(rel, float) and rel != rel) or str(rel) == "":
            continue
        if group in out:
            raise KitError(f"method.images={str(file)!r} lists {group} twice; keep one image per group")
        out[group] = Path(str(rel))
    return out


def submitted_images(source: str | os.PathLike, column: str = "image") -> tuple[Path, dict[str, Path]]:
    """The folder a submission may read and its image per group id (relative to that folder).

    Args:
        source: a folder of ``<scene>-<variation>/<object>.png`` (or ``.jpg``), or a manifest file
            (``.csv``, ``.jsonl``, ``.parquet``) with the columns ``id`` and ``column``, paths
            relative to its folder (config key ``method.images``).
        column: the manifest's image column (``method.images_column``).

    Returns:
        ``(folder, {id: path relative to folder})``. Paths are not yet checked: :func:`read_image`
        refuses one that leads outside the folder.

    Raises:
        KitError: naming ``method.images``, for a source that is not there, a table that cannot be
            read or lacks a column, two images for one group.
    """
    src = Path(source).expanduser()
    if src.is_dir():
        return src, {k: p.relative_to(src) for k, p in _from_folder(src).items()}
    if src.is_file():
        return src.parent, _from_manifest(src, column)
    raise KitError(
        f"method.images={str(source)!r} is neither a folder nor a file; give the folder of "
        "<scene>-<variation>/<object>.png images (named by the kit's ids) or a manifest file with columns id and "
        f"{column}"
    )


def read_image(folder: str | os.PathLike, rel: str | os.PathLike, size: tuple[int, int]) -> np.ndarray:
    """One submitted image: ``(H, W, 3)`` uint8 RGB.

    Args:
        folder: the submission's folder; the image must be inside it (:func:`inside`).
        rel: the image's path relative to ``folder``.
        size: ``(width, height)`` the group's camera has.

    Raises:
        KitError: naming the file: outside the folder, not an image, larger than
            :data:`MAX_IMAGE_PIXELS`, of another size (naming the size expected), or not 8-bit
            (grayscale, RGB, RGBA or a palette; saved at 16 bits or as floats it is refused).
    """
    from PIL import Image, ImageOps, UnidentifiedImageError

    path = inside(folder, rel, "the image")
    w, h = size
    try:
        with Image.open(path) as im:
            orientation = im.getexif().get(0x0112, 1)
            shown = im.size[::-1] if orientation in (5, 6, 7, 8) else im.size
            if shown[0] * shown[1] > MAX_IMAGE_PIXELS:
                raise KitError(
                    f"{path}: {shown[0]} x {shown[1]} pixels is not an image of this benchmark; expected {w} x {h}"
                )
            if shown != (w, h):
                raise KitError(
                    f"{path} is {shown[0]} x {shown[1]} pixels; the group's camera is {w} x {h}: generate the image at "
                    f"{w} x {h} (the kit's width and height), neither cropped nor resized"
                )
            if im.mode not in ("RGB", "RGBA", "L", "LA", "P"):
                raise KitError(
                    f"{path} has PIL mode {im.mode!r}; save it as 8-bit RGB (PNG or JPEG): the benchmark scores 8-bit "
                    "images, as it scores its own"
                )
            pixels = np.asarray(ImageOps.exif_transpose(im).convert("RGB"), dtype=np.uint8)
    except KitError:
        raise
    except (UnidentifiedImageError, OSError, Image.DecompressionBombError, SyntaxError, ValueError) as e:
        raise KitError(f"{path} cannot be read as an image ({type(e).__name__}: {e}); save it as an RGB PNG") from None
    return pixels
