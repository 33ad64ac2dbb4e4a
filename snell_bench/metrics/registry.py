"""One registry of metrics: what each metric is (its key, label, direction, print format, what it
needs) and how it is computed, read by scoring, every table, writer, page and plot, the
speed/accuracy sweep and the docs.

A metric is a :class:`MetricSpec`. The built-in ones (:data:`BUILTIN_METRICS`) are PSNR, MAE,
LPIPS, the authors' box LPIPS, CLIP, ImageReward and the PSNR against a procedural scene's true
render. A user's metric is a :class:`MetricSpec` in the user's own package, named either by a
Python entry point of the group :data:`ENTRY_POINT_GROUP` (``snell_bench.metrics``; the entry
point's name is the metric's) or by its dotted path (``my_pkg.metrics:SSIM``), and switched on with
``metrics.extra=[masked_ssim]``: it is then computed for every cell and appears in every table
after the table's own columns, labelled and formatted as its spec says.

Convention:
    - :class:`ScoreInputs` is what a metric's ``compute`` sees: the generated image ``(H, W, 3)``
      float64 sRGB in [0, 1], the reference and its metric mask (``(H, W)`` bool), the prompt, the
      object's mask and the true render where there is one, the protocol and the run's scorers.
    - ``compute`` returns a float or raises
      :class:`~snell_bench.metrics.functional.MetricUnavailable` with the reason (never a placeholder
      number). :func:`compute_metrics` records that as a missing value with the reason.
    - A metric that ``needs`` the reference (``"reference"``) is missing with the reference's reason
      where there is none; one that needs the true render (``"true_render"``) is left out of the
      record where there is none (no column: the scene has no truth); one with a ``scorer`` (a
      weight-backed model built once per run by :func:`~snell_bench.metrics.scoring.load_scorers`)
      is missing with the scorer's reason where it could not be built.
"""

from __future__ import annotations

import functools
import importlib
import logging
import math
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from importlib.metadata import entry_points
from typing import Any

from .functional import PROTOCOLS, MetricUnavailable, check_protocol, masked_mae, masked_psnr

log = logging.getLogger(__name__)

__all__ = [
    "BUILTIN_METRICS",
    "ENTRY_POINT_GROUP",
    "MISSING",
    "NEEDS",
    "MetricSpec",
    "ScoreInputs",
    "builtin_metric",
    "compute_metrics",
    "installed_metrics",
    "load_metric",
    "metric_spec",
    "metrics_for",
]

#: The entry-point group of users' metrics (``[project.entry-points."snell_bench.metrics"]``).
ENTRY_POINT_GROUP = "snell_bench.metrics"

#: What a metric may need: the reference render and its metric mask, the true render of a
#: procedural scene (over the object's mask), the prompt.
NEEDS = ("reference", "true_render", "prompt")

#: How a missing value is printed in Markdown and LaTeX tables.
MISSING = "—"

_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_.]*")


@dataclass(frozen=True)
class ScoreInputs:
    """What a metric is computed from (see the module's convention).

    Attributes:
        generated: the image, ``(H, W, 3)`` sRGB in [0, 1].
        reference: the reference render ``(H, W, 3)``, or None.
        mask: the reference's metric mask ``(H, W)`` bool, or None.
        prompt: the text CLIP and ImageReward score against.
        object_mask: the object's pixels ``(H, W)`` bool (where ``psnr_true`` is scored), or None.
        true_render: the true render ``(H, W, 3)`` of a procedural scene, or None.
        protocol: ``"paper"`` or ``"authors"`` (``metrics.protocol``).
        scorers: the run's weight-backed scorers by name (a mapping of name to scorer,
            :class:`MetricUnavailable` or None).
        generated_path: the saved image (ImageReward reads the file), or None.
        lpips_box_range: the input range of the authors' box LPIPS (``metrics.lpips_box_range``).
        histogram_match: PSNR and MAE match the generated histogram to the reference's in the mask.
    """

    generated: Any
    reference: Any = None
    mask: Any = None
    prompt: str = ""
    object_mask: Any = None
    true_render: Any = None
    protocol: str = "paper"
    scorers: Mapping[str, Any] = field(default_factory=dict)
    generated_path: Any = None
    lpips_box_range: str = "signed"
    histogram_match: bool = True

    def scorer(self, name: str) -> Any:
        """The scorer ``name`` (LPIPS, CLIP, ImageReward), or :class:`MetricUnavailable` saying why
        there is none."""
        return self.scorers.get(name)


