"""Monocular depth estimators: the tiny random-weight Depth Pro / Depth Anything V2 (CPU, offline),
loading from local files, MoGe-2's output conversion against a fake ``moge.model.v2``, and the
conf/depth/ group; real checkpoints only with -m weights."""

import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")

import copy
import importlib
import importlib.util
import inspect
import math
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from omegaconf import OmegaConf

import snell_bench
from snell_bench.models.depth import (
    DepthEstimate,
    DepthEstimator,
    MoGe2Depth,
    TransformersDepth,
    resolve_depth_device,
    tiny_depth_anything,
    tiny_depth_pro,
)
from snell_bench.models.errors import DeviceNotAvailableError, WeightsNotFoundError
from snell_bench.scene.camera import Camera

CONF_DEPTH = Path(snell_bench.__file__).parent / "conf" / "depth"
NOT_CACHED = "snell-bench-tests/no-such-depth-model"


def rand_image(h, w, seed=0) -> np.ndarray:
    return np.random.default_rng(seed).random((h, w, 3), dtype=np.float32)


@pytest.fixture(scope="module")
def depth_pro() -> TransformersDepth:
    return tiny_depth_pro(seed=0)


@pytest.fixture(scope="module")
def depth_anything() -> TransformersDepth:
    return tiny_depth_anything(seed=0)


@pytest.fixture(params=["depth_pro", "depth_anything"])
def tiny(request) -> TransformersDepth:
    return request.getfixturevalue(request.param)


# ---------------------------------------------------------------------------------------- interface


class TestDepthEstimate:
    def test_casts_and_validates(self):
        est = DepthEstimate(depth=np.ones((4, 6)), intrinsics=[5, 5, 2.5, 1.5])
        assert est.depth.dtype == np.float32 and est.intrinsics == (5.0, 5.0, 2.5, 1.5)
        assert all(isinstance(v, float) for v in est.intrinsics)
        with pytest.raises(ValueError, match=r"\(H, W\)"):
            DepthEstimate(depth=np.ones((4, 6, 1)))
        with pytest.raises(ValueError, match="fx, fy, cx, cy"):
            DepthEstimate(depth=np.ones((4, 6)), intrinsics=(1.0, 2.0, 3.0))

    def test_camera(self):
        assert DepthEstimate(depth=np.ones((4, 6))).camera() is None
        cam = DepthEstimate(depth=np.ones((4, 6)), intrinsics=(5.0, 6.0, 2.5, 1.5)).camera()
        assert (cam.width, cam.height) == (6, 4)
        np.testing.assert_allclose(cam.K, [[5, 0, 2.5], [0, 6, 1.5], [0, 0, 1]])


def test_device():
    assert resolve_depth_device(None) == torch.device("cpu")
    assert resolve_depth_device("cpu") == torch.device("cpu")
    assert resolve_depth_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
def test_cuda_missing_names_the_config_key():
    with pytest.raises(DeviceNotAvailableError, match="depth.device"):
        resolve_depth_device("cuda")


# ---------------------------------------------------------------------------------------- tiny models


