"""Alignment scores (CLIP, ImageReward) and score_all: offline plumbing and missing-weight reasons."""

import json
import os
import stat
import sys
import textwrap

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np
import pytest
import torch
from tolerances import reordering_tolerance

from snell_bench.metrics import (
    METRIC_NAMES,
    CLIPScore,
    ImageRewardScorer,
    MaskedLPIPS,
    MetricUnavailable,
    load_scorers,
    masked_mae,
    masked_psnr,
    resolve_clip_checkpoint,
    score_all,
)
from snell_bench.metrics.alignment import _to_pil

PROMPT = (
    "A cozy living room with a polished wooden coffee table close to the camera, with a big glass "
    "sphere on top, surrounded by a beige sofa."
)


@pytest.fixture
def images():
    rng = np.random.default_rng(11)
    ref = rng.random((40, 48, 3))
    gen = np.clip(ref + 0.1 * rng.standard_normal(ref.shape), 0, 1)
    mask = np.zeros((40, 48), bool)
    mask[8:30, 10:40] = True
    return gen, ref, mask


# ------------------------------------------------------------------------------------------
# CLIP
# ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def random_clip():
    return CLIPScore(allow_random_weights=True)


class TestCLIPScore:
    def test_random_vit_b16_plumbing(self, random_clip, images):
        gen, _, _ = images
        assert random_clip.weights_source == "random" and not random_clip.model.training
        s = random_clip(gen, PROMPT)
        assert 0.0 <= s <= 100.0
        assert random_clip(gen, PROMPT) == s  # deterministic
        t = torch.from_numpy(gen).permute(2, 0, 1)[None].float()
        assert random_clip(t, PROMPT) == pytest.approx(s, abs=1e-4)

    def test_score_is_100_times_clamped_cosine(self, random_clip, images):
        import open_clip
        import torch.nn.functional as F
        from PIL import Image

        gen, _, _ = images
        pil = Image.fromarray((np.clip(gen, 0, 1) * 255).round().astype(np.uint8))
        tok = open_clip.get_tokenizer("ViT-B-16")
        with torch.no_grad():
            img = random_clip.model.encode_image(random_clip.preprocess(pil)[None])
            txt = random_clip.model.encode_text(tok([PROMPT]))
        cos = (F.normalize(img, dim=-1) * F.normalize(txt, dim=-1)).sum().item()
        # the same embeddings, another float32 formula: the dot product and the two norms are
        # reductions of length n = 512 whose absolute terms sum to at most |img| |txt|, so each
        # formula is within 2 n u of the exact cosine and the two within reordering_tolerance(2 n, 1)
        atol = reordering_tolerance(2 * img.shape[-1], 1.0)
        assert random_clip.cosine(gen, PROMPT) == pytest.approx(cos, abs=atol)
        assert random_clip(gen, PROMPT) == pytest.approx(100 * max(cos, 0.0), abs=100 * atol)

    def test_missing_weights_name_the_config_key(self, tmp_path):
        with pytest.raises(MetricUnavailable, match="metrics.clip_weights"):
            CLIPScore(weights_path=tmp_path / "missing.safetensors")
        with pytest.raises(MetricUnavailable, match="metrics.clip_weights"):
            CLIPScore(cache_dir=tmp_path)  # empty cache
        with pytest.raises(MetricUnavailable, match="metrics.clip_weights"):
            CLIPScore(weights_path=tmp_path)  # a folder without a checkpoint

    def test_checkpoint_resolution(self, tmp_path):
        f = tmp_path / "weights.bin"
        f.write_bytes(b"x")
        assert resolve_clip_checkpoint(f) == str(f)
        d = tmp_path / "folder"
        d.mkdir()
        (d / "open_clip_model.safetensors").write_bytes(b"x")
        (d / "other.bin").write_bytes(b"x")
        assert resolve_clip_checkpoint(d) == str(d / "open_clip_model.safetensors")
        # a Hugging Face cache entry of the (ViT-B-16, openai) pair
        cache = tmp_path / "hf"
        repo = cache / "models--timm--vit_base_patch16_clip_224.openai"
        (repo / "refs").mkdir(parents=True)
        (repo / "refs" / "main").write_text("abc123")
        snap = repo / "snapshots" / "abc123"
        snap.mkdir(parents=True)
        (snap / "open_clip_model.safetensors").write_bytes(b"x")
        assert resolve_clip_checkpoint(None, "ViT-B-16", "openai", cache) == str(snap / "open_clip_model.safetensors")

    def test_weights_are_loaded_from_a_file(self, tmp_path, images):
        import open_clip
        import torch.nn.functional as F

        cfg = {
            "embed_dim": 16,
            "vision_cfg": {"image_size": 32, "layers": 1, "width": 32, "head_width": 16, "patch_size": 16},
            "text_cfg": {"context_length": 77, "vocab_size": 49408, "width": 32, "heads": 2, "layers": 1},
        }
        (tmp_path / "snell-test-tiny-clip.json").write_text(json.dumps(cfg))
        open_clip.add_model_config(tmp_path / "snell-test-tiny-clip.json")
        torch.manual_seed(123)
        model = open_clip.create_model("snell-test-tiny-clip").eval()
        path = tmp_path / "tiny.pt"
        torch.save(model.state_dict(), path)

        scorer = CLIPScore(path, "snell-test-tiny-clip", pretrained_tag=None)
        rand = CLIPScore(model_name="snell-test-tiny-clip", pretrained_tag=None, allow_random_weights=True)
        assert scorer.weights_source == str(path)
        gen, _, _ = images
        with torch.no_grad():
            img = model.encode_image(scorer.preprocess(_to_pil(gen))[None])
            txt = model.encode_text(scorer.tokenizer([PROMPT]))
        cos = F.cosine_similarity(img, txt).item()
        # weights read back from the file may be summed in another order than the ones in memory: the
        # longest reduction is the 16 x 16 x 3 patch embedding, and the scale-free cosine moves by at
        # most the relative error of the two embeddings, 2 n u each
        assert scorer.cosine(gen, PROMPT) == pytest.approx(cos, abs=reordering_tolerance(2 * 16 * 16 * 3, 1.0))
        assert rand.cosine(gen, PROMPT) != pytest.approx(cos, abs=1e-3)


