"""Optics: Snell's law and Fresnel (pure torch functions), the Open3D tracer, the warps, and far
background at infinity (:mod:`snell_bench.optics.far_field`)."""

from snell_bench.optics.functional import face_forward, fresnel, fresnel_cos, reflect, refract
from snell_bench.optics.tracer import HitKind, SceneTracer
from snell_bench.optics.warps import WarpSet, compute_warps, warp_inputs_hash

__all__ = [
    "face_forward",
    "fresnel",
    "fresnel_cos",
    "reflect",
    "refract",
    "HitKind",
    "SceneTracer",
    "WarpSet",
    "compute_warps",
    "warp_inputs_hash",
]