@dataclass(frozen=True)
class MetricSpec:
    """One metric: how it is labelled, compared, printed and computed.

    Attributes:
        name: its key in a cell's record (``metrics.json``), e.g. ``"psnr"``.
        label: the column header, e.g. ``"PSNR"``.
        higher_is_better: the direction that decides which value is marked best.
        format: a :meth:`str.format` pattern for one value, e.g. ``"{:.2f}"``.
        compute: ``compute(inputs: ScoreInputs) -> float``, raising :class:`MetricUnavailable` with
            the reason; ``None`` for a column that is derived elsewhere (the trade-off's
            ``psnr_converged``).
        needs: of :data:`NEEDS`, what it is computed from.
        scorer: the weight-backed scorer it calls (``lpips``, ``clip``, ``image_reward``), or None.
        config_key: the key that points at that scorer's weights (named when it is not configured).
        protocols: the evaluation protocols that report it.
        description: one line for the docs.
        source: where it comes from: ``snell_bench`` or the plugin (entry point or dotted path).
    """

    name: str
    label: str
    higher_is_better: bool
    format: str = "{:.3f}"
    compute: Callable[[ScoreInputs], float] | None = None
    needs: tuple[str, ...] = ("reference",)
    scorer: str | None = None
    config_key: str | None = None
    protocols: tuple[str, ...] = PROTOCOLS
    description: str = ""
    source: str = "snell_bench"

    def __post_init__(self) -> None:
        unknown = [n for n in self.needs if n not in NEEDS]
        if unknown:
            raise ValueError(f"metric {self.name!r}: unknown needs {unknown}; use some of {list(NEEDS)}")
        if not _NAME.fullmatch(str(self.name)):
            raise ValueError(
                f"metric name {self.name!r} is not a column name (a letter or underscore, then letters, digits, "
                "underscores and dots)"
            )
        try:
            self.format.format(0.5)
        except (ValueError, IndexError, KeyError) as e:
            raise ValueError(f"metric {self.name!r}: format {self.format!r} cannot print a number ({e})") from None

    @property
    def arrow(self) -> str:
        """ "↑" if higher is better, else "↓"."""
        return "↑" if self.higher_is_better else "↓"

    def fmt(self, value: float | None) -> str:
        """The value as printed in a table (:data:`MISSING` for None and NaN)."""
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return MISSING
        return self.format.format(value)


# ---------------------------------------------------------------------------- the built-in metrics
def _psnr(x: ScoreInputs) -> float:
    return masked_psnr(x.generated, x.reference, x.mask, histogram_match=x.histogram_match, protocol=x.protocol)


def _mae(x: ScoreInputs) -> float:
    return masked_mae(x.generated, x.reference, x.mask, histogram_match=x.histogram_match, protocol=x.protocol)


def _lpips(x: ScoreInputs) -> float:
    kwargs = {} if x.protocol == "paper" else {"protocol": x.protocol}
    return x.scorer("lpips")(x.generated, x.reference, x.mask, **kwargs)


def _lpips_box(x: ScoreInputs) -> float:
    return x.scorer("lpips")(
        x.generated, x.reference, x.mask, protocol=x.protocol, box=True, box_range=x.lpips_box_range
    )


def _clip(x: ScoreInputs) -> float:
    return x.scorer("clip")(x.generated, x.prompt)


def _image_reward(x: ScoreInputs) -> float:
    return x.scorer("image_reward")(x.generated_path if x.generated_path is not None else x.generated, x.prompt)


def _psnr_true(x: ScoreInputs) -> float:
    return masked_psnr(x.generated, x.true_render, x.object_mask, protocol=x.protocol)


