"""What a method costs for ``job=plan``: the bases of the estimates (the documented GPU and CPU
figures, kept with their sources in ``snell_bench/methods/documented_costs.yaml``, or a
``benchmarks/bench_gpu.py`` measurement), a model's description and where its weights are, a cell's
:class:`Estimate`, and the sampler's, FLUX Fill's and FLUX Kontext's scaling of a basis.

Each method kind (:mod:`snell_bench.methods`) says what it costs with these (``Method.cost``);
:mod:`snell_bench.experiment.estimate` adds the plan around them.

Convention:
    Times are seconds per cell as ``(low, high)``; memory is in GB (10⁹ bytes) of bfloat16 weights.
    A basis is scaled to a cell's settings linearly: the synchronized sampler by its model calls
    weighted by their pixels (:func:`model_calls`), the pipelines by steps x pixels. The scaling is
    an approximation and is printed with every row.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from snell_bench.config import SamplerSettings
from snell_bench.sampler.authors_calls import authors_model_calls

__all__ = [
    "Basis",
    "CPU_LABEL",
    "CPU_PRESETS",
    "DOCUMENTED_FILE",
    "Documented",
    "Estimate",
    "ModelNeed",
    "README_BASIS",
    "README_LABEL",
    "add",
    "cpu_estimate",
    "fill_estimate",
    "device_of",
    "diffusers_folder",
    "documented",
    "example",
    "lookup",
    "model_calls",
    "ratio_note",
    "relight_estimate",
    "sampler_estimate",
    "scaled",
    "secs",
    "together_gb",
    "find_weights",
    "why",
]


# ---------------------------------------------------------------------------- the bases of the estimates
@dataclass(frozen=True)
class Basis:
    """Seconds and GB the estimates start from, at the settings they were taken at.

    Attributes:
        label: where the figures come from (printed with the plan).
        measured: a measurement (``plan.bench``) rather than the documented basis (docs/gpu.md).
        pair_s: one Snellcaster image + panorama pair, ``(low, high)`` seconds.
        pair_calls: its model calls ``(main, pano)``.
        size: ``(height, width, pano_height)`` of the pair, the t2i image and the pipelines.
        t2i_s, t2i_steps: the generator alone.
        fill_s, fill_steps: FLUX Fill.
        kontext_s, kontext_steps: FLUX Kontext, per relighting candidate.
        memory_gb: bfloat16 weights of ``flux_dev``, ``fill``, ``kontext`` and the part of each
            that is FLUX.1-dev's text encoders and VAE, ``shared_text_vae``.
        peak_gb: measured peak GPU memory per stage (``pair``, ``t2i``, ``fill``, ``kontext``).
    """

    label: str
    measured: bool
    pair_s: tuple[float, float]
    pair_calls: tuple[int, int]
    size: tuple[int, int, int]
    t2i_s: tuple[float, float]
    t2i_steps: int
    fill_s: tuple[float, float]
    fill_steps: int
    kontext_s: tuple[float, float]
    kontext_steps: int
    memory_gb: dict[str, float]
    peak_gb: dict[str, float] = field(default_factory=dict)


#: The file of the documented figures, in the package's config folder (no config group uses it).
DOCUMENTED_FILE = "documented_costs.yaml"


@dataclass(frozen=True)
class Documented:
    """The documented figures (:data:`DOCUMENTED_FILE`; each with its source there).

    Attributes:
        basis: the GPU basis (docs/gpu.md) at the authors' model calls per pair
            (:func:`~snell_bench.sampler.authors_calls.authors_model_calls` at the paper's setting).
        cpu_label: the label of ``cpu_presets``.
        cpu_presets: the CPU stand-ins' full method per image, ``(preset, seconds)`` by
            ``(height, width, pano_height, steps)`` (docs/presets.md).
        other_gb: GB of other models' weights by name (``moge2``, ``sam3``).
        activations_gb: GB a stage holds beside its weights when no bench measured it.
        reference_gpu_gb, larger_gpu_gb: the GPU the figures are for, and a larger one.
        group_inputs_s: each group's inputs on the CPU, ``(warps, reference)`` seconds.
    """

    basis: Basis
    cpu_label: str
    cpu_presets: dict[tuple[int, int, int, int], tuple[str, float]]
    other_gb: dict[str, float]
    activations_gb: float
    reference_gpu_gb: float
    larger_gpu_gb: float
    group_inputs_s: tuple[float, float]


def _pair(values: Sequence[float]) -> tuple[float, float]:
    low, high = values
    return float(low), float(high)


@functools.cache
def documented() -> Documented:
    """The documented figures, read from :data:`DOCUMENTED_FILE` once."""
    import yaml

    data = yaml.safe_load(resources.files(__package__).joinpath(DOCUMENTED_FILE).read_text(encoding="utf-8"))
    gpu, cpu = data["gpu"], data["cpu"]
    calls = authors_model_calls(SamplerSettings())
    basis = Basis(
        label=str(gpu["label"]),
        measured=False,
        pair_s=_pair(gpu["pair_s"]),
        pair_calls=(calls["main"], calls["pano"]),
        size=tuple(int(x) for x in gpu["size"]),
        t2i_s=_pair(gpu["t2i_s"]),
        t2i_steps=int(gpu["t2i_steps"]),
        fill_s=_pair(gpu["fill_s"]),
        fill_steps=int(gpu["fill_steps"]),
        kontext_s=_pair(gpu["kontext_s"]),
        kontext_steps=int(gpu["kontext_steps"]),
        memory_gb={k: float(v) for k, v in gpu["memory_gb"].items()},
    )
    presets = {
        (int(p["height"]), int(p["width"]), int(p["pano_height"]), int(p["steps"])): (
            str(p["preset"]),
            float(p["seconds"]),
        )
        for p in cpu["presets"]
    }
    return Documented(
        basis=basis,
        cpu_label=str(cpu["label"]),
        cpu_presets=presets,
        other_gb={k: float(v) for k, v in gpu["other_gb"].items()},
        activations_gb=float(gpu["activations_gb"]),
        reference_gpu_gb=float(gpu["reference_gpu_gb"]),
        larger_gpu_gb=float(gpu["larger_gpu_gb"]),
        group_inputs_s=_pair(gpu["group_inputs_s"]),
    )


#: The documented basis (docs/gpu.md): the authors' 56 main-view + 56 panorama model calls at
#: 720 x 1280 with a 1024 x 2048 panorama, t2i at 20 steps, Fill at 30, Kontext at its 28 per candidate.
README_BASIS = documented().basis
#: The label of the documented figures (docs/gpu.md).
README_LABEL = README_BASIS.label
#: The documented CPU measurements (docs/presets.md), ``(preset, seconds)`` by ``(height, width,
#: pano_height, steps)``.
CPU_PRESETS = documented().cpu_presets
#: The label of :data:`CPU_PRESETS`.
CPU_LABEL = documented().cpu_label


# ---------------------------------------------------------------------------- model calls of the sampler
def model_calls(s: SamplerSettings) -> dict[str, int]:
    """The velocity evaluations per branch, ``{"main": n, "pano": n}``, that the sampler makes with
    settings ``s`` (:func:`~snell_bench.sampler.expected_model_calls`; the adaptive decisions, which
    may drop the panorama for a scene, are not known before the warps: this is their upper bound)."""
    from snell_bench.sampler import expected_model_calls

    return expected_model_calls(s)


# ---------------------------------------------------------------------------- models and their weights
@dataclass
class ModelNeed:
    """One model the grid loads and what it needs here.

    Attributes:
        kind: the pool's kind (``generator``, ``fill``, ``relighter``, ``pipeline``, ``depth``,
            ``segmenter``), or ``lora``, ``lpips``, ``clip``, ``image_reward``.
        name: what it is (``FLUX.1-dev``, ``analytic (CPU stand-in)``).
        source: the configured model id, folder or file.
        weights: ``found``, ``missing``, ``random`` (``model.random_init``), ``none`` (built in
            code, or a CPU stand-in) or ``unchecked`` (a builder this plan does not know).
        where: the file or folder found, or why none is needed or what is missing.
        key: the config key that points at its weights.
        fix: the setting that makes a missing one found.
        device: ``cuda``, ``cpu`` or ``cuda if available``.
        needs_gpu: it runs on CUDA (``model.device`` null or ``cuda``).
        memory_gb: its bfloat16 weights, GB; ``None``: not known.
        family: ``flux`` for FLUX.1-dev, Fill and Kontext (sharing text encoders and VAE).
        methods: the grid's methods that need it; cells / cells_left: how many.
    """

    kind: str
    name: str
    source: str = ""
    weights: str = "none"
    where: str = ""
    key: str = ""
    fix: str = ""
    device: str = "cpu"
    needs_gpu: bool = False
    memory_gb: float | None = None
    family: str = ""
    methods: list[str] = field(default_factory=list)
    cells: int = 0
    cells_left: int = 0


def example(key: str, source: str) -> str:
    return f"{key}=/data/{Path(str(source).rstrip('/')).name or 'weights'}"


def why(error: Exception) -> str:
    """What a resolver's error says is missing (its first clause, without the fix it goes on to give)."""
    text = str(error).split("\n")[0]
    for cut in (": set ", "; set ", ". Set ", ". "):
        text = text.split(cut)[0]
    return text.split("not found: ", 1)[-1][:240]