class TestTinyModels:
    def test_protocol_and_names(self, depth_pro, depth_anything):
        assert isinstance(depth_pro, DepthEstimator) and isinstance(depth_anything, DepthEstimator)
        assert depth_pro.name == "tiny_depth_pro" and depth_anything.name == "tiny_depth_anything"
        for est in (depth_pro, depth_anything):
            assert not est.model.training and est.device.type == "cpu"
            assert all(not p.requires_grad for p in est.model.parameters())

    def test_depth_at_input_size(self, tiny):
        out = tiny(rand_image(64, 96))
        assert isinstance(out, DepthEstimate)
        assert out.depth.shape == (64, 96) and out.depth.dtype == np.float32
        d = out.depth
        assert not np.isinf(d).any()
        assert np.isfinite(d).mean() > 0.99
        assert np.nanmin(d) > 0
        assert np.nanstd(d) > 0  # the image shows through

    def test_depth_anything_is_metric_in_range(self, depth_anything):
        d = depth_anything(rand_image(64, 96)).depth
        assert depth_anything.model.config.depth_estimation_type == "metric"
        assert np.nanmax(d) <= depth_anything.model.config.max_depth * 1.05  # bicubic may overshoot a little
        assert depth_anything(rand_image(64, 96)).intrinsics is None

    def test_deterministic_for_the_seed(self, tiny):
        factory = tiny_depth_pro if tiny.name == "tiny_depth_pro" else tiny_depth_anything
        img = rand_image(64, 96, seed=3)
        state = torch.random.get_rng_state()
        again = factory(seed=0)
        assert torch.equal(state, torch.random.get_rng_state())  # the caller's RNG is untouched
        a, b = tiny(img), again(img)
        np.testing.assert_array_equal(a.depth, b.depth)
        assert a.intrinsics == b.intrinsics
        other = factory(seed=1)(img)
        assert np.nanmax(np.abs(other.depth - a.depth)) > 1e-3

    def test_other_image_sizes_are_resized_by_the_processor(self, tiny):
        img = rand_image(50, 77, seed=1)
        pixels = tiny.processor(images=torch.from_numpy(img).permute(2, 0, 1), return_tensors="pt", do_rescale=False)
        assert tuple(pixels["pixel_values"].shape[-2:]) != (50, 77)
        out = tiny(img)
        assert out.depth.shape == (50, 77) and np.isfinite(out.depth).mean() > 0.99
        if out.intrinsics is not None:
            assert out.intrinsics[2:] == (38.0, 24.5)

    def test_bad_images(self, depth_anything):
        with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
            depth_anything(np.zeros((8, 8), np.float32))
        with pytest.raises(TypeError, match="float"):
            depth_anything(np.zeros((8, 8, 3), np.uint8))
        with pytest.raises(ValueError, match="non-finite"):
            depth_anything(np.full((8, 8, 3), np.nan, np.float32))


class TestDepthProGeometry:
    def test_intrinsics_match_the_field_of_view(self, depth_pro):
        H, W = 48, 80
        img = rand_image(H, W, seed=2)
        out = depth_pro(img)
        with torch.no_grad():
            pixels = depth_pro.processor(
                images=torch.from_numpy(img).permute(2, 0, 1), return_tensors="pt", do_rescale=False
            )
            raw = depth_pro.model(**pixels)
        fov = float(raw.field_of_view[0])
        assert 0 < fov < 180
        f = 0.5 * W / math.tan(math.radians(fov) / 2)
        fx, fy, cx, cy = out.intrinsics
        assert fx == pytest.approx(f, rel=1e-5) and fy == fx
        assert (cx, cy) == ((W - 1) / 2, (H - 1) / 2)
        np.testing.assert_allclose(out.camera().K, Camera.from_fov(W, H, fov).K, rtol=1e-5)
        assert out.camera().fov_x_deg == pytest.approx(fov, rel=1e-5)

    def test_depth_is_focal_over_width_times_canonical_inverse_depth(self, depth_pro):
        """depth = f / (W * canonical inverse depth), interpolated (as inverse depth) to (H, W)."""
        H, W = 48, 80
        img = rand_image(H, W, seed=2)
        out = depth_pro(img)
        with torch.no_grad():
            pixels = depth_pro.processor(
                images=torch.from_numpy(img).permute(2, 0, 1), return_tensors="pt", do_rescale=False
            )
            raw = depth_pro.model(**pixels)
        inverse = raw.predicted_depth[None] * W / out.intrinsics[0]
        inverse = F.interpolate(inverse, size=(H, W), mode="bilinear", align_corners=False)[0, 0]
        expected = (1.0 / inverse.clamp(1e-4, 1e4)).numpy()
        np.testing.assert_allclose(out.depth, expected, rtol=1e-5)

    def test_invalid_field_of_view_gives_no_depth(self):
        est = tiny_depth_pro(seed=0)
        with torch.no_grad():
            est.model.fov_model.head.layers[-1].bias.fill_(500.0)
        out = est(rand_image(32, 48))
        assert out.intrinsics is None and out.depth.shape == (32, 48) and np.isnan(out.depth).all()

    def test_without_fov_head_is_refused(self, depth_pro):
        from transformers import DepthProForDepthEstimation

        model = DepthProForDepthEstimation(depth_pro.model.config, use_fov_model=False)
        with pytest.raises(ValueError, match="field-of-view"):
            TransformersDepth(model, depth_pro.processor)