#: The built-in metrics, in the order a record lists them.
BUILTIN_METRICS: tuple[MetricSpec, ...] = (
    MetricSpec(
        "psnr",
        "PSNR",
        True,
        "{:.2f}",
        _psnr,
        description="masked PSNR (dB) against the reference: grayscale, histogram-matched in the mask",
    ),
    MetricSpec(
        "mae",
        "MAE",
        False,
        "{:.4f}",
        _mae,
        description="masked mean absolute error against the reference, as PSNR",
    ),
    MetricSpec(
        "lpips",
        "LPIPS",
        False,
        "{:.3f}",
        _lpips,
        scorer="lpips",
        config_key="metrics.lpips_weights",
        description="LPIPS (VGG) against the reference, its spatial map averaged over the mask",
    ),
    MetricSpec(
        "lpips_box",
        "LPIPS (box)",
        False,
        "{:.3f}",
        _lpips_box,
        scorer="lpips",
        config_key="metrics.lpips_weights",
        protocols=("authors",),
        description="the authors' LPIPS of the mask's bounding box (metrics.protocol=authors only)",
    ),
    MetricSpec(
        "clip",
        "CLIP",
        True,
        "{:.2f}",
        _clip,
        needs=("prompt",),
        scorer="clip",
        config_key="metrics.clip_weights",
        description="CLIP score 100 max(cos, 0) of the full image and the prompt (ViT-B/16)",
    ),
    MetricSpec(
        "image_reward",
        "ImageReward",
        True,
        "{:.3f}",
        _image_reward,
        needs=("prompt",),
        scorer="image_reward",
        config_key="metrics.image_reward_python",
        description="ImageReward of the full image and the prompt (its own environment)",
    ),
    MetricSpec(
        "psnr_true",
        "PSNR (true)",
        True,
        "{:.2f}",
        _psnr_true,
        needs=("true_render",),
        description="masked PSNR (dB) against the true render of a procedural scene, over the object",
    ),
)

_BUILTIN = {m.name: m for m in BUILTIN_METRICS}

#: Columns derived from a metric under another reference (the speed/accuracy sweep's converged
#: reference): ``<metric><suffix>`` -> its label's suffix.
_DERIVED = {"_converged": " (conv.)"}


def builtin_metric(name: str) -> MetricSpec | None:
    """The built-in spec of ``name``, or None."""
    return _BUILTIN.get(name)


# ---------------------------------------------------------------------------- users' metrics
@functools.lru_cache(maxsize=1)
def _entry_points() -> dict[str, Any]:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def installed_metrics() -> tuple[str, ...]:
    """The names of the metrics installed packages register (entry points of :data:`ENTRY_POINT_GROUP`)."""
    return tuple(sorted(_entry_points()))


def _as_spec(obj: Any, where: str) -> MetricSpec:
    if isinstance(obj, type) and not isinstance(obj, MetricSpec):
        obj = obj()  # a class whose instances are specs (or that builds one)
    if callable(getattr(obj, "spec", None)) and not isinstance(obj, MetricSpec):
        obj = obj.spec()
    if not isinstance(obj, MetricSpec):
        raise ValueError(
            f"{where} is a {type(obj).__name__}, not a snell_bench.metrics.MetricSpec; register a MetricSpec "
            "(see docs/own-method.md)"
        )
    return obj


def _import(path: str) -> Any:
    module, sep, attr = path.partition(":")
    if not sep:
        module, _, attr = path.rpartition(".")
    if not module or not attr:
        raise ValueError(f"{path!r} is not a dotted path (package.module:NAME)")
    obj = importlib.import_module(module)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


@functools.cache
def load_metric(entry: str) -> MetricSpec:
    """The spec ``entry`` names: a built-in metric, an installed entry point of
    :data:`ENTRY_POINT_GROUP`, or a dotted path (``my_pkg.metrics:SSIM``) to a :class:`MetricSpec`
    (or a class or factory returning one).

    Raises:
        ValueError: naming ``metrics.extra``, the entry and the installed metrics, when it names
            none of them or does not import.
    """
    entry = str(entry)
    if entry in _BUILTIN:
        return _BUILTIN[entry]
    eps = _entry_points()
    try:
        if entry in eps:
            spec = _as_spec(eps[entry].load(), f"the entry point {entry!r} ({eps[entry].value})")
            spec = spec if spec.name == entry else replace(spec, name=entry)
            return replace(spec, source=f"entry point {eps[entry].value}")
        if "." in entry or ":" in entry:
            return replace(_as_spec(_import(entry), entry), source=entry)
    except (ImportError, AttributeError, ValueError, TypeError) as e:
        raise ValueError(f"metrics.extra: {entry!r} cannot be loaded ({type(e).__name__}: {e})") from None
    known = sorted(set(_BUILTIN) | set(eps))
    raise ValueError(
        f"metrics.extra: unknown metric {entry!r}; use a built-in or installed one ({known}) or a dotted path "
        "to a MetricSpec (my_pkg.metrics:SPEC)"
    )


