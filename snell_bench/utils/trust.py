"""What a run folder holds is data, never instructions: paths from it stay inside it, links in it
are not followed, and its files are read with bounded parsers (docs/run-folders.md).

Convention:
    - A path taken from a record or a cell folder is relative, has no ``..`` and crosses no
      symbolic link below the folder it is relative to (:func:`safe_path`). snell_bench writes
      no symbolic links into a run (it shares files by hard link), so a link there was put by
      someone else and is not followed.
    - JSON is read up to :data:`MAX_JSON_BYTES` bytes and :data:`MAX_JSON_DEPTH` levels of nesting
      (:func:`read_json`); YAML up to :data:`MAX_YAML_BYTES` bytes that expands to at most
      :data:`MAX_YAML_NODES` nodes (an alias bomb expands a few hundred bytes into gigabytes)
      (:func:`load_yaml`); images up to :data:`MAX_IMAGE_PIXELS` pixels, refused from their header
      before any pixel is decoded (:func:`open_image`).
    - A reader that refuses returns the reason in one line (naming the file); the caller treats the
      cell as damaged (recomputed by the runner, left out by the reports with that reason).
    - The two files a run keeps as Python objects (a group's kept inputs, a result sampled ahead)
      are pickles, which run code when loaded: they carry an HMAC-SHA256 of their bytes under a
      key only this user can read (``$SNELL_BENCH_KEY_FILE``, else
      ``~/.cache/snell_bench/signing.key``, made on first use with mode 0600), and are loaded only
      when it matches (:func:`signed`, :func:`read_signed`); one that does not is computed again.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import logging
import os
import secrets
import warnings
from pathlib import Path, PurePosixPath

__all__ = [
    "MAX_IMAGE_PIXELS",
    "MAX_JSON_BYTES",
    "MAX_JSON_DEPTH",
    "MAX_YAML_NODES",
    "MAX_YAML_BYTES",
    "UntrustedPath",
    "json_depth",
    "load_yaml",
    "open_image",
    "read_json",
    "read_signed",
    "safe_path",
    "signed",
]

log = logging.getLogger(__name__)

#: The largest JSON file a run folder's record may be (a cell's metrics.json is a few kB).
MAX_JSON_BYTES = 16 * 2**20
#: The deepest nesting a record may have (snell_bench writes at most 6 levels).
MAX_JSON_DEPTH = 64
#: The largest config.yaml a cell may hold (a cell's is about 10 kB).
MAX_YAML_BYTES = 2**20
#: The most nodes a config.yaml may expand to, aliases copied (a cell's has about 1,000).
MAX_YAML_NODES = 100_000
#: The most pixels an image in a run folder may have (64 Mpx: 8K × 8K).
MAX_IMAGE_PIXELS = 64_000_000


class UntrustedPath(ValueError):
    """A path from a run folder that would leave it or follow a link; the message names it."""


def safe_path(root: str | os.PathLike, rel: str | os.PathLike, what: str = "file") -> Path:
    """``root / rel``, refused unless it stays inside ``root`` without following a link.

    Args:
        root: the folder (a cell, or a run's shared folder); it may itself be reached by a link.
        rel: the relative path a record or a listing gave.
        what: what the path is, for the message (e.g. ``"metrics.json files entry"``).

    Raises:
        UntrustedPath: ``rel`` is absolute, has a ``..`` or crosses a symbolic link below ``root``.

    Examples:
        >>> safe_path("/runs/exp/cell", "images/a.png").as_posix()
        '/runs/exp/cell/images/a.png'
        >>> safe_path("/runs/exp/cell", "../../etc/passwd")
        Traceback (most recent call last):
        ...
        snell_bench.utils.trust.UntrustedPath: file '../../etc/passwd' leaves /runs/exp/cell: ...
    """
    text = os.fspath(rel)
    parts = PurePosixPath(text.replace("\\", "/")).parts
    if not text or os.path.isabs(text) or PurePosixPath(text).is_absolute() or ".." in parts or ":" in parts[0]:
        raise UntrustedPath(
            f"{what} {text!r} leaves {root}: a run folder names its files relative to their cell, "
            "without '..'; the record is damaged"
        )
    path = Path(root)
    for part in parts:
        path = path / part
        if path.is_symlink():
            raise UntrustedPath(
                f"{what} {text!r} in {root} is a symbolic link ({path} -> {os.readlink(path)}); snell_bench "
                "writes none and does not follow one"
            )
    return path


def json_depth(value, limit: int = MAX_JSON_DEPTH) -> int:
    """The nesting depth of parsed JSON (a scalar: 0), counted without recursion; stops counting
    past ``limit + 1``."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, (dict, list)):
            d += 1
            deepest = max(deepest, d)
            if deepest > limit:
                return deepest
            stack.extend((x, d) for x in (v.values() if isinstance(v, dict) else v))
    return deepest


def read_json(path: str | os.PathLike, *, max_bytes: int = MAX_JSON_BYTES, max_depth: int = MAX_JSON_DEPTH):
    """``(value, None)`` of a JSON file, or ``(None, problem)``: a link, unreadable, larger than
    ``max_bytes``, not UTF-8, not JSON, or nested deeper than ``max_depth`` (checked before
    parsing, so a deep file cannot exhaust the parser's stack)."""
    path = Path(path)
    if path.is_symlink():
        return None, f"a symbolic link ({path} -> {os.readlink(path)}); snell_bench writes none and does not follow one"
    try:
        size = path.stat().st_size
        if size > max_bytes:
            return None, f"{size:,} bytes, more than a record may have ({max_bytes:,})"
        raw = path.read_bytes()[: max_bytes + 1]
    except OSError as e:
        return None, f"cannot be read: {e.strerror or e}"
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        return None, f"not UTF-8 text (byte 0x{raw[e.start]:02x} at position {e.start})"
    if _bracket_depth(text) > max_depth:
        return None, f"nested more than {max_depth} levels deep"
    try:
        return json.loads(text), None
    except (ValueError, RecursionError) as e:
        return None, f"not valid JSON: {e}"


def _bracket_depth(text: str) -> int:
    """An upper bound on the nesting of JSON ``text``: the most ``[`` / ``{`` open at once outside
    strings (a string's brackets are skipped; a malformed text errs on the deep side)."""
    import re

    deepest = depth = 0
    for m in re.finditer(r'"(?:[^"\\]|\\.)*"|[\[\{\]\}]', text):
        c = m.group()
        if c in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif c in "]}":
            depth -= 1
    return deepest


def load_yaml(path: str | os.PathLike, *, max_bytes: int = MAX_YAML_BYTES, max_nodes: int = MAX_YAML_NODES):
    """``(value, None)`` of a YAML file read safely (plain data only), or ``(None, problem)``:
    a link, unreadable, larger than ``max_bytes``, not YAML, or one that would expand to more than
    ``max_nodes`` nodes (aliases counted as the copies they stand for, from the composed graph,
    before anything is expanded: an alias bomb is refused in milliseconds)."""
    import yaml

    path = Path(path)
    if path.is_symlink():
        return None, f"a symbolic link ({path} -> {os.readlink(path)}); snell_bench writes none and does not follow one"
    try:
        size = path.stat().st_size
        if size > max_bytes:
            return None, f"{size:,} bytes, more than a cell's config.yaml may have ({max_bytes:,})"
        text = path.read_text(encoding="utf-8")
        loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
        node = yaml.compose(text, Loader=loader)  # aliases stay shared nodes here
        n = _expanded_nodes(node)
        if n > max_nodes:
            return None, f"expands to {n:,} nodes through its aliases, more than a config may have ({max_nodes:,})"
        return yaml.load(text, Loader=loader), None  # noqa: S506 - a safe loader
    except (OSError, UnicodeDecodeError) as e:
        return None, f"cannot be read: {getattr(e, 'strerror', None) or e}"
    except (yaml.YAMLError, RecursionError, ValueError) as e:
        return None, f"not YAML that snell_bench reads: {str(e).splitlines()[0] if str(e) else type(e).__name__}"


def _expanded_nodes(root) -> int:
    """How many nodes a composed YAML graph stands for once every alias is copied (each distinct
    node counted once, its size memoised; a cycle counts as too many)."""
    import yaml

    if root is None:
        return 0
    size: dict[int, int] = {}
    stack = [(root, False)]
    while stack:
        node, ready = stack.pop()
        if id(node) in size and not ready:
            continue
        children = []
        if isinstance(node, yaml.SequenceNode):
            children = list(node.value)
        elif isinstance(node, yaml.MappingNode):
            children = [x for pair in node.value for x in pair]
        if ready:
            size[id(node)] = 1 + sum(size.get(id(c), MAX_YAML_NODES + 1) for c in children)
        else:
            size[id(node)] = MAX_YAML_NODES + 1  # in progress: a cycle back to it is too many
            stack.append((node, True))
            stack.extend((c, False) for c in children if id(c) not in size)
    return size[id(root)]


def open_image(
    path: str | os.PathLike, *, root: str | os.PathLike | None = None, max_pixels: int = MAX_IMAGE_PIXELS, size=None
):
    """``(image, None)``: the PIL image at ``path``, loaded (reduced on load towards ``size`` pixels
    on its long side where the format allows, JPEG), or ``(None, problem)``: missing (problem
    ``None`` too: a missing image is not damage), a link (anywhere below ``root``, the run folder,
    when given), not an image, or over ``max_pixels`` (refused from its header, before any pixel
    is decoded)."""
    from PIL import Image

    path = Path(path)
    try:
        if root is not None:
            safe_path(root, path.relative_to(root), "image")
        elif path.is_symlink():
            raise UntrustedPath(f"{path} is a symbolic link; snell_bench writes none and does not follow one")
    except (UntrustedPath, ValueError) as e:  # ValueError: not below root
        return None, str(e)
    if not path.is_file():
        return None, None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                w, h = im.size
                if w * h > max_pixels:
                    return None, f"{path} is {w} x {h} pixels, more pixels than a run's image may have ({max_pixels:,})"
                if size is not None and im.format == "JPEG":
                    im.draft("RGB", (size, size))
                im.load()
                return im.copy(), None
    except Image.DecompressionBombError as e:  # PIL's own limit, met before ours
        return None, f"{path} has more pixels than a run's image may have ({max_pixels:,}): {e}"
    except (OSError, SyntaxError, ValueError) as e:
        return None, f"{path} is not a readable image ({type(e).__name__}: {e})"


_MAGIC = b"snell_bench signed v1\n"
_KEY: bytes | None = None


def _key() -> bytes:
    """This user's signing key (32 random bytes), made on first use; a key that cannot be kept
    (no writable home) lives for this process only, so what it signs is computed again later."""
    global _KEY
    if _KEY is None:
        cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
        path = Path(os.environ.get("SNELL_BENCH_KEY_FILE") or cache / "snell_bench" / "signing.key")
        try:
            if not path.is_file():
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_name(f".{path.name}.{os.getpid()}")
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
                with os.fdopen(fd, "wb") as f:
                    f.write(secrets.token_bytes(32))
                try:  # the first process to link its key wins; the others read that one
                    os.link(tmp, path)
                except FileExistsError:
                    pass
                finally:
                    tmp.unlink(missing_ok=True)
            key = path.read_bytes()
            if len(key) < 32:
                raise OSError(f"{len(key)} bytes, not a key")
            _KEY = key
        except OSError as e:
            log.warning("no signing key at %s (%s): files kept as Python objects are computed again later", path, e)
            _KEY = secrets.token_bytes(32)
    return _KEY


def signed(payload: bytes) -> bytes:
    """``payload`` with this user's HMAC-SHA256 in front, for :func:`read_signed`."""
    return _MAGIC + hmac.new(_key(), payload, hashlib.sha256).digest() + payload


def read_signed(path: str | os.PathLike) -> tuple[bytes | None, str | None]:
    """``(payload, None)`` of a file :func:`signed` wrote with this user's key, or ``(None,
    problem)``: missing, a link, unsigned or signed otherwise (changed since, or by someone else)."""
    path = Path(path)
    if path.is_symlink():
        return None, f"{path} is a symbolic link; snell_bench writes none and does not follow one"
    try:
        blob = path.read_bytes()
    except OSError as e:
        return None, f"{path} cannot be read: {e.strerror or e}"
    head, n = len(_MAGIC), hashlib.sha256().digest_size
    mac, payload = blob[head : head + n], blob[head + n :]
    if blob[:head] != _MAGIC or not hmac.compare_digest(mac, hmac.new(_key(), payload, hashlib.sha256).digest()):
        return None, f"{path} is not signed with this user's key (changed since it was written, or not written here)"
    return payload, None