def test_non_positive_depth_is_nan():
    est = tiny_depth_anything(seed=0)
    est.model.head.max_depth = -20.0
    assert np.isnan(est(rand_image(28, 42)).depth).all()


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
@pytest.mark.parametrize("factory", [tiny_depth_pro, tiny_depth_anything])
def test_tiny_on_cuda_matches_cpu(factory):
    img = rand_image(48, 64, seed=7)
    cpu, gpu = factory(seed=0)(img), factory(seed=0, device="cuda")(img)
    assert gpu.depth.dtype == np.float32 and gpu.depth.shape == (48, 64)
    np.testing.assert_allclose(gpu.depth, cpu.depth, rtol=1e-2, atol=1e-3)
    assert (gpu.intrinsics is None) == (cpu.intrinsics is None)
    if cpu.intrinsics is not None:
        np.testing.assert_allclose(gpu.intrinsics, cpu.intrinsics, rtol=1e-3)


# ---------------------------------------------------------------------------------------- loading


class TestLoading:
    @pytest.mark.parametrize("name", ["depth_pro", "depth_anything"])
    def test_from_a_local_folder(self, request, tmp_path, name):
        # in float64 (a copy: the module's fixture stays float32), so that the weights read back and
        # the ones in memory give the same network outputs to float64 rounding (~1e-15) whatever
        # order the kernels sum in; the processor and the post-processing run in float32 on the same
        # inputs, and the outputs rounded to float32 differ at most by one float32 step (2 * 2**-24
        # relative) in the inverse depth and in the field of view, which the interpolation (weights
        # summing to 1, absolute sum <= 1.25 for bicubic) and the focal length (d ln f / d fov =
        # 1 / sin(fov) ~ 1.2 at 60 degrees) carry to at most 5 * 2**-24 ~ 3e-7 relative in the depth
        tiny = request.getfixturevalue(name)
        tiny = TransformersDepth(copy.deepcopy(tiny.model), tiny.processor, dtype=torch.float64, name=tiny.name)
        tiny.model.save_pretrained(tmp_path)
        tiny.processor.save_pretrained(tmp_path)
        loaded = TransformersDepth.from_pretrained(tmp_path, device="cpu", dtype=torch.float64)
        assert loaded.name == {"depth_pro": "depth_pro", "depth_anything": "depth_anything_v2"}[name]
        assert type(loaded.processor) is type(tiny.processor) and not loaded.model.training
        assert loaded.model.dtype == torch.float64
        img = rand_image(40, 60, seed=4)
        a, b = loaded(img), tiny(img)
        np.testing.assert_allclose(a.depth, b.depth, rtol=1e-6)
        assert (a.intrinsics is None) == (b.intrinsics is None)
        if b.intrinsics is not None:
            assert a.intrinsics == pytest.approx(b.intrinsics, rel=1e-6)

    def test_relative_depth_anything_is_refused(self, depth_anything, tmp_path):
        config = depth_anything.model.config.__class__.from_dict(depth_anything.model.config.to_dict())
        config.depth_estimation_type = "relative"
        config.save_pretrained(tmp_path)  # the config only: refused before any weight is read
        with pytest.raises(ValueError, match="relative") as err:
            TransformersDepth.from_pretrained(tmp_path)
        assert "metric" in str(err.value) and "Metric-Indoor" in str(err.value)
        from transformers import DepthAnythingForDepthEstimation

        with pytest.raises(ValueError, match="relative"):
            TransformersDepth(DepthAnythingForDepthEstimation(config), depth_anything.processor)

    def test_other_architectures_are_refused(self, tmp_path):
        from transformers import Dinov2Config

        Dinov2Config(hidden_size=8, num_hidden_layers=1, num_attention_heads=1).save_pretrained(tmp_path)
        with pytest.raises(ValueError, match="not a supported depth estimator"):
            TransformersDepth.from_pretrained(tmp_path)

    @pytest.mark.parametrize("path", ["/no/such/folder", NOT_CACHED, "not a path or id", None])
    def test_missing_weights_name_the_config_key(self, path):
        with pytest.raises(WeightsNotFoundError, match="depth.path") as err:
            TransformersDepth.from_pretrained(path)
        text = str(err.value)
        assert "Hugging Face cache" in text and "local folder" in text and "never downloaded" in text
        assert isinstance(err.value, RuntimeError)

    def test_folder_without_weights(self, depth_pro, tmp_path):
        depth_pro.model.config.save_pretrained(tmp_path)
        with pytest.raises(WeightsNotFoundError, match="depth.path"):
            TransformersDepth.from_pretrained(tmp_path)