def metrics_for(protocol: str = "paper", extra: Iterable[str] = ()) -> tuple[MetricSpec, ...]:
    """The metrics a cell scored under ``protocol`` records, in order: the built-in ones that
    protocol reports, then ``extra`` (``metrics.extra``, :func:`load_metric`) in its order."""
    check_protocol(protocol)
    specs = [m for m in BUILTIN_METRICS if protocol in m.protocols]
    for entry in extra or ():
        spec = load_metric(str(entry))
        if spec.name not in [s.name for s in specs] and protocol in spec.protocols:
            specs.append(spec)
    return tuple(specs)


def metric_spec(name: str) -> MetricSpec:
    """The spec of a metric column ``name``: a built-in or installed metric, a derived column
    (``psnr_converged``), else a generic one labelled by its name (higher is better, 3 decimals)."""
    name = str(name)
    if name in _BUILTIN:
        return _BUILTIN[name]
    for suffix, label in _DERIVED.items():
        base = name[: -len(suffix)] if name.endswith(suffix) else None
        if base and (base in _BUILTIN or base in _entry_points()):
            spec = metric_spec(base)
            return replace(spec, name=name, label=spec.label + label, compute=None)
    if name in _entry_points():
        try:
            return load_metric(name)
        except ValueError as e:
            log.warning("metric %s: %s; labelled by its name", name, e)
    return MetricSpec(name, name, True, "{:.3f}", source="unknown")


# ---------------------------------------------------------------------------- computing
def _missing_reason(spec: MetricSpec, x: ScoreInputs, reference_reason: str | None) -> str | None:
    """Why ``spec`` cannot be computed from ``x`` (before trying), or None."""
    scorer = x.scorer(spec.scorer) if spec.scorer is not None else True
    if isinstance(scorer, MetricUnavailable):  # the scorer could not be built: its reason first
        return scorer.reason
    if "reference" in spec.needs and (x.reference is None or x.mask is None):
        return reference_reason or "no reference"
    if scorer is None:
        return f"not configured (set {spec.config_key})" if spec.config_key else "not configured"
    return None


def compute_metrics(
    specs: Sequence[MetricSpec], inputs: ScoreInputs, *, reference_reason: str | None = None
) -> tuple[dict[str, float | None], dict[str, str]]:
    """Every metric of ``specs`` on ``inputs``: ``({name: float | None}, {name: reason})``.

    A metric that needs the true render is left out where ``inputs.true_render`` is None; every
    other one is a float, or None with its reason (its scorer's, the reference's
    ``reference_reason``, or what its ``compute`` raised as :class:`MetricUnavailable`). Any other
    exception propagates (a bug, not a missing value). Values are as computed (finite or not)."""
    metrics: dict[str, float | None] = {}
    missing: dict[str, str] = {}
    for spec in specs:
        if spec.compute is None or ("true_render" in spec.needs and inputs.true_render is None):
            continue
        if "true_render" in spec.needs and inputs.object_mask is None:
            raise ValueError(f"metric {spec.name}: the true render needs the object_mask it is scored over")
        metrics[spec.name] = None
        reason = _missing_reason(spec, inputs, reference_reason)
        if reason is not None:
            missing[spec.name] = reason
            continue
        try:
            value = spec.compute(inputs)
        except MetricUnavailable as e:
            missing[spec.name] = e.reason
            continue
        if value is None:
            missing[spec.name] = f"{spec.name} returned no value ({spec.source})"
            continue
        metrics[spec.name] = float(value)
    return metrics, missing