def lookup(find: Callable[[], Any]) -> tuple[str, str]:
    """``("found", path)`` or ``("missing", why)`` of a resolver that raises when weights are missing."""
    from snell_bench.metrics.functional import MetricUnavailable
    from snell_bench.models.errors import WeightsNotFoundError

    try:
        return "found", str(find())
    except (WeightsNotFoundError, MetricUnavailable, OSError, ValueError, ImportError) as e:
        return "missing", why(e)


def diffusers_folder(source: str) -> str:
    from snell_bench.models.flux_weights import resolve_weights_folder

    return resolve_weights_folder(source)


def device_of(value: Any, default_cuda: bool) -> tuple[str, bool]:
    """``(device, needs_gpu)`` of a ``device`` setting: null/auto is CUDA for the FLUX models and the
    pipelines (required), CUDA when available for the segmenter and the depth estimator."""
    text = "" if value is None else str(value)
    if text.startswith("cuda"):
        return text, True
    if text in ("", "auto"):
        return ("cuda", True) if default_cuda else ("cuda if available", False)
    return text, False


def find_weights(need: ModelNeed, random: bool, find: Callable[[], Any]) -> ModelNeed:
    if random:
        need.weights, need.where = "random", "model.random_init=true: random weights, real shapes, meaningless pixels"
        return need
    need.weights, need.where = lookup(find)
    if need.weights == "missing":
        need.fix = f"set {example(need.key, need.source)}, or put {need.source} in the Hugging Face cache"
    return need


