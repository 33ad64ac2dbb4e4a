"""text_to_image: the synchronized sampler's text-to-image baseline, without warps."""

import pytest
import torch

from snell_bench.sampler.text_to_image import text_to_image


@pytest.mark.parametrize("backend", ["analytic", "tiny_flux"])
def test_equals_the_samplers_text_to_image_baseline(backend, small_camera):
    """Bit for bit what ``sample(..., sync="none")`` gives for the same seed (same noise, steps)."""
    import numpy as np

    from snell_bench.models.analytic import AnalyticGenerator
    from snell_bench.models.tiny_flux import TinyFluxGenerator
    from snell_bench.optics.warps import compute_warps
    from snell_bench.sampler import SamplerSettings, sample
    from tests.conftest import sphere_at

    H, W = 96, 160
    depth = np.full((H, W), 4.0)
    ws = compute_warps(depth, small_camera, sphere_at([0.0, 0.2, 2.5], 0.4), pano_height=32, cache_dir=None)
    i_minus = torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(1))
    if backend == "analytic":
        gen = AnalyticGenerator.from_scene(i_minus[0].permute(1, 2, 0).numpy(), ws.object_mask, None)
    else:
        gen = TinyFluxGenerator(seed=0)
    ref = sample(
        gen, ws, i_minus, "a room", "a panorama", SamplerSettings(steps=4, sync="none", progress=False), seed=7
    )
    out = text_to_image(gen, "a room", H, W, steps=4, seed=7)
    assert torch.equal(out, ref.image)
    assert not torch.equal(out, text_to_image(gen, "a room", H, W, steps=4, seed=8))
