"""Mitsuba 3 for the reference renderer: importing it and choosing its variant.

Importing this module does not import Mitsuba; :func:`import_mitsuba`, :func:`mitsuba_variant` and
:func:`set_variant` do.

Convention:
    - Variant: ``$SNELL_BENCH_MITSUBA_VARIANT`` (:data:`VARIANT_ENV`) wins if set; otherwise the first
      of :data:`PREFERRED_VARIANTS` that this Mitsuba build has and whose tiny reference render
      succeeds in a subprocess: ``cuda_ad_rgb`` (the GPU; probed only where the CUDA driver library
      loads, :func:`cuda_driver`), then ``llvm_ad_rgb`` (vectorised on the CPU, ~3x faster than
      ``scalar_rgb``); else ``scalar_rgb``. The probes run once per process (:func:`probed_variant`).
    - Probe: ``python -c "from snell_bench.render.probe import probe_render; probe_render()"`` with the
      variant forced by the environment, in a subprocess, because a broken JIT backend (no libLLVM, or
      an incompatible one; no GPU, or a driver too old for Dr.Jit's CUDA backend) can abort the whole
      process, which no ``try`` catches. It succeeds iff the subprocess exits with 0 and prints a
      marker.
    - Every variant renders the same scene with the same code (:mod:`snell_bench.render.pieces`,
      :mod:`snell_bench.render.plugins`, :mod:`snell_bench.render.integrator`): arrays cross to
      Mitsuba as numpy (copied to the device by the variant's array types) and back with
      ``numpy.array`` (copied to the host). The JIT variants (``llvm_*``, ``cuda_*``) add a pixel's
      samples in whatever order its threads finish, so their images are reproducible up to float
      rounding; ``scalar_rgb`` bit for bit. The variant is recorded with every reference.
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

__all__ = [
    "PREFERRED_VARIANTS",
    "PROBE_OK",
    "VARIANT_ENV",
    "cuda_driver",
    "import_mitsuba",
    "mitsuba_variant",
    "probed_variant",
    "set_variant",
]

#: Environment variable that forces a Mitsuba variant (e.g. ``scalar_rgb``), skipping the probe.
VARIANT_ENV = "SNELL_BENCH_MITSUBA_VARIANT"
#: The line a successful probe prints.
PROBE_OK = "SNELL_BENCH_MITSUBA_PROBE_OK"
#: The variants tried, in order, when none is forced: the GPU, then the vectorised CPU back end.
PREFERRED_VARIANTS = ("cuda_ad_rgb", "llvm_ad_rgb")
_CUDA_VARIANT = "cuda_ad_rgb"
_FALLBACK_VARIANT = "scalar_rgb"
#: The CUDA driver library, as Dr.Jit's CUDA back end loads it.
_CUDA_LIBRARIES = ("libcuda.so.1", "libcuda.so", "libcuda.dylib", "nvcuda.dll")
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


def cuda_driver() -> bool:
    """Whether the CUDA driver library loads here (what Dr.Jit's CUDA back end needs; loading it
    initialises no device): without it ``cuda_ad_rgb`` is not probed."""
    import ctypes

    for name in _CUDA_LIBRARIES:
        try:
            ctypes.CDLL(name)
        except OSError:
            continue
        return True
    return False


def probed_variant() -> str | None:
    """The variant this process's probes chose, or ``None`` before :func:`mitsuba_variant` probed
    (a forced variant is not a probe's); imports nothing."""
    return _probed_variant


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

    ``$SNELL_BENCH_MITSUBA_VARIANT`` wins if set. Otherwise the first of :data:`PREFERRED_VARIANTS`
    (``cuda_ad_rgb`` where the CUDA driver loads, then ``llvm_ad_rgb``) that Mitsuba has and whose
    tiny render succeeds in a subprocess, else ``scalar_rgb``. The probes run once per process.

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
        have = mi.variants()
        candidates = [v for v in PREFERRED_VARIANTS if v in have and (v != _CUDA_VARIANT or cuda_driver())]
        v = next((v for v in candidates if _probe(v)), _FALLBACK_VARIANT)
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
