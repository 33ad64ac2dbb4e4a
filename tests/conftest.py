"""Shared fixtures: small analytic scenes with known answers."""

import logging
import os
import sys

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np
import pytest

from snell_bench.scene.camera import Camera
from snell_bench.scene.objects import GlassObject


def sphere_at(center, radius, ior=1.5, subdivisions=5) -> GlassObject:
    """A placed icosphere with the given centre and radius (camera frame)."""
    T = np.eye(4)
    T[:3, :3] *= 2 * radius
    T[:3, 3] = np.asarray(center, float) - [0.0, radius, 0.0]
    return GlassObject.sphere(ior=ior, subdivisions=subdivisions).transformed(T)


def analytic_sphere_plane(dirs, center, radius, ior, plane_z):
    """Ray-by-ray closed form: camera rays ``dirs`` through a sphere onto the plane z = plane_z.

    Snell's law here is written independently of snell_bench.optics (tangential component of the
    direction scaled by the index ratio). Returns (points on the plane (N, 3), NaN where the ray
    misses the sphere or is totally reflected)."""
    c = np.asarray(center, float)

    def hit(o, d, far):
        oc = o - c
        b = (oc * d).sum(-1)
        disc = b * b - ((oc * oc).sum(-1) - radius**2)
        s = np.sqrt(np.maximum(disc, 0))
        return np.where(disc > 0, -b + s if far else -b - s, np.nan)

    def snell(i, n, eta):
        cos_i = -(i * n).sum(-1, keepdims=True)
        tan = eta * (i + cos_i * n)
        s2 = (tan * tan).sum(-1, keepdims=True)
        return tan - np.sqrt(np.maximum(1 - s2, 0)) * n, s2[..., 0] > 1

    o = np.zeros_like(dirs)
    p1 = o + hit(o, dirs, False)[:, None] * dirs
    d1, _ = snell(dirs, (p1 - c) / radius, 1 / ior)
    p2 = p1 + hit(p1, d1, True)[:, None] * d1
    d2, tir = snell(d1, -(p2 - c) / radius, ior)
    p3 = p2 + ((plane_z - p2[:, 2]) / d2[:, 2])[:, None] * d2
    return np.where(tir[:, None], np.nan, p3), p1


@pytest.fixture
def small_camera() -> Camera:
    return Camera.from_fov(160, 96, 60.0)


def integrate_flow(gen, z, cond, steps: int = 400):
    """Euler-integrate ``gen``'s exact velocity from ``sigma = 1`` on a linear schedule of ``steps``
    steps, the last step replaced by the posterior mean (the velocity is undefined at 0)."""
    from snell_bench.sampler import linear_sigmas

    sig = linear_sigmas(steps)
    for a, b in zip(sig[:-1], sig[1:]):
        if b == 0:
            return gen.posterior_mean(z, float(a), cond)
        z = z + (float(b) - float(a)) * gen.velocity(z, float(a), cond)
    return z


@pytest.fixture
def run_cli(tmp_path, monkeypatch):
    """``cli()`` in this process with these arguments (runs and reports under tmp_path): its exit
    status. Hydra's logging set-up is undone afterwards."""
    from snell_bench.__main__ import cli

    root = logging.getLogger()
    saved = root.handlers[:], root.level

    def run(*args: str) -> int:
        argv = [*args, f"runs_dir={tmp_path / 'runs'}", f"reports_dir={tmp_path / 'reports'}"]
        monkeypatch.setattr(sys, "argv", ["snell_bench", *argv])
        try:
            cli()
        except SystemExit as e:
            return e.code
        return 0

    yield run
    root.handlers[:], _ = saved
    root.setLevel(saved[1])
