"""The small scene the sampler's tests share: a glass sphere on the procedural room's table."""

import torch

from snell_bench.optics import compute_warps
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.placement import place_object
from snell_bench.scene.procedural import ProceduralScene


def room_sphere(width: int, height: int, pano_height: int):
    """``(scene, render, warps, i_minus)``: the room (seed 0) rendered at ``width x height``, a sphere
    (subdivision 3, 0.4 of its distance) placed on its table, the warps traced with a panorama of
    ``pano_height``, and I⁻ as a ``(1, 3, H, W)`` float32 tensor."""
    scene = ProceduralScene("room", seed=0)
    r = scene.render(width, height)
    obj = place_object(GlassObject.sphere(subdivisions=3), r.depth, r.camera, up_hint=scene.up, relative_size=0.4)
    ws = compute_warps(r.depth, r.camera, obj, pano_height=pano_height)
    i_minus = torch.from_numpy(r.image).permute(2, 0, 1)[None].float()
    return scene, r, ws, i_minus
