"""The I⁻ term of the main view's blend, π^R(I⁻): I⁻ itself outside the object, bit for bit, in
both blend domains, with the object's silhouette kept out of the pyramid's level choice."""

import numpy as np
import pytest
import torch
from scipy.ndimage import binary_dilation

from snell_bench.imaging.pyramid import collapse, gaussian_pyramid, laplacian_pyramid, warped_bands
from snell_bench.sampler import SamplerSettings
from snell_bench.sampler.views import Views, keep_outside
from tests.sampler.room import room_sphere
from tests.tolerances import reordering_tolerance

H, W, HP = 64, 96, 32


@pytest.fixture(scope="module")
def setup():
    _, _, ws, i_minus = room_sphere(W, H, HP)
    return ws, i_minus


def views(setup, **kw):
    ws, i_minus = setup
    return Views(ws, i_minus, SamplerSettings(panorama=False, reflection=False, progress=False, **kw))


@pytest.mark.parametrize("kw", [{}, {"roi": False}, {"lpw": False}])
def test_image_domain_is_i_minus_outside_the_object(setup, kw):
    ws, i_minus = setup
    v = views(setup, **kw)
    outside = torch.from_numpy(~ws.object_mask)
    assert torch.equal(v.imin_main[..., outside], i_minus[..., outside])
    assert v.imin_main_m[..., outside].all()
    # inside: the refraction where it is valid, invalid (and 0) where it is not
    inside_ok = torch.from_numpy(ws.object_mask & np.isfinite(ws.refraction[..., 0]))
    assert torch.equal(v.imin_main_m[0, 0], ~torch.from_numpy(ws.object_mask) | inside_ok)
    assert (v.imin_main[..., ~v.imin_main_m[0, 0]] == 0).all()


def test_bands_are_i_minus_own_away_from_the_object(setup):
    ws, i_minus = setup
    v = views(setup, dpa_domain="bands")
    own = laplacian_pyramid(i_minus, 5)
    assert len(v.imin_main) == 5
    for k, (band, ref, m) in enumerate(zip(v.imin_main, own, v.imin_main_m)):
        # level k reads level k + 1 through pyrup (2 coarse pixels each way, square): a level-k pixel
        # more than 2 * 2**(k + 1) + 2**k level-0 pixels from the object (in x or y) never reads it
        near = binary_dilation(ws.object_mask, np.ones((3, 3), bool), iterations=5 * 2**k + 1)
        far = torch.from_numpy(~near[:: 2**k, :: 2**k][: band.shape[-2], : band.shape[-1]])
        assert far.sum() > 0.3 * far.numel() if k < 2 else True  # coarse levels of 64 x 96: few or none
        assert m[..., far].all()
        # the same operations on the same values, in a 4-channel (image and mask) upsampling where
        # the level has invalid pixels: equal up to the summation order of the 5 x 5 blur and the
        # bilinear resampling (29 terms)
        tol = reordering_tolerance(29, ref)
        torch.testing.assert_close(band[..., far], ref[..., far], atol=tol, rtol=0)
    # the pyramid collapses to the completed image: I⁻ outside the object (float rounding of 5 levels)
    out = collapse(v.imin_main, v.imin_main_m)
    outside = torch.from_numpy(~ws.object_mask)
    tol = reordering_tolerance(5 * 29, i_minus)
    torch.testing.assert_close(out[..., outside], i_minus[..., outside], atol=tol, rtol=0)


def test_keep_outside_on_gaussian_levels():
    # a hand-made 8 x 8 object block with one invalid pixel; own levels 1.0, warped levels 5.0
    obj = torch.zeros(1, 1, 8, 8, dtype=torch.bool)
    obj[..., 2:6, 2:6] = True
    own = gaussian_pyramid(torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(0)), 3)
    m0 = obj.clone()
    m0[..., 2, 2] = False
    masks = [m0, torch.zeros(1, 1, 4, 4, dtype=torch.bool), torch.zeros(1, 1, 2, 2, dtype=torch.bool)]
    masks[1][..., 1:3, 1:3] = True  # blocks holding a valid object pixel
    masks[2][...] = True
    levels = [torch.full_like(o, 5.0) for o in own]
    out, out_m = keep_outside(levels, masks, own, obj)
    assert torch.equal(out[0][~obj], own[0][~obj]) and torch.equal(out[0][m0], levels[0][m0])
    assert not out_m[0][..., 2, 2] and out[0][..., 2, 2] == 0  # the object's invalid pixel
    assert out_m[1].all() and torch.equal(out[1][~masks[1]], own[1][~masks[1]])
    assert torch.equal(out[2], levels[2])
    bands = warped_bands(out, out_m)
    torch.testing.assert_close(collapse(bands, out_m), out[0], atol=reordering_tolerance(3 * 29, 5.0), rtol=0)
    img, img_m = keep_outside(levels[0], m0, own[0], obj)
    assert torch.equal(img, out[0]) and torch.equal(img_m, out_m[0])
