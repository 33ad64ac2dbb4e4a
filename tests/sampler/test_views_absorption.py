"""A tinted glass in the main view's blend: the refracted estimate is tinted by the warps'
transmittance before the Fresnel mix, and nothing changes outside the object or for clear glass."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from snell_bench.imaging.blend import absorb
from snell_bench.sampler import SamplerSettings
from snell_bench.sampler.views import Views
from tests.sampler.room import room_sphere

H, W, HP = 64, 96, 32


@pytest.fixture(scope="module")
def setup():
    _, _, ws, i_minus = room_sphere(W, H, HP)
    sigma = np.array([8.0, 3.0, 0.5], np.float32)  # per metre; the sphere is ~0.4 m across
    tinted = replace(ws, absorption=tuple(sigma), optical_depth=ws.path_length[..., None] * sigma)
    x0 = torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(0))
    pano = torch.rand(1, 3, HP, 2 * HP, generator=torch.Generator().manual_seed(1))
    return ws, tinted, i_minus, x0, pano


def test_refraction_is_tinted_before_the_fresnel_mix(setup):
    ws, tinted, i_minus, x0, _ = setup
    s = SamplerSettings(panorama=False, reflection=False, progress=False)
    clear = Views(ws, i_minus, s).blend_main(x0, None)
    got = Views(tinted, i_minus, s).blend_main(x0, None)
    T = tinted.transmittance()
    assert (T[ws.object_mask] < 1).all() and T.min() < 0.1
    assert torch.equal(got, absorb(clear, T))


def test_outside_the_object_and_clear_glass_are_unchanged(setup):
    ws, tinted, i_minus, x0, pano = setup
    s = SamplerSettings(progress=False)
    clear = Views(ws, i_minus, s).blend_main(x0, pano)
    got = Views(tinted, i_minus, s).blend_main(x0, pano)
    outside = torch.from_numpy(~ws.object_mask)
    assert torch.equal(got[..., outside], clear[..., outside])
    assert not torch.equal(got, clear)
    assert Views(ws, i_minus, s).transmittance is None and np.all(ws.transmittance() == 1)