@pytest.mark.weights
def test_clip_with_real_weights():
    """Needs ``SNELL_CLIP_WEIGHTS`` (open_clip ViT-B-16 OpenAI weights) or a Hugging Face cache hit."""
    try:
        clip = CLIPScore(os.environ.get("SNELL_CLIP_WEIGHTS"))
    except MetricUnavailable as e:
        pytest.skip(e.reason)
    red = np.zeros((224, 224, 3))
    red[..., 0] = 1.0
    on_topic = clip(red, "a plain red image")
    off_topic = clip(red, "a photo of a dog playing in the snow")
    assert 10 < on_topic <= 100 and on_topic > off_topic


# ------------------------------------------------------------------------------------------
# ImageReward
# ------------------------------------------------------------------------------------------


def make_fake_python(path, body):
    """An executable standing in for another environment's interpreter (called as ``X -c SRC``)."""
    path.write_text(f"#!{sys.executable}\n" + textwrap.dedent(body))
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


class TestImageReward:
    def test_not_configured(self, images):
        with pytest.raises(MetricUnavailable, match="metrics.image_reward_python"):
            ImageRewardScorer(None)
        with pytest.raises(MetricUnavailable, match="not an executable"):
            ImageRewardScorer("/nonexistent/bin/python")
        gen, ref, mask = images
        result = score_all(gen, ref, mask, PROMPT)
        assert result["metrics"]["image_reward"] is None
        assert result["missing"]["image_reward"].startswith("not configured")
        assert "metrics.image_reward_python" in result["missing"]["image_reward"]

    def test_protocol_with_a_fake_interpreter(self, tmp_path, images):
        log = tmp_path / "request.json"
        fake = make_fake_python(
            tmp_path / "python",
            f"""
            import json, sys
            assert sys.argv[1] == "-c"
            request = json.loads(sys.stdin.read())
            open({str(log)!r}, "w").write(json.dumps(request))
            print("some library chatter")
            print(json.dumps({{"scores": [0.25 * (i + 1) for i, _ in enumerate(request["items"])]}}))
            """,
        )
        scorer = ImageRewardScorer(fake, model="/weights/ImageReward.pt", med_config="/weights/med_config.json")
        a, b = tmp_path / "a.png", tmp_path / "b.png"
        assert scorer.score_paths([(a, "first"), (b, "second")]) == [0.25, 0.5]
        request = json.loads(log.read_text())
        assert request["protocol"] == 1 and request["model"] == "/weights/ImageReward.pt"
        assert request["med_config"] == "/weights/med_config.json"
        assert request["items"] == [
            {"image": str(a.resolve()), "prompt": "first"},
            {"image": str(b.resolve()), "prompt": "second"},
        ]
        gen, _, _ = images
        assert scorer(gen, PROMPT) == 0.25  # arrays go through a temporary PNG
        assert json.loads(log.read_text())["items"][0]["prompt"] == PROMPT

    @pytest.mark.parametrize(
        "body, match",
        [
            ("import sys; sys.stderr.write('boom'); sys.exit(3)", "exit code 3.*boom"),
            ('print(\'{"error": "weights missing"}\')', "weights missing"),
            ("print('{\"scores\": [1.0, 2.0]}')", "answered"),
            ("print('not json')", "exit code 0"),
        ],
    )
    def test_failures_are_unavailable(self, tmp_path, body, match):
        scorer = ImageRewardScorer(make_fake_python(tmp_path / "python", "import sys; sys.stdin.read()\n" + body))
        with pytest.raises(MetricUnavailable, match=match):
            scorer.score_paths([(tmp_path / "a.png", "p")])

    def test_real_worker_with_a_stub_library(self, tmp_path, images):
        lib = tmp_path / "lib" / "ImageReward"
        lib.mkdir(parents=True)
        (lib / "__init__.py").write_text(
            textwrap.dedent(
                """
                from PIL import Image

                class _Model:
                    def eval(self):
                        return self
                    def score(self, prompt, image):
                        print("scoring", image)  # must not corrupt the answer
                        with Image.open(image) as im:
                            return len(prompt) + im.size[0] / 1000

                def load(name="ImageReward-v1.0", device="cpu", download_root=None, med_config=None):
                    print("load checkpoint from", name, med_config)
                    return _Model()
                """
            )
        )
        fake = make_fake_python(
            tmp_path / "python",
            f"""
            import sys
            sys.path.insert(0, {str(lib.parent)!r})
            exec(compile(sys.argv[2], "<worker>", "exec"))
            """,
        )
        gen, ref, mask = images
        scorer = ImageRewardScorer(fake, med_config=tmp_path / "med_config.json")
        assert scorer(gen, "abc") == pytest.approx(3 + 48 / 1000)
        result = score_all(gen, ref, mask, PROMPT, image_reward=scorer)
        assert result["metrics"]["image_reward"] == pytest.approx(len(PROMPT) + 48 / 1000)

    def test_real_worker_without_the_library(self, tmp_path):
        # this environment has no image-reward: the worker answers with the import error
        scorer = ImageRewardScorer(sys.executable)
        with pytest.raises(MetricUnavailable, match="ImageReward"):
            scorer.score_paths([(tmp_path / "a.png", "p")])


