"""The physics-only method: I⁻ seen through the glass by Snell's law alone.

Each object pixel takes the colour of I⁻ where its refracted ray lands (π^R, traced by snell_bench)
and, with ``reflection``, the Fresnel-weighted colour of its mirror ray, combined in linear RGB; no
generator is involved. It is the answer optics gives without any model: what a generative method
must at least match inside the object, and what it can only add to (the unobserved surfaces, the
panorama behind the camera, the light). Pixels whose refracted ray ends nowhere I⁻ shows keep I⁻.

Registered by the entry point ``physics_only`` (``pyproject.toml``): ``method=physics_only`` and
``grid.methods=[..., physics_only]`` select it; ``method.params.reflection=false`` switches the
reflection off (or ``examples/conf/method/physics_only_refraction.yaml`` through Hydra's search path).
"""

from __future__ import annotations

import torch

from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear
from snell_bench.imaging.remap import remap
from snell_bench.methods import Method
from snell_bench.methods.cost import Estimate
from snell_bench.pipeline import CellResult

__all__ = ["PhysicsOnly"]


class PhysicsOnly(Method):
    """I⁻ remapped through the exact π^R, with Fresnel reflection (see the module's docs).

    Args:
        reflection: add the first surface's reflection of I⁻ (its mirror warp), weighted by the
            unpolarised Fresnel reflectance, in linear RGB.
    """

    description = "I⁻ through Snell's law alone (π^R, Fresnel reflection): no generator"
    default_label = "Physics only (I⁻ through π^R)"

    def __init__(self, reflection: bool = True) -> None:
        super().__init__(reflection=reflection)
        self.reflection = bool(reflection)

    def run(self, cfg, inputs, warps, t):
        i_minus = inputs.i_minus  # (1, 3, H, W) sRGB in [0, 1]
        with t("sampling"):
            refracted, ok = remap(i_minus, warps.refraction)
            linear = srgb_to_linear(torch.where(ok[:, None], refracted, i_minus))
            if self.reflection:
                reflected, seen = remap(i_minus, warps.reflection)
                r = torch.from_numpy(warps.fresnel).to(linear)[None, None] * seen[:, None]
                linear = r * srgb_to_linear(reflected) + (1 - r) * linear
            inside = torch.from_numpy(warps.object_mask)[None, None]
            image = torch.where(inside, linear_to_srgb(linear), i_minus).clamp(0, 1).float()
        return CellResult(image=image, warps=warps, stats={"physics_only": {"reflection": self.reflection}})

    def cost(self, scene_cfg, cfg, models, basis):
        return Estimate((0.0, 0.0), 0.0, None, "CPU", "two remaps of I⁻ on the CPU (no model)")
