"""The default job through Hydra: config composition and the refraction preview."""

import json

import numpy as np
import pytest
from PIL import Image

from snell_bench.config import compose as make_cfg


def test_root_config_composes_with_defaults():
    cfg = make_cfg(["output_dir=/tmp/x"])
    assert cfg.job == "preview" and cfg.scene.kind == "room"
    assert cfg.object.factory._target_ == "snell_bench.scene.objects.GlassObject.sphere"
    assert cfg.scene.width == 1280 and cfg.scene.height == 720 and cfg.warps.pano_height == 1024
    assert "experiment" not in cfg  # kept out of the defaults list so +experiment=NAME works


def test_unknown_object_factory_and_missing_mesh_are_clear(tmp_path):
    from snell_bench.pipeline import build_object

    cfg = make_cfg(["object=spot", "object.path=/nonexistent/fox.ply", f"output_dir={tmp_path}"])
    with pytest.raises(FileNotFoundError, match="object.path"):
        build_object(cfg.object)
    cfg = make_cfg(["object.factory._target_=snell_bench.scene.objects.GlassObject.torus", f"output_dir={tmp_path}"])
    with pytest.raises(ValueError, match="object.factory"):
        build_object(cfg.object)


@pytest.mark.parametrize("scene,obj", [("living_room", "sphere"), ("landscape", "spot")])
def test_preview_writes_a_glass_composite(tmp_path, scene, obj):
    from snell_bench.experiment.preview import run_preview

    cfg = make_cfg(
        [
            f"scene={scene}",
            f"object={obj}",
            "scene.width=192",
            "scene.height=108",
            "scene.supersample=1",
            "warps.pano_height=64",
            "warps.cache_dir=null",
            f"output_dir={tmp_path}",
        ]
    )
    summary = run_preview(cfg)
    for name in ("I_minus.png", "mask.png", "warp.png", "panorama.png", "composite.png", "preview.png", "summary.json"):
        assert (tmp_path / name).is_file(), name
    assert summary["warps"]["object_pixels"] > 50
    i_minus = np.asarray(Image.open(tmp_path / "I_minus.png"))
    comp = np.asarray(Image.open(tmp_path / "composite.png"))
    mask = np.asarray(Image.open(tmp_path / "mask.png")) > 0
    assert i_minus.shape == comp.shape == (108, 192, 3)
    np.testing.assert_array_equal(comp[~mask], i_minus[~mask])  # unchanged outside the glass
    assert np.abs(comp[mask].astype(int) - i_minus[mask]).mean() > 5  # the glass shows something else
    saved = json.loads((tmp_path / "summary.json").read_text())
    assert saved["warps"]["object_pixels"] == int(mask.sum()) == summary["warps"]["object_pixels"]
    assert saved["object"]["name"] == cfg.object.name and saved["scene"]["name"] == scene
    assert set(saved["timings_s"]) >= {"scene", "warps", "panorama", "composite"}
    # the composite is the Fresnel mix in linear RGB of the warped inputs: recomputed here from the
    # saved PNGs with scipy's bilinear sampling and the sRGB formula (independent of the project's
    # remap and colour code), within 8-bit rounding
    from scipy.ndimage import map_coordinates

    from snell_bench.pipeline import prepare_inputs

    def srgb_to_lin(c):
        return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)

    def lin_to_srgb(c):
        return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.clip(c, 0, None) ** (1 / 2.4) - 0.055)

    def sample(img, xy, wrap=False):
        return np.stack(
            [
                map_coordinates(img[..., c], [xy[:, 1], xy[:, 0]], order=1, mode="grid-wrap" if wrap else "nearest")
                for c in range(3)
            ],
            -1,
        )

    ws = prepare_inputs(cfg, references=False).warps
    pano = np.asarray(Image.open(tmp_path / "panorama.png"), np.float64) / 255
    sel = (
        ws.object_mask
        & np.isfinite(ws.pano_reflection).all(-1)
        & (ws.refraction_valid | np.isfinite(ws.pano_refraction).all(-1))
    )
    valid = ws.refraction_valid[sel][:, None]
    refr = np.where(
        valid,
        sample(i_minus / 255.0, np.nan_to_num(ws.refraction[sel])),
        sample(pano, np.nan_to_num(ws.pano_refraction[sel]), wrap=True),
    )
    refl = sample(pano, ws.pano_reflection[sel], wrap=True)
    R = ws.fresnel[sel][:, None]
    expect = lin_to_srgb(R * srgb_to_lin(refl) + (1 - R) * srgb_to_lin(refr)) * 255
    err = np.abs(comp[sel] - expect)
    assert sel.sum() > 50 and np.median(err) <= 1.0 and np.mean(err) < 2.0, (sel.sum(), np.median(err), err.mean())


def test_experiment_overrides_compose():
    cfg = make_cfg(["+experiment=quick", "output_dir=/tmp/x"])
    assert (cfg.scene.width, cfg.scene.height, cfg.warps.pano_height) == (640, 360, 256)
    assert cfg.object.name == "sphere"  # untouched groups keep their defaults


def test_presets_and_experiments_compose_in_order():
    """An experiment picks the balanced preset; preset=NAME on the command line replaces that
    choice; single keys override both."""
    bal = make_cfg(["+experiment=smoke", "output_dir=/tmp/x"])
    assert (bal.scene.width, bal.scene.height, bal.warps.pano_height, bal.sampler.steps) == (640, 360, 512, 20)
    paper = make_cfg(["+experiment=ablation", "preset=paper", "output_dir=/tmp/x"])
    assert (paper.scene.width, paper.scene.height, paper.warps.pano_height) == (1280, 720, 1024)
    assert paper.grid.methods[0] == "snellcaster"  # the experiment's grid is kept
    fast = make_cfg(["preset=fast", "sampler.steps=6", "output_dir=/tmp/x"])
    assert (fast.sampler.steps, fast.sampler.levels, fast.warps.pano_height, fast.reference.spp) == (6, 3, 256, 98)
    assert make_cfg(["output_dir=/tmp/x"]).scene.width == 1280  # no preset: the schema's paper size