# ---------------------------------------------------------------------------------------- MoGe-2


MOGE_INFER_PARAMS = [
    "self",
    "image",
    "num_tokens",
    "resolution_level",
    "force_projection",
    "apply_mask",
    "fov_x",
    "use_fp16",
]


class FakeMoGeModel(torch.nn.Module):
    """Mimics ``moge.model.v2.MoGeModel`` (dlr-moge 2.0.0): ``from_pretrained`` and ``infer`` with the
    same signatures and output conventions (normalised intrinsics with the centre of pixel ``i`` at
    ``(i + 0.5) / W``, ``inf`` depth outside the mask, points from depth and intrinsics)."""

    loaded_from: list = []
    principal_point = (0.5, 0.5)
    focal = (0.9, 1.6)

    def __init__(self):
        super().__init__()
        self.anchor = torch.nn.Parameter(torch.zeros(1))
        self.calls = []

    @classmethod
    def from_pretrained(cls, pretrained_model_name_or_path, model_kwargs=None, **hf_kwargs):
        cls.loaded_from.append(pretrained_model_name_or_path)
        return cls()

    @torch.inference_mode()
    def infer(
        self,
        image,
        num_tokens=None,
        resolution_level=9,
        force_projection=True,
        apply_mask=True,
        fov_x=None,
        use_fp16=True,
    ):
        self.calls.append(dict(image=image.clone(), num_tokens=num_tokens, level=resolution_level, fp16=use_fp16))
        omit_batch = image.dim() == 3
        if omit_batch:
            image = image[None]
        B, _, H, W = image.shape
        yy, xx = torch.meshgrid(
            torch.arange(H, dtype=torch.float32), torch.arange(W, dtype=torch.float32), indexing="ij"
        )
        depth = (1.5 + yy / H + 0.5 * image[:, 0]).float()
        mask = torch.ones(B, H, W, dtype=torch.bool)
        mask[:, : H // 4, : W // 3] = False
        fx, fy = self.focal
        cx, cy = self.principal_point
        K = torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]).expand(B, 3, 3)
        u, v = (xx + 0.5) / W, (yy + 0.5) / H  # utils3d's uv_map
        points = torch.stack([(u - cx) / fx * depth, (v - cy) / fy * depth, depth], dim=-1)
        points = torch.where(mask[..., None], points, torch.inf)
        depth = torch.where(mask, depth, torch.inf)
        out = {"points": points, "intrinsics": K, "depth": depth, "mask": mask, "normal": torch.zeros_like(points)}
        return {k: v.squeeze(0) for k, v in out.items()} if omit_batch else out


@pytest.fixture
def fake_moge(monkeypatch):
    v2 = types.ModuleType("moge.model.v2")
    v2.MoGeModel = FakeMoGeModel
    model = types.ModuleType("moge.model")
    model.v2 = v2
    root = types.ModuleType("moge")
    root.model = model
    for name, mod in (("moge", root), ("moge.model", model), ("moge.model.v2", v2)):
        monkeypatch.setitem(sys.modules, name, mod)
    monkeypatch.setattr(FakeMoGeModel, "loaded_from", [])
    return FakeMoGeModel