# ---------------------------------------------------------------------------- time of a cell
@dataclass(frozen=True)
class Estimate:
    """Time and GPU memory of one cell.

    Attributes:
        seconds: ``(low, high)`` seconds; ``None``: no basis for it.
        weights_gb: GPU weights its models hold together, GB (shared text encoders counted once).
        peak_gb: measured peak GPU memory of its stages (``plan.bench``), or ``None``.
        basis: ``bench``, ``README``, ``CPU`` (the documented CPU measurement) or ``none``.
        note: how the basis was scaled, or why there is none.
    """

    seconds: tuple[float, float] | None
    weights_gb: float
    peak_gb: float | None
    basis: str
    note: str


def scaled(s: tuple[float, float], ratio: float) -> tuple[float, float]:
    return (s[0] * ratio, s[1] * ratio)


def add(a: tuple[float, float], b: tuple[float, float]) -> tuple[float, float]:
    return (a[0] + b[0], a[1] + b[1])


def together_gb(models: Sequence[ModelNeed], basis: Basis) -> float:
    """GB of the weights of ``models`` held at once: FLUX.1-dev's text encoders and VAE, which
    Fill and Kontext share, counted once."""
    total = sum(m.memory_gb or 0.0 for m in models)
    flux = sum(1 for m in models if m.family == "flux")
    return total - basis.memory_gb["shared_text_vae"] * max(flux - 1, 0)


def ratio_note(ratio: float) -> str:
    return "" if abs(ratio - 1) < 1e-9 else f"; x{ratio:.2f} (linear in model calls x pixels)"


def secs(s: tuple[float, float] | None) -> str:
    """``(low, high)`` seconds as ``43–65 s``, ``1.7–2.1 min`` or ``3.6–5.4 h`` (one unit, the high's)."""
    if s is None:
        return "—"
    lo, hi = s
    div, unit = (3600, "h") if hi >= 3600 else (60, "min") if hi >= 120 else (1, "s")

    def one(x: float) -> str:
        x /= div
        return f"{x:.0f}" if x >= 10 else f"{x:.1f}"

    return f"{one(hi)} {unit}" if one(lo) == one(hi) else f"{one(lo)}–{one(hi)} {unit}"


def _gpu_weights(models: Sequence[ModelNeed], basis: Basis) -> float:
    return together_gb([m for m in models if m.needs_gpu], basis)


def _pixels(scene_cfg: DictConfig, basis: Basis) -> float:
    """The cell's image pixels over the basis's."""
    Hb, Wb, _ = basis.size
    return scene_cfg.scene.height * scene_cfg.scene.width / (Hb * Wb)


