"""Mitsuba 3 for the reference renderer: importing it and choosing its variant.

Importing this module does not import Mitsuba; :func:`import_mitsuba`, :func:`mitsuba_variant` and
:func:`set_variant` do.

Convention:
    - Variant: ``$SNELL_BENCH_MITSUBA_VARIANT`` (:data:`VARIANT_ENV`) wins if set; otherwise
      ``llvm_ad_rgb`` (vectorised, ~3x faster than ``scalar_rgb``) if a tiny reference render with it
      succeeds in a subprocess, else ``scalar_rgb``. The probe runs once per process.
    - Probe: ``python -c "from snell_bench.render.probe import probe_render; probe_render()"`` with the
      variant forced by the environment, in a subprocess, because a broken JIT backend (no libLLVM, or
      an incompatible one) can abort the whole process, which no ``try`` catches. It succeeds iff the
      subprocess exits with 0 and prints a marker.
    - :func:`set_variant` selects the variant and registers the plugins of
      :mod:`snell_bench.render.plugins` for it; every function that builds or renders a Mitsuba scene
      takes the ``mitsuba`` module it returns.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

from snell_bench.render.plugins import register_plugins

log = logging.getLogger(__name__)

__all__ = ["PROBE_OK", "VARIANT_ENV", "import_mitsuba", "mitsuba_variant", "set_variant"]

#: Environment variable that forces a Mitsuba variant (e.g. ``scalar_rgb``), skipping the probe.
VARIANT_ENV = "SNELL_BENCH_MITSUBA_VARIANT"
#: The line a successful probe prints.
PROBE_OK = "SNELL_BENCH_MITSUBA_PROBE_OK"
_PREFERRED_VARIANT = "llvm_ad_rgb"
_FALLBACK_VARIANT = "scalar_rgb"
_PROBE_TIMEOUT_S = 300
_PROBE_CODE = "from snell_bench.render.probe import probe_render; probe_render()"
_INSTALL_HINT = (
    "the reference renderer needs Mitsuba 3: install the render extra with "
    "`pip install snell_bench[render]` (or `make setup EXTRAS=test,render`)"
)

_probed_variant: str | None = None


def import_mitsuba():
    """The ``mitsuba`` module.

    Raises:
        ImportError: Mitsuba is not installed (the message names the ``render`` extra).
    """
    try:
        import mitsuba as mi
    except ImportError as e:
        raise ImportError(f"{_INSTALL_HINT} ({e})") from e
    return mi


def _probe(variant: str) -> bool:
    """Whether a tiny reference render with ``variant`` succeeds in a subprocess (see the module's
    conventions)."""
    root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ)
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env[VARIANT_ENV] = variant
    try:
        r = subprocess.run(
            [sys.executable, "-c", _PROBE_CODE], env=env, capture_output=True, text=True, timeout=_PROBE_TIMEOUT_S
        )
    except (subprocess.TimeoutExpired, OSError) as e:
        log.info("mitsuba variant %s: probe failed (%s)", variant, e)
        return False
    ok = r.returncode == 0 and PROBE_OK in r.stdout
    if not ok:
        tail = (r.stderr or r.stdout).strip().splitlines()[-3:]
        log.info("mitsuba variant %s unusable here (exit code %s): %s", variant, r.returncode, " | ".join(tail))
    return ok


def mitsuba_variant() -> str:
    """The Mitsuba variant to render with.

    ``$SNELL_BENCH_MITSUBA_VARIANT`` wins if set. Otherwise ``llvm_ad_rgb`` (vectorised, ~3x faster)
    if a tiny render with it succeeds in a subprocess, else ``scalar_rgb``. The probe runs once per
    process.

    Returns:
        The variant's name.

    Raises:
        ImportError: Mitsuba is not installed.
        ValueError: the environment variable names no Mitsuba variant.
    """
    global _probed_variant
    mi = import_mitsuba()
    forced = os.environ.get(VARIANT_ENV, "").strip()
    if forced:
        if forced not in mi.variants():
            raise ValueError(f"{VARIANT_ENV}={forced!r} is not a Mitsuba variant; available: {mi.variants()}")
        return forced
    if _probed_variant is None:
        usable = _PREFERRED_VARIANT in mi.variants() and _probe(_PREFERRED_VARIANT)
        v = _PREFERRED_VARIANT if usable else _FALLBACK_VARIANT
        log.info("mitsuba: rendering with the %s variant", v)
        _probed_variant = v
    return _probed_variant


def set_variant():
    """Select :func:`mitsuba_variant` and register the plugins of :mod:`snell_bench.render.plugins`
    for it.

    Returns:
        The ``mitsuba`` module, set to that variant.
    """
    mi = import_mitsuba()
    mi.set_variant(mitsuba_variant())
    register_plugins(mi)
    return mi