class TestMoGe2:
    def test_fake_mimics_the_real_signature(self):
        """The parameters of the real ``infer`` (dlr-moge 2.0.0), compared with it when it is installed."""
        params = list(inspect.signature(FakeMoGeModel.infer).parameters)
        assert params == MOGE_INFER_PARAMS
        if importlib.util.find_spec("moge") is not None:
            from moge.model.v2 import MoGeModel

            assert list(inspect.signature(MoGeModel.infer).parameters) == MOGE_INFER_PARAMS

    def test_missing_package_names_the_extra(self, monkeypatch):
        for name in ("moge", "moge.model", "moge.model.v2"):
            monkeypatch.setitem(sys.modules, name, None)
        with pytest.raises(ImportError) as err:
            MoGe2Depth.from_pretrained("Ruicheng/moge-2-vitl-normal")
        text = str(err.value)
        assert "dlr-moge" in text and "snell_bench[depth]" in text and "EXTRAS=test,depth" in text

    @pytest.mark.parametrize("principal_point", [(0.5, 0.5), (0.6, 0.45)])
    def test_conversion(self, fake_moge, monkeypatch, tmp_path, principal_point):
        monkeypatch.setattr(fake_moge, "principal_point", principal_point)
        (tmp_path / "model.pt").write_bytes(b"")
        est = MoGe2Depth.from_pretrained(tmp_path / "model.pt", device="cpu", resolution_level=3)
        assert isinstance(est, DepthEstimator) and est.name == "moge2"
        H, W = 40, 64
        img = rand_image(H, W, seed=5)
        out = est(img)
        call = est.model.calls[-1]
        assert call["image"].shape == (3, H, W) and call["image"].dtype == torch.float32
        torch.testing.assert_close(call["image"], torch.from_numpy(img).permute(2, 0, 1))
        assert (call["level"], call["num_tokens"], call["fp16"]) == (3, None, False)

        fx_n, fy_n = fake_moge.focal
        cx_n, cy_n = principal_point
        fx, fy, cx, cy = out.intrinsics
        assert fx == pytest.approx(fx_n * W) and fy == pytest.approx(fy_n * H)
        assert cx == pytest.approx(cx_n * W - 0.5) and cy == pytest.approx(cy_n * H - 0.5)
        if principal_point == (0.5, 0.5):
            assert (cx, cy) == pytest.approx(((W - 1) / 2, (H - 1) / 2))

        raw = est.model.infer(torch.from_numpy(img).permute(2, 0, 1))
        mask = raw["mask"].numpy()
        assert out.depth.shape == (H, W) and out.depth.dtype == np.float32
        assert np.isnan(out.depth[~mask]).all() and (~mask).any()
        np.testing.assert_allclose(out.depth[mask], raw["depth"].numpy()[mask], rtol=1e-6)
        # back-projecting integer pixel centres with the converted intrinsics gives MoGe's points
        pts = raw["points"].numpy()
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
        z = out.depth.astype(np.float64)
        mine = np.stack([(xx - cx) / fx * z, (yy - cy) / fy * z, z], axis=-1)
        np.testing.assert_allclose(mine[mask], pts[mask], rtol=1e-5, atol=1e-6)

    def test_checkpoint_paths(self, fake_moge, tmp_path):
        (tmp_path / "model.pt").write_bytes(b"")
        MoGe2Depth.from_pretrained(tmp_path)  # a folder holding model.pt
        MoGe2Depth.from_pretrained(str(tmp_path / "model.pt"), num_tokens=1200)
        assert fake_moge.loaded_from == [str(tmp_path / "model.pt")] * 2

    def test_edge_rtol_cuts_the_ring_around_the_mask(self, fake_moge, tmp_path):
        """A flat grey image: the fake's depth 1.5 + y / H changes by < 1 % per pixel, so rtol 0.1
        cuts only the valid pixels next to its mask's hole (the top-left H/4 x W/3 block)."""
        (tmp_path / "model.pt").write_bytes(b"")
        H, W = 24, 36
        img = np.full((H, W, 3), 0.5, np.float32)
        plain = MoGe2Depth.from_pretrained(tmp_path, device="cpu")(img).depth
        cut = MoGe2Depth.from_pretrained(tmp_path, device="cpu", edge_rtol=0.1)(img).depth
        ring = np.zeros((H, W), bool)
        ring[: H // 4 + 1, : W // 3 + 1] = True
        ring[: H // 4, : W // 3] = False
        assert np.array_equal(np.isnan(cut), np.isnan(plain) | ring)
        assert np.array_equal(cut[~np.isnan(cut)], plain[~np.isnan(cut)])
        with pytest.raises(ValueError, match="depth.edge_rtol"):
            MoGe2Depth.from_pretrained(tmp_path, edge_rtol=-1.0)

    @pytest.mark.parametrize("kind", ["empty folder", "no such path", "not cached", "not set"])
    def test_missing_weights_name_the_config_key(self, fake_moge, tmp_path, kind):
        paths = {"empty folder": tmp_path, "no such path": tmp_path / "nothing.pt", "not cached": NOT_CACHED}
        path = paths.get(kind)
        with pytest.raises(WeightsNotFoundError, match="depth.path") as err:
            MoGe2Depth.from_pretrained(path)
        assert "model.pt" in str(err.value) and "Hugging Face cache" in str(err.value)
        assert fake_moge.loaded_from == []


def test_real_moge_code_with_random_weights(tmp_path):
    """The installed MoGe-2 code (optional extra ``depth``) on a small random-weight model: the
    converted intrinsics back-project integer pixel centres onto MoGe's own points."""
    v2 = pytest.importorskip("moge.model.v2")
    config = dict(
        encoder=dict(backbone="dinov2_vits14", intermediate_layers=4, dim_out=32),
        neck=dict(dim_in=[34, 2, 2, 2, 2], dim_res_blocks=[32] * 5, dim_out=[None] * 5, resamplers=["bilinear"] * 4),
        points_head=dict(
            dim_in=[32] * 5, dim_res_blocks=[32] * 5, dim_out=[None] * 4 + [3], resamplers=["bilinear"] * 4
        ),
        mask_head=dict(dim_in=[32] * 5, dim_res_blocks=[32] * 5, dim_out=[None] * 4 + [1], resamplers=["bilinear"] * 4),
        scale_head=dict(dims=[384, 32, 1]),
        remap_output="exp",
        num_tokens_range=[60, 120],
    )
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        model = v2.MoGeModel(**config)
    torch.save({"model_config": config, "model": model.state_dict()}, tmp_path / "model.pt")
    est = MoGe2Depth.from_pretrained(tmp_path, device="cpu", resolution_level=0)
    H, W = 64, 96
    img = rand_image(H, W, seed=6)
    out = est(img)
    raw = est.model.infer(torch.from_numpy(img).permute(2, 0, 1), resolution_level=0, use_fp16=False)
    mask = raw["mask"].numpy()
    assert out.depth.shape == (H, W) and out.depth.dtype == np.float32 and mask.any()
    assert np.isnan(out.depth[~mask]).all()
    fx, fy, cx, cy = out.intrinsics
    assert (cx, cy) == pytest.approx(((W - 1) / 2, (H - 1) / 2))
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    z = out.depth.astype(np.float64)
    mine = np.stack([(xx - cx) / fx * z, (yy - cy) / fy * z, z], axis=-1)
    pts = raw["points"].numpy()
    np.testing.assert_allclose(mine[mask], pts[mask], rtol=1e-4, atol=1e-5 * np.abs(pts[mask]).max())


# ---------------------------------------------------------------------------------------- conf/depth


EXPECTED_CONFIGS = {
    "none": None,
    "file": None,
    "moge2": "snell_bench.models.depth.MoGe2Depth.from_pretrained",
    "depth_pro": "snell_bench.models.depth.TransformersDepth.from_pretrained",
    "depth_anything_v2": "snell_bench.models.depth.TransformersDepth.from_pretrained",
    "tiny_depth_pro": "snell_bench.models.depth.tiny_depth_pro",
    "tiny_depth_anything": "snell_bench.models.depth.tiny_depth_anything",
}


def _locate(target: str):
    module, _, attr = target.rpartition(".")
    try:
        return getattr(importlib.import_module(module), attr)
    except ModuleNotFoundError:  # Class.method
        module, _, cls = module.rpartition(".")
        return getattr(getattr(importlib.import_module(module), cls), attr)


class TestConfigGroup:
    def test_files(self):
        assert sorted(p.stem for p in CONF_DEPTH.glob("*.yaml")) == sorted(EXPECTED_CONFIGS)

    @pytest.mark.parametrize("name", sorted(EXPECTED_CONFIGS))
    def test_loads_and_target_imports(self, name):
        cfg = OmegaConf.load(CONF_DEPTH / f"{name}.yaml")
        assert cfg.name == name
        assert list(cfg.defaults) == ["base_depth", "_self_"]
        target = EXPECTED_CONFIGS[name]
        if target is None:
            assert cfg.estimator is None
            return
        assert cfg.estimator._target_ == target and callable(_locate(target))
        node = OmegaConf.to_container(cfg.estimator)
        assert node["device"] == "${..device}"
        if name.startswith("tiny_"):
            assert "path" not in node
        else:
            assert node["path"] == "${..path}" and isinstance(cfg.path, str)
        params = inspect.signature(_locate(target)).parameters
        assert set(node) - {"_target_"} <= set(params)

    def test_real_checkpoint_ids(self):
        ids = {n: OmegaConf.load(CONF_DEPTH / f"{n}.yaml").path for n in ("moge2", "depth_pro", "depth_anything_v2")}
        assert ids == {
            "moge2": "Ruicheng/moge-2-vitl-normal",
            "depth_pro": "apple/DepthPro-hf",
            "depth_anything_v2": "depth-anything/Depth-Anything-V2-Metric-Indoor-Large-hf",
        }

    @pytest.mark.parametrize("name", ["tiny_depth_pro", "tiny_depth_anything"])
    def test_tiny_instantiate(self, name):
        from hydra.utils import instantiate

        cfg = OmegaConf.merge({"path": None, "device": "cpu"}, OmegaConf.load(CONF_DEPTH / f"{name}.yaml"))
        est = instantiate(cfg.estimator)
        assert est.name == name and est(rand_image(32, 48)).depth.shape == (32, 48)


# ---------------------------------------------------------------------------------------- real weights


def _real_device() -> str:
    return os.environ.get("SNELL_BENCH_DEPTH_DEVICE", "auto")


@pytest.fixture(scope="module")
def procedural_room():
    from snell_bench.scene.procedural import ProceduralScene

    scene = ProceduralScene("room", 0)
    return scene, scene.render(512, 384)


def _check_against_truth(out: DepthEstimate, render, scene, *, fov_tolerance_deg: float | None):
    assert out.depth.shape == render.depth.shape and out.depth.dtype == np.float32
    valid = np.isfinite(out.depth)
    assert valid.mean() > 0.9 and (out.depth[valid] > 0).all()
    ratio = np.median(out.depth[valid] / render.depth[valid])
    assert 1 / 3 < ratio < 3, ratio
    if fov_tolerance_deg is not None:
        assert abs(out.camera().fov_x_deg - scene.fov_x_deg) < fov_tolerance_deg


@pytest.mark.weights
@pytest.mark.parametrize(
    "env, default",
    [
        ("SNELL_BENCH_DEPTH_PRO_PATH", "apple/DepthPro-hf"),
        ("SNELL_BENCH_DEPTH_ANYTHING_PATH", "depth-anything/Depth-Anything-V2-Metric-Indoor-Large-hf"),
    ],
)
def test_real_transformers_checkpoint(procedural_room, env, default):
    try:
        est = TransformersDepth.from_pretrained(os.environ.get(env, default), device=_real_device())
    except WeightsNotFoundError as err:
        pytest.skip(str(err))
    scene, render = procedural_room
    out = est(render.image)
    _check_against_truth(out, render, scene, fov_tolerance_deg=15.0 if est.kind == "depth_pro" else None)
    assert (out.intrinsics is None) == (est.kind == "depth_anything")


@pytest.mark.weights
def test_real_moge2(procedural_room):
    try:
        est = MoGe2Depth.from_pretrained(
            os.environ.get("SNELL_BENCH_MOGE2_PATH", "Ruicheng/moge-2-vitl-normal"), device=_real_device()
        )
    except (ImportError, WeightsNotFoundError) as err:
        pytest.skip(str(err))
    scene, render = procedural_room
    _check_against_truth(est(render.image), render, scene, fov_tolerance_deg=15.0)