def sampler_estimate(
    scene_cfg: DictConfig, c: DictConfig, models: Sequence[ModelNeed], basis: Basis, *, full: bool
) -> Estimate:
    """Time and GPU memory of a cell that samples with the model's generator (the synchronized
    sampler, the generator alone, the inpainting stand-in): the basis's pair (``sampler.sync``
    ``snellcaster``) or t2i scaled by the cell's model calls weighted by their pixels. A generator
    that is not FLUX.1-dev on CUDA has no GPU basis: the documented CPU measurement where the cell
    is the ``full`` method at a preset's settings, else none.

    Args:
        scene_cfg: the run's config with the cell's scene (its image size).
        c: the run's config with the cell's method, its switches applied.
        models: the models the cell needs (:class:`ModelNeed`; the ``generator`` among them).
        basis: the figures to scale.
        full: the cell is the full method (Snellcaster unrelit), which the CPU measurement timed.
    """
    H, W = scene_cfg.scene.height, scene_cfg.scene.width
    Hb, Wb, Pb = basis.size
    weights = _gpu_weights(models, basis)
    gen = next((m for m in models if m.kind == "generator"), None)
    settings = OmegaConf.to_object(c.sampler)
    assert isinstance(settings, SamplerSettings)
    calls = model_calls(settings)
    if gen is not None and gen.family == "flux" and not gen.needs_gpu:
        return Estimate(None, weights, None, "none", f"FLUX.1-dev on {gen.device} (model.device): no basis")
    if gen is None or not gen.needs_gpu:
        return cpu_estimate(scene_cfg, c, settings, weights, full=full and settings.sync == "snellcaster")
    P = c.warps.pano_height
    work = calls["main"] * H * W + calls["pano"] * 2 * P * P
    if settings.sync == "snellcaster":
        base, (bm, bp) = basis.pair_s, basis.pair_calls
        ratio = work / (bm * Hb * Wb + bp * 2 * Pb * Pb)
        note = f"pair {secs(base)} for {bm}+{bp} calls; {calls['main']}+{calls['pano']} calls" + ratio_note(ratio)
        peak = basis.peak_gb.get("pair")
    else:
        base = basis.t2i_s
        ratio = work / (basis.t2i_steps * Hb * Wb)
        note = f"t2i {secs(base)} for {basis.t2i_steps} calls; {calls['main']} calls" + ratio_note(ratio)
        peak = basis.peak_gb.get("t2i")
    return Estimate(scaled(base, ratio), weights, peak, "bench" if basis.measured else "README", note)


def cpu_estimate(scene_cfg, c, settings: SamplerSettings, weights: float, *, full: bool) -> Estimate:
    """The documented CPU measurement (:data:`CPU_PRESETS`) of a ``full`` method cell at a preset's
    settings, else no basis."""
    key = (scene_cfg.scene.height, scene_cfg.scene.width, c.warps.pano_height, settings.steps)
    name = c.model.name
    if full and not c.method.relight and key in CPU_PRESETS:
        preset, seconds = CPU_PRESETS[key]
        note = (
            f"CPU stand-in ({name}): the {preset} preset's full method per image (warps, sampling, reference, metrics)"
        )
        return Estimate((seconds, seconds), weights, None, "CPU", note)
    return Estimate(None, weights, None, "none", f"CPU stand-in ({name}): time basis unknown (CPU)")


def fill_estimate(scene_cfg: DictConfig, c: DictConfig, models: Sequence[ModelNeed], basis: Basis) -> Estimate:
    """FLUX Fill's time: the basis's Fill scaled by steps x pixels; no basis off the GPU."""
    weights = _gpu_weights(models, basis)
    fill = next((m for m in models if m.kind == "fill"), None)
    if fill is None or not fill.needs_gpu:
        return Estimate(None, weights, None, "none", "FLUX Fill off the GPU: no basis")
    steps = basis.fill_steps if c.method.steps is None else c.method.steps
    ratio = _pixels(scene_cfg, basis) * steps / basis.fill_steps
    note = f"Fill {basis.fill_s[0]:g} s at {basis.fill_steps} steps" + ratio_note(ratio)
    src = "bench" if basis.measured else "README"
    return Estimate(scaled(basis.fill_s, ratio), weights, basis.peak_gb.get("fill"), src, note)


def relight_estimate(
    est: Estimate, scene_cfg: DictConfig, c: DictConfig, models: Sequence[ModelNeed], basis: Basis
) -> Estimate:
    """``est`` with relighting added (``method.relight``): ``relight.candidates`` x FLUX Kontext's
    time per candidate (steps x pixels) on the GPU; a CPU relighter is named, not estimated."""
    relighter = next((m for m in models if m.kind == "relighter"), None)
    if not c.method.relight or relighter is None or est.seconds is None:
        return est
    n = c.relight.candidates
    if not relighter.needs_gpu:
        return replace(est, note=est.note + f"; + {n} relighting candidates on the CPU (not estimated)")
    steps = basis.kontext_steps if c.relight.steps is None else c.relight.steps
    r = _pixels(scene_cfg, basis) * steps / basis.kontext_steps
    peak = est.peak_gb
    if basis.peak_gb.get("kontext") is not None and peak is not None:
        peak = max(peak, basis.peak_gb["kontext"])
    return replace(
        est,
        seconds=add(est.seconds, scaled(basis.kontext_s, n * r)),
        peak_gb=peak,
        note=est.note + f"; + {n} x Kontext {secs(scaled(basis.kontext_s, r))}",
    )
