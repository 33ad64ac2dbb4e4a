"""The authors' lighting rules (snell_bench.render.lighting) on hand-made images and boxes, against
values worked out by hand from render_gt's rules."""

import math

import numpy as np
import pytest

from snell_bench.render.lighting import (
    BrightPatch,
    brightest_patch,
    exposure_ev,
    fallback_light,
    luminance,
    patch_light,
    patch_probe_pixels,
    world_colour,
)


def _image(h=48, w=64, value=0.1):
    return np.full((h, w, 3), value, np.float64)


class TestBrightestPatch:
    def test_a_bright_block_gives_its_centre_tone_and_luminance(self):
        img = _image()
        img[18:23, 28:33] = 1.0  # 25 pixels, more than the 0.3 % (9.2 pixels) above the percentile
        p = brightest_patch(img)
        assert (p.x, p.y) == (30, 20)
        # half-width max(2, int(0.03 * 48)) = 2: the 5 x 5 patch is the block itself
        np.testing.assert_allclose(p.tone, [1.0, 1.0, 1.0])
        assert p.luminance == pytest.approx(1.0)

    def test_a_lone_bright_pixel_is_taken_as_it_is(self):
        img2 = np.zeros((48, 64, 3))
        img2[5, 50] = [0.0, 1.0, 0.0]
        img2[6, 50] = [0.0, 0.5, 0.0]
        q = brightest_patch(img2)
        assert (q.x, q.y) == (50, 5)  # 2 pixels above 0: the brightest pixel
        # the 5 x 5 patch around it holds 1.0 and 0.5 green: mean luminance 0.7152 * 1.5 / 25
        assert q.luminance == pytest.approx(0.7152 * 1.5 / 25)

    def test_probe_pixels_start_at_the_patch_and_step_by_image_fractions(self):
        px = patch_probe_pixels(30, 20, 200, 100)
        np.testing.assert_allclose(px[0], [30, 20], atol=1e-9)
        np.testing.assert_allclose(px[1], [30 + 0.015 * 200, 20], atol=1e-9)  # right
        np.testing.assert_allclose(px[3], [30, 20 - 0.015 * 100], atol=1e-9)  # up
        np.testing.assert_allclose(px[8], [30, 20 + 0.03 * 100], atol=1e-9)  # down
        corner = patch_probe_pixels(0, 0, 200, 100)
        assert corner[2][0] == pytest.approx(0.001 * 200 - 0.5)  # clamped to 0.1 % of the width


class TestPatchLight:
    patch = BrightPatch(0, 0, np.array([0.8, 0.6, 0.4]), 0.5)
    scene = (np.array([-1.0, -1.0, 1.0]), np.array([1.0, 1.0, 2.0]))  # size 2: offset o = 0.24
    wall = (np.array([-1.0, -1.0, 2.0]), np.array([1.0, 1.0, 2.0]))
    far_object = (np.array([-0.1, -0.1, 1.0]), np.array([0.1, 0.1, 1.2]))

    def test_in_front_of_a_wall_facing_the_camera(self):
        light = patch_light([0, 0, 2], [0, 0, -1], np.zeros(3), self.patch, self.scene, self.wall, self.far_object)
        # n x (hit - camera) = 0: the side is the x axis; 0.9 o back towards the camera, 0.5 o right
        np.testing.assert_allclose(light.position, [0.12, 0.0, 2 - 0.216], atol=1e-12)
        # 0.8 from the object's centre, d_ref = 0.15: no distance scale; 250 + 3200 * 0.5
        assert light.energy == pytest.approx(1850.0)
        np.testing.assert_allclose(light.colour, 0.75 * self.patch.tone + 0.25)
        assert light.radius == pytest.approx(0.16)

    def test_pushed_out_of_the_background_box_and_dimmed_near_the_object(self):
        deep = (np.array([-1.0, -1.0, 1.5]), np.array([1.0, 1.0, 2.0]))  # the start z = 1.784 is inside
        near = (np.array([0.05, -0.05, 1.2]), np.array([0.15, 0.05, 1.3]))
        light = patch_light([0, 0, 2], [0, 0, -1], np.zeros(3), self.patch, self.scene, deep, near)
        # moves 0.6 o = 0.144 towards the camera until z < 1.5: twice (1.640, 1.496)
        np.testing.assert_allclose(light.position, [0.12, 0.0, 2 - 0.216 - 2 * 0.144], atol=1e-12)
        d = math.dist(light.position, [0.1, 0.0, 1.25])
        scale = max(0.06, min(1.0, (d / 0.08) ** 2))  # d_ref = max(0.75 * 0.1, 0.08)
        assert light.energy == pytest.approx(1850.0 * scale)

    def test_the_side_is_normal_cross_view(self):
        elsewhere = (np.full(3, 5.0), np.full(3, 6.0))  # the light starts outside it: no push
        light = patch_light([1, 0, 2], [-1, 0, 0], np.zeros(3), self.patch, self.scene, elsewhere, self.far_object)
        side = np.cross([-1, 0, 0], np.array([1, 0, 2]) / math.sqrt(5))
        side /= np.linalg.norm(side)
        np.testing.assert_allclose(light.position, np.array([1, 0, 2]) + 0.216 * np.array([-1, 0, 0]) + 0.12 * side)

    def test_fallback_between_camera_and_scene(self):
        img = np.full((10, 10, 3), 0.25)
        light = fallback_light(img, self.scene, self.wall, up=np.array([0, -1.0, 0]), forward=np.array([0, 0, 1.0]))
        # centre z 1.5, half-depth 0.5: z = 1.5 - 0.6 = 0.9; up by 0.8 * 2
        np.testing.assert_allclose(light.position, [0.0, -1.6, 0.9])
        assert light.energy == pytest.approx(1200.0 * 2.0)  # 0.5 / 0.25 = 2 (at the clamp)
        np.testing.assert_allclose(light.colour, 0.55 * 0.25 + 0.45)
        assert light.radius == pytest.approx(0.2)


class TestWorldAndExposure:
    def test_the_world_colour_comes_from_the_border(self):
        img = np.zeros((50, 100, 3))
        border = np.array([0.2, 0.4, 0.6])
        img[:] = border
        img[4:-4, 4:-4] = [1.0, 0.0, 1.0]  # int(0.08 * 50) = 4 pixels of border: the inside is ignored
        colour, strength = world_colour(img)
        np.testing.assert_allclose(colour, 0.75 * border + 0.25)
        assert strength == pytest.approx(0.6 * float(luminance(border)))
        _, dark = world_colour(np.zeros((20, 20, 3)))
        assert dark == pytest.approx(0.02)  # the lower clamp

    @pytest.mark.parametrize(
        "grey,ev",
        [(0.5, 0.0), (0.25, 1.0), (0.1, 1.0), (1.0, -1.0), (0.9, math.log2(0.5 / 0.9)), (0.0, 1.0)],
    )
    def test_the_exposure_aims_the_mean_luminance_at_one_half(self, grey, ev):
        assert exposure_ev(np.full((8, 8, 3), grey)) == pytest.approx(ev)

    def test_the_exposure_uses_the_mean_colour(self):
        img = np.zeros((2, 2, 3))
        img[0, 0] = [0.0, 1.0, 0.0]  # mean luminance 0.7152 / 4
        assert exposure_ev(img) == pytest.approx(max(-2.0, min(1.0, math.log2(0.5 / (0.7152 / 4)))))

    def test_a_bad_image_names_its_shape(self):
        with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
            exposure_ev(np.zeros((4, 4)))
