"""The path-traced truth of a procedural scene relit with the glass in place: its noise, and the
traced relighter with the scene's own lights against it (outdoor: a directional sun)."""

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from render_testing import forced_cpu_variant  # noqa: E402

from snell_bench.optics import compute_warps  # noqa: E402
from snell_bench.render.light_truth import light_truth  # noqa: E402
from snell_bench.scene.objects import GlassObject  # noqa: E402
from snell_bench.scene.placement import place_object  # noqa: E402
from snell_bench.scene.sources import procedural_scene  # noqa: E402


@pytest.fixture(scope="module", autouse=True)
def cpu_variant():
    with forced_cpu_variant():
        yield


def _psnr(a, b, m) -> float:
    return float(10 * np.log10(1.0 / ((a - b)[m] ** 2).mean()))


def test_traced_relighting_with_the_true_sun_reaches_the_truths_noise():
    """Outdoor, a sphere on a stone table under the sun: the truth (256 spp) changes the shadow and
    caustic region by far more than its noise; the traced relighter with the scene's own lights
    scores within 2 dB of the truth's self-noise there (a perfect relighting scores about that),
    the image without relighting more than 12 dB below."""
    import torch

    from snell_bench.relight.traced import TracedRelighter

    sc = procedural_scene("outdoor", 0, 160, 90)
    obj = place_object(GlassObject.sphere(), sc.depth, sc.camera)
    truth = light_truth(sc.source, sc.camera, sc.image, obj, spp=256)
    region = truth.receivers & (np.abs(truth.image - sc.image).max(-1) > 2 / 255)
    assert region.sum() > 300 and truth.self_noise_db > 28
    ws = compute_warps(sc.depth, sc.camera, obj, pano_height=32)
    image = torch.from_numpy(sc.image.transpose(2, 0, 1))[None].float()
    relit = TracedRelighter(lights="true", caustic_rays=200_000).relight(image, seed=0, scene=sc, obj=obj, warps=ws)
    relit = relit[0].numpy().transpose(1, 2, 0)
    assert _psnr(relit, truth.image, region) >= truth.self_noise_db - 2.0
    assert _psnr(sc.image, truth.image, region) < truth.self_noise_db - 12.0
