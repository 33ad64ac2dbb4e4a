"""Text-image alignment scores (CLIP score, ImageReward) and :func:`score_all`.

Convention:
    - Images: torch float tensors ``(1, 3, H, W)`` / ``(3, H, W)`` or numpy ``(H, W, 3)``, sRGB in
      [0, 1] (``uint8`` read as ``value / 255``), a ``PIL.Image`` or an image file path. Both scores see
      the FULL image (no mask) and the text exactly as given: the caller picks the full prompt or the
      object phrase (config key ``metrics.clip_text``).
    - CLIP score ``= 100 * max(cos(image embedding, text embedding), 0)`` with open_clip ViT-B/16 and
      the model's own evaluation preprocessing (resize the short side to 224, centre crop, normalise);
      prompts longer than the 77-token context are truncated by the tokenizer.
    - ImageReward runs in a separate interpreter (config key ``metrics.image_reward_python``) over a
      JSON protocol on stdin/stdout (see :data:`IMAGE_REWARD_WORKER`).
    - Weights are never downloaded. A scorer whose weights or program are missing raises
      :class:`~snell_bench.metrics.functional.MetricUnavailable` naming the config key to set;
      :func:`score_all` reports it as ``None`` with the reason.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypedDict

import numpy as np
import torch

from .fidelity import MaskedLPIPS
from .functional import MetricUnavailable, check_protocol
from .registry import BUILTIN_METRICS, ScoreInputs, compute_metrics, metrics_for

__all__ = [
    "AUTHORS_ONLY_METRICS",
    "CLIP_DEFAULT",
    "IMAGE_REWARD_WORKER",
    "METRIC_NAMES",
    "CLIPScore",
    "ImageRewardScorer",
    "ScoreResult",
    "default_clip_checkpoint",
    "metric_names",
    "resolve_clip_checkpoint",
    "score_all",
]

#: The metrics :func:`score_all` reports under ``metrics.protocol=paper``, in order (the built-in
#: metrics of :mod:`~snell_bench.metrics.registry` scored against the reference and the prompt).
METRIC_NAMES = tuple(m.name for m in BUILTIN_METRICS if "paper" in m.protocols and "true_render" not in m.needs)

#: The metrics only the authors' evaluation has (``lpips_box``: their bounding-box LPIPS).
AUTHORS_ONLY_METRICS = tuple(m.name for m in BUILTIN_METRICS if m.protocols == ("authors",))


def metric_names(protocol: str = "paper") -> tuple[str, ...]:
    """The metrics :func:`score_all` reports under ``protocol``, in order: :data:`METRIC_NAMES`, and
    under ``"authors"`` also ``lpips_box`` (after ``lpips``). Under ``"paper"`` ``lpips_box`` is not
    reported at all (the paper has no such metric)."""
    return tuple(m.name for m in metrics_for(protocol) if "true_render" not in m.needs)


def _to_pil(image: Any):
    """An image (tensor, array, PIL image or path) as an RGB ``PIL.Image``."""
    from PIL import Image

    if isinstance(image, (str, os.PathLike)):
        with Image.open(image) as im:
            return im.convert("RGB")
    if isinstance(image, Image.Image):
        return image.convert("RGB")
    if isinstance(image, torch.Tensor):
        t = image.detach().cpu()
        if t.ndim == 4:
            if t.shape[0] != 1:
                raise ValueError(f"expected one image, got a batch of {t.shape[0]}")
            t = t[0]
        if t.ndim != 3 or t.shape[0] not in (1, 3):
            raise ValueError(f"expected (1, 3, H, W) or (3, H, W), got {tuple(image.shape)}")
        a = t.permute(1, 2, 0).numpy()
    else:
        a = np.asarray(image)
        if a.ndim == 2:
            a = a[..., None]
        if a.ndim != 3 or a.shape[-1] not in (1, 3):
            raise ValueError(f"expected a numpy (H, W, 3) image, got {a.shape}")
    if a.dtype != np.uint8:
        a = np.round(np.clip(a.astype(np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)
    if a.shape[-1] == 1:
        a = np.repeat(a, 3, axis=-1)
    return Image.fromarray(np.ascontiguousarray(a), mode="RGB")


# --------------------------------------------------------------------------------------------
# CLIP score
# --------------------------------------------------------------------------------------------

_CLIP_FILE_NAMES = (
    "open_clip_model.safetensors",
    "open_clip_pytorch_model.safetensors",
    "open_clip_pytorch_model.bin",
    "open_clip_pytorch_model.pth",
    "model.safetensors",
    "pytorch_model.bin",
)


def resolve_clip_checkpoint(
    weights_path: str | os.PathLike | None,
    model_name: str = "ViT-B-16",
    pretrained_tag: str | None = "openai",
    cache_dir: str | os.PathLike | None = None,
) -> str:
    """The local open_clip checkpoint file to load, without any network access.

    Convention:
        ``weights_path``: a checkpoint file, or a folder holding one (``open_clip_model.safetensors``,
        ``open_clip_pytorch_model.bin``, ...). ``None``: the Hugging Face cache entry of the
        ``(model_name, pretrained_tag)`` pair (``cache_dir`` overrides the cache folder), then the
        URL-download cache of open_clip (``~/.cache/clip``). Nothing found: :class:`MetricUnavailable`
        naming ``metrics.clip_weights``.
    """
    hint = f"set {CLIPScore.CONFIG_KEY} to an open_clip {model_name} checkpoint file or folder"
    if weights_path is not None:
        p = Path(weights_path).expanduser()
        if p.is_file():
            return str(p)
        if p.is_dir():
            for name in _CLIP_FILE_NAMES:
                if (p / name).is_file():
                    return str(p / name)
            found = sorted(p.glob("*.safetensors")) + sorted(p.glob("*.bin")) + sorted(p.glob("*.pt"))
            if len(found) == 1:
                return str(found[0])
        raise MetricUnavailable(f"CLIP weights not found at {p}: {hint}")

    import open_clip

    cfg = open_clip.get_pretrained_cfg(model_name, pretrained_tag) if pretrained_tag else {}
    hub = (cfg or {}).get("hf_hub", "")
    if hub:
        from huggingface_hub import try_to_load_from_cache

        repo_id, file_name = os.path.split(hub)
        candidates = [file_name] if file_name else ["open_clip_model.safetensors", "open_clip_pytorch_model.bin"]
        for name in candidates:
            hit = try_to_load_from_cache(repo_id, name, cache_dir=None if cache_dir is None else str(cache_dir))
            if isinstance(hit, str) and os.path.isfile(hit):
                return hit
    url = (cfg or {}).get("url", "")
    if url:
        hit = Path(cache_dir or Path("~/.cache/clip").expanduser()) / os.path.basename(url)
        if hit.is_file():
            return str(hit)
    where = f"the Hugging Face cache ({hub.rstrip('/')})" if hub else "the local caches"
    raise MetricUnavailable(
        f"no CLIP weights for {model_name} ({pretrained_tag}) on this machine: {hint}, or place them in {where}"
    )


#: Where :func:`resolve_clip_checkpoint` finds ViT-B-16 (openai) without ``weights_path``: open_clip's
#: pretrained entry (its Hugging Face repository and file names, then the URL download's file),
#: written out for :func:`default_clip_checkpoint`.
CLIP_DEFAULT = (
    "timm/vit_base_patch16_clip_224.openai",
    ("open_clip_model.safetensors", "open_clip_pytorch_model.bin"),
    "ViT-B-16.pt",
)


def default_clip_checkpoint() -> str:
    """What ``resolve_clip_checkpoint(None)`` finds (:data:`CLIP_DEFAULT`), without importing
    open_clip (~4 s): for looking the weights up (``job=plan``), not for loading them."""
    from huggingface_hub import try_to_load_from_cache

    repo, names, url_file = CLIP_DEFAULT
    for name in names:
        hit = try_to_load_from_cache(repo, name)
        if isinstance(hit, str) and os.path.isfile(hit):
            return hit
    hit = Path("~/.cache/clip").expanduser() / url_file
    if hit.is_file():
        return str(hit)
    raise MetricUnavailable(f"no CLIP weights for ViT-B-16 (openai) on this machine (Hugging Face cache: {repo})")


class CLIPScore:
    """CLIP score of a full image against a full prompt (open_clip, local weights only).

    Convention:
        - Weights: ``weights_path`` (config key ``metrics.clip_weights``) or a cache hit, see
          :func:`resolve_clip_checkpoint`. A checkpoint loaded from a file gets the activation of
          ``pretrained_tag`` (QuickGELU for OpenAI's ViT-B/16).
        - ``allow_random_weights=True`` (with ``weights_path=None``) builds a seeded random model
          without looking for weights: for plumbing tests only, its scores are meaningless.
        - ``score(image, prompt)`` / ``__call__``: ``100 * max(cos, 0)`` as a float in [0, 100].
    """

    CONFIG_KEY = "metrics.clip_weights"

    def __init__(
        self,
        weights_path: str | os.PathLike | None = None,
        model_name: str = "ViT-B-16",
        *,
        pretrained_tag: str | None = "openai",
        cache_dir: str | os.PathLike | None = None,
        device: str | torch.device = "cpu",
        allow_random_weights: bool = False,
    ):
        import open_clip

        if weights_path is None and allow_random_weights:
            checkpoint = None
        else:
            checkpoint = resolve_clip_checkpoint(weights_path, model_name, pretrained_tag, cache_dir)
        tag_cfg = open_clip.get_pretrained_cfg(model_name, pretrained_tag) if pretrained_tag else {}
        quick_gelu = bool((tag_cfg or {}).get("quick_gelu", False)) and checkpoint is not None
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(0)
            model, _, preprocess = open_clip.create_model_and_transforms(
                model_name, pretrained=checkpoint, force_quick_gelu=quick_gelu, device=device
            )
        self.model = model.eval()
        self.preprocess = preprocess
        self.tokenizer = open_clip.get_tokenizer(model_name)
        self.device = torch.device(device)
        self.model_name = model_name
        self.weights_source = checkpoint if checkpoint is not None else "random"

    @torch.no_grad()
    def cosine(self, image: Any, prompt: str) -> float:
        """Cosine similarity of the image and text embeddings."""
        pixels = self.preprocess(_to_pil(image)).unsqueeze(0).to(self.device)
        tokens = self.tokenizer([prompt]).to(self.device)
        img = self.model.encode_image(pixels).float()
        txt = self.model.encode_text(tokens).float()
        return float(torch.nn.functional.cosine_similarity(img, txt, dim=-1)[0])

    def score(self, image: Any, prompt: str) -> float:
        """``100 * max(cos, 0)``."""
        return 100.0 * max(self.cosine(image, prompt), 0.0)

    __call__ = score


# --------------------------------------------------------------------------------------------
# ImageReward (separate interpreter)
# --------------------------------------------------------------------------------------------

#: Program run as ``<python> -c IMAGE_REWARD_WORKER``. Request (stdin, one JSON object):
#: ``{"protocol": 1, "model": name or checkpoint path, "med_config": path or null,
#: "download_root": path or null, "device": "cpu", "items": [{"image": path, "prompt": str}, ...]}``.
#: Answer (the last non-empty stdout line, one JSON object): ``{"scores": [float, ...]}`` (one per
#: item, in order) or ``{"error": "message"}``. Library output goes to stderr.
IMAGE_REWARD_WORKER = r"""
import contextlib, inspect, json, sys

def _main():
    answer_to = sys.stdout
    sys.stdout = sys.stderr
    try:
        request = json.loads(sys.stdin.read())
        import ImageReward as RM
        torch = sys.modules.get("torch")  # imported by ImageReward
        kwargs = {"device": request.get("device") or "cpu"}
        params = inspect.signature(RM.load).parameters
        if request.get("download_root"):
            kwargs["download_root"] = request["download_root"]
        if request.get("med_config"):
            key = "med_config" if "med_config" in params else "med_config_path"
            kwargs[key] = request["med_config"]
        model = RM.load(request.get("model") or "ImageReward-v1.0", **kwargs)
        model.eval()
        scores = []
        with torch.no_grad() if torch is not None else contextlib.nullcontext():
            for item in request["items"]:
                value = model.score(item["prompt"], item["image"])
                if isinstance(value, (list, tuple)):
                    value = value[0]
                scores.append(float(value))
        answer = {"scores": scores}
    except BaseException as exc:
        answer = {"error": "%s: %s" % (type(exc).__name__, exc)}
    answer_to.write(json.dumps(answer) + "\n")
    answer_to.flush()

_main()
"""


class ImageRewardScorer:
    """ImageReward scores computed by another Python environment through a subprocess.

    Convention:
        - ``python`` (config key ``metrics.image_reward_python``): the interpreter of an environment
          with ``image-reward`` installed. ``None`` or not executable: :class:`MetricUnavailable`.
        - ``model``: ``"ImageReward-v1.0"`` (found in ``download_root``, default
          ``~/.cache/ImageReward``) or a checkpoint path; ``med_config``: a local ``med_config.json``.
        - The child gets ``HF_HUB_OFFLINE=1`` (unless set) and no ``PYTHONPATH`` / ``PYTHONHOME``;
          ``env`` entries are added last. One call loads the model once and scores every item.
        - A failed, timed-out or malformed run raises :class:`MetricUnavailable` with the reason.
    """

    CONFIG_KEY = "metrics.image_reward_python"

    def __init__(
        self,
        python: str | os.PathLike | None = None,
        *,
        model: str = "ImageReward-v1.0",
        med_config: str | os.PathLike | None = None,
        download_root: str | os.PathLike | None = None,
        device: str = "cpu",
        timeout: float = 1800.0,
        env: Mapping[str, str] | None = None,
    ):
        if not python:
            raise MetricUnavailable(
                f"ImageReward not configured: set {self.CONFIG_KEY} to the python executable of an "
                "environment with image-reward installed"
            )
        exe = shutil.which(str(python))
        if exe is None:
            raise MetricUnavailable(f"{self.CONFIG_KEY}={str(python)!r} is not an executable")
        self.python = exe
        self.model = str(model)
        self.med_config = None if med_config is None else str(med_config)
        self.download_root = None if download_root is None else str(download_root)
        self.device = device
        self.timeout = timeout
        self.env = dict(env or {})

    def _child_env(self) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
        env.setdefault("HF_HUB_OFFLINE", "1")
        env.update(self.env)
        return env

    def score_paths(self, items: Sequence[tuple[str | os.PathLike, str]]) -> list[float]:
        """Scores of ``(image path, prompt)`` pairs, in order, from one subprocess run."""
        items = [(str(Path(p).resolve()), str(prompt)) for p, prompt in items]
        if not items:
            return []
        request = {
            "protocol": 1,
            "model": self.model,
            "med_config": self.med_config,
            "download_root": self.download_root,
            "device": self.device,
            "items": [{"image": p, "prompt": t} for p, t in items],
        }
        try:
            proc = subprocess.run(
                [self.python, "-c", IMAGE_REWARD_WORKER],
                input=json.dumps(request),
                capture_output=True,
                text=True,
                timeout=self.timeout,
                env=self._child_env(),
            )
        except subprocess.TimeoutExpired:
            raise MetricUnavailable(f"ImageReward subprocess timed out after {self.timeout:g} s") from None
        except OSError as e:
            raise MetricUnavailable(f"ImageReward subprocess could not start ({self.python}): {e}") from None
        lines = [ln for ln in proc.stdout.splitlines() if ln.strip()]
        answer = None
        if lines:
            try:
                answer = json.loads(lines[-1])
            except json.JSONDecodeError:
                answer = None
        if isinstance(answer, dict) and "error" in answer:
            raise MetricUnavailable(f"ImageReward failed: {answer['error']}")
        if proc.returncode != 0 or not isinstance(answer, dict):
            tail = (proc.stderr or proc.stdout or "").strip()[-800:]
            raise MetricUnavailable(
                f"ImageReward subprocess failed (exit code {proc.returncode}, {self.python}): {tail}"
            )
        scores = answer.get("scores")
        if not isinstance(scores, list) or len(scores) != len(items):
            raise MetricUnavailable(f"ImageReward subprocess answered {answer!r} for {len(items)} images")
        try:
            return [float(s) for s in scores]
        except (TypeError, ValueError):
            raise MetricUnavailable(f"ImageReward subprocess answered non-numbers: {scores!r}") from None

    def score(self, image: Any, prompt: str) -> float:
        """Score one image (a path is passed as is; arrays and tensors go through a temporary PNG)."""
        if isinstance(image, (str, os.PathLike)):
            return self.score_paths([(image, prompt)])[0]
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "image.png")
            _to_pil(image).save(path)
            return self.score_paths([(path, prompt)])[0]

    __call__ = score


# --------------------------------------------------------------------------------------------
# Everything for one image
# --------------------------------------------------------------------------------------------


class ScoreResult(TypedDict):
    """``metrics``: every name of :data:`METRIC_NAMES` -> float or None;
    ``missing``: name -> reason, for each None."""

    metrics: dict[str, float | None]
    missing: dict[str, str]


def score_all(
    generated,
    reference,
    mask,
    prompt: str,
    *,
    lpips: MaskedLPIPS | MetricUnavailable | None = None,
    clip: CLIPScore | MetricUnavailable | None = None,
    image_reward: ImageRewardScorer | MetricUnavailable | None = None,
    generated_path: str | os.PathLike | None = None,
    histogram_match: bool = True,
    protocol: str = "paper",
    lpips_box_range: str = "signed",
) -> ScoreResult:
    """All metrics of one generated image: ``{"metrics": {...}, "missing": {...}}``.

    Convention:
        - The names of :func:`metric_names` (``protocol``), in order.
        - PSNR, MAE, LPIPS: masked, under ``protocol`` (``"paper"``: grayscale, histogram-matched PSNR
          and MAE in float64, LPIPS of the RGB images averaged over the mask of its spatial map;
          ``"authors"``: the authors' evaluation on the 8-bit images, ``lpips`` their spatial LPIPS of
          the masked images averaged over the mask and ``lpips_box`` their bounding-box LPIPS; see
          :func:`~snell_bench.metrics.functional.masked_psnr` and
          :class:`~snell_bench.metrics.fidelity.MaskedLPIPS`). An unknown ``protocol`` raises
          ``ValueError`` naming ``metrics.protocol``. The LPIPS scorer is called as
          ``lpips(generated, reference, mask)`` under ``paper`` and as ``lpips(generated, reference,
          mask, protocol="authors")`` and ``lpips(..., protocol="authors", box=True,
          box_range=lpips_box_range)`` under ``authors`` (``lpips_box_range``: config key
          ``metrics.lpips_box_range``). ``histogram_match`` applies to PSNR and MAE only.
        - CLIP and ImageReward: the full image against ``prompt``, the text exactly as given (the
          caller picks the full prompt or the object phrase, config key ``metrics.clip_text``).
        - A scorer given as ``None`` is missing with reason ``"not configured (set <config key>)"``;
          one given as a :class:`MetricUnavailable` (what its constructor raised) is missing with that
          reason (both LPIPS values use the LPIPS scorer). An empty mask makes PSNR, MAE and LPIPS
          missing. Other errors propagate.
        - ``generated_path``: the generated image's file, handed to ImageReward as is (else a
          temporary PNG of ``generated`` is written).
    """
    inputs = ScoreInputs(
        generated,
        reference,
        mask,
        prompt,
        protocol=check_protocol(protocol),
        scorers={"lpips": lpips, "clip": clip, "image_reward": image_reward},
        generated_path=generated_path,
        lpips_box_range=lpips_box_range,
        histogram_match=histogram_match,
    )
    metrics, missing = compute_metrics([m for m in metrics_for(protocol) if "true_render" not in m.needs], inputs)
    return {"metrics": metrics, "missing": missing}