@pytest.mark.weights
def test_image_reward_with_a_real_environment(tmp_path):
    """Needs ``SNELL_IMAGE_REWARD_PYTHON`` (an interpreter with image-reward and its weights cached)."""
    try:
        scorer = ImageRewardScorer(os.environ.get("SNELL_IMAGE_REWARD_PYTHON"))
    except MetricUnavailable as e:
        pytest.skip(e.reason)
    img = np.random.default_rng(0).random((256, 256, 3))
    value = scorer(img, "a photo of a glass sphere on a wooden table")
    assert np.isfinite(value) and -5 < value < 5


# ------------------------------------------------------------------------------------------
# score_all
# ------------------------------------------------------------------------------------------


class TestScoreAll:
    def test_nothing_configured(self, images):
        gen, ref, mask = images
        result = score_all(gen, ref, mask, PROMPT)
        assert set(result) == {"metrics", "missing"}
        assert tuple(result["metrics"]) == METRIC_NAMES
        assert result["metrics"]["psnr"] == pytest.approx(masked_psnr(gen, ref, mask))
        assert result["metrics"]["mae"] == pytest.approx(masked_mae(gen, ref, mask))
        assert set(result["missing"]) == {"lpips", "clip", "image_reward"}
        assert all(r.startswith("not configured") for r in result["missing"].values())
        json.dumps(result)  # serialisable as is

    def test_constructor_failures_carry_their_reason(self, images, tmp_path):
        gen, ref, mask = images
        scorers = load_scorers({"lpips_weights": str(tmp_path / "no.pth"), "clip_weights": str(tmp_path / "no.bin")})
        assert all(isinstance(s, MetricUnavailable) for s in scorers.values())
        result = score_all(gen, ref, mask, PROMPT, **scorers)
        assert "metrics.lpips_weights" in result["missing"]["lpips"]
        assert "metrics.clip_weights" in result["missing"]["clip"]
        assert "metrics.image_reward_python" in result["missing"]["image_reward"]
        assert result["metrics"]["psnr"] is not None

    def test_everything_configured(self, images, random_clip, tmp_path):
        gen, ref, mask = images
        lp = MaskedLPIPS(allow_random_backbone=True)
        fake = make_fake_python(
            tmp_path / "python",
            """
            import json, sys
            request = json.loads(sys.stdin.read())
            print(json.dumps({"scores": [float(len(request["items"][0]["image"]))]}))
            """,
        )
        png = tmp_path / "generated.png"
        result = score_all(
            gen,
            ref,
            mask,
            PROMPT,
            lpips=lp,
            clip=random_clip,
            image_reward=ImageRewardScorer(fake),
            generated_path=png,
        )
        assert result["missing"] == {}
        assert result["metrics"]["lpips"] == pytest.approx(lp(gen, ref, mask))
        assert result["metrics"]["clip"] == pytest.approx(random_clip(gen, PROMPT))
        assert result["metrics"]["image_reward"] == float(len(str(png.resolve())))
        # an empty mask removes the masked metrics only
        empty = score_all(gen, ref, np.zeros_like(mask), PROMPT, lpips=lp, clip=random_clip)
        assert empty["metrics"]["psnr"] is None and empty["metrics"]["lpips"] is None
        assert "empty mask" in empty["missing"]["lpips"]
        assert empty["metrics"]["clip"] is not None
