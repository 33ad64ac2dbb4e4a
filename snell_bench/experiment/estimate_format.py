"""``job=plan``'s record and its text: the device planned for (:class:`DeviceInfo`), each method's
time (:class:`MethodTime`), the :class:`Plan`, the lines on GPU memory (:func:`memory_plan`) and the
text ``job=plan`` prints (:func:`format_plan`).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from omegaconf import DictConfig

from snell_bench.experiment.estimate_cells import CellState
from snell_bench.methods.cost import CPU_LABEL, README_LABEL, Basis, ModelNeed, documented, secs, together_gb

__all__ = [
    "ACTIVATIONS_GB",
    "GIB",
    "DeviceInfo",
    "MethodTime",
    "Plan",
    "activations_gb",
    "format_plan",
    "local_device",
    "memory_plan",
]


@dataclass(frozen=True)
class DeviceInfo:
    """The CUDA device of this machine (``cuda``: one is available; ``memory_gb``: of device 0)."""

    cuda: bool
    name: str = ""
    memory_gb: float | None = None
    count: int = 0


def local_device() -> DeviceInfo:
    """This machine's CUDA device 0 (``torch.cuda``), or none."""
    import torch

    if not torch.cuda.is_available():
        return DeviceInfo(cuda=False)
    props = torch.cuda.get_device_properties(0)
    return DeviceInfo(True, str(props.name), props.total_memory / 1e9, torch.cuda.device_count())


@dataclass
class MethodTime:
    """Time of one method's cells: per cell (over the scenes, ``low``-``high``) and in total."""

    method: str
    kind: str
    per_cell: tuple[float, float] | None
    cells_left: int
    total: tuple[float, float] | None
    weights_gb: float
    peak_gb: float | None
    basis: str
    note: str


@dataclass
class Plan:
    """What ``job=plan`` prints (:func:`format_plan`); see the module's docs."""

    experiment: str
    root: Path
    model: str
    recipe: str
    scenes: int
    variations: int
    objects: int
    methods: list[str]
    cells: list[CellState]
    models: list[ModelNeed]
    device: DeviceInfo
    times: list[MethodTime]
    basis: Basis
    memory: list[str]
    warnings: list[str]
    compositions: int

    @property
    def groups(self) -> int:
        return self.scenes * self.variations * self.objects

    def counts(self) -> Counter:
        return Counter(c.state for c in self.cells)

    @property
    def left(self) -> list[CellState]:
        return [c for c in self.cells if not c.done]


# ---------------------------------------------------------------------------- memory
#: GB (10⁹ bytes) in a GiB (``models.memory_gb``'s unit).
GIB = 2**30 / 1e9

#: GB of activations beside a model's weights when no bench measured them: the documented "a few GB
#: of activations at 720 x 1280", taken as 10.
ACTIVATIONS_GB = documented().activations_gb


def activations_gb(basis: Basis) -> float:
    """GB a stage holds beside its weights: the largest measured peak less its weights
    (``plan.bench``), else :data:`ACTIVATIONS_GB`."""
    weights = {"pair": "flux_dev", "t2i": "flux_dev", "fill": "fill", "kontext": "kontext"}
    extra = [basis.peak_gb[k] - basis.memory_gb[w] for k, w in weights.items() if k in basis.peak_gb]
    return max(0.0, *extra) if extra else ACTIVATIONS_GB


def _weights_line(known: list[ModelNeed], unknown: list[str], basis: Basis) -> str:
    together = together_gb(known, basis)
    largest = max(known, key=lambda m: m.memory_gb or 0.0) if known else None
    shared = sum(1 for m in known if m.family == "flux") > 1
    return (
        f"GPU weights together: {together:.0f} GB"
        + (
            f" (FLUX.1-dev's text encoders and VAE, {basis.memory_gb['shared_text_vae']:g} GB, counted once)"
            if shared
            else ""
        )
        + (f"; not known: {', '.join(unknown)}" if unknown else "")
        + (f"; largest: {largest.name} {largest.memory_gb:g} GB" if largest else "")
    )


def memory_plan(models: Sequence[ModelNeed], models_cfg: DictConfig, device: DeviceInfo, basis: Basis) -> list[str]:
    """Lines on the GPU memory of ``models`` (those the cells left need): whether they fit together
    on ``device`` or in ``models.memory_gb``, else the model-major order with offloading."""
    gpu = [m for m in models if m.kind != "lora" and (m.needs_gpu or (m.device == "cuda if available" and device.cuda))]
    if not gpu:
        return ["no model runs on a GPU"]
    known = [m for m in gpu if m.memory_gb is not None]
    together = together_gb(known, basis)
    lines = [_weights_line(known, [m.name for m in gpu if m.memory_gb is None], basis)]
    act = activations_gb(basis)
    why = (
        "the bench's largest peak less its weights"
        if basis.peak_gb
        else f"the documented 'a few GB' at 720 x 1280, taken as {ACTIVATIONS_GB:g}"
    )
    lines.append(f"activations: {act:.0f} GB ({why})")
    budget_gib = models_cfg.get("memory_gb")
    offload = bool(models_cfg.get("offload", True))
    where = (
        "host memory (models.offload=true)" if offload else "nowhere: dropped and loaded again (models.offload=false)"
    )
    reference, larger = documented().reference_gpu_gb, documented().larger_gpu_gb
    if device.cuda:
        capacity, what = device.memory_gb, f"{device.name} ({device.memory_gb:.0f} GB)"
    else:
        capacity, what = reference, f"an {reference:g} GB GPU (no GPU here: the documented reference)"
    if budget_gib is None:
        if together + act <= capacity:
            lines.append(f"they fit together on {what}: group-major order, every model stays loaded")
        else:
            lines.append(
                f"they do not fit together on {what}: set models.memory_gb={max(int((capacity - act) / GIB), 1)} (GiB: "
                "the GPU less the activations) so the grid runs model-major "
                f"(each model loads once, the least recently used one moved to {where})"
            )
    else:
        budget = float(budget_gib) * GIB
        fits = (
            "the models fit the budget together"
            if together <= budget
            else f"they do not fit together: each makes room in {where}"
        )
        lines.append(f"models.memory_gb={budget_gib:g} GiB ({budget:.0f} GB): model-major order; {fits}")
    for m in known:
        gb = m.memory_gb or 0.0
        if device.cuda and gb > device.memory_gb:
            lines.append(f"{m.name} ({gb:g} GB) is larger than {what}: it cannot load there")
        elif not device.cuda and gb > reference:
            lines.append(
                f"{m.name} ({gb:g} GB) is larger than an {reference:g} GB GPU: it needs a larger one (e.g. {larger:g} GB)"
            )
        elif budget_gib is not None and gb > float(budget_gib) * GIB:
            lines.append(f"{m.name} ({gb:g} GB) is larger than models.memory_gb: the pool loads it alone")
    return lines


# ---------------------------------------------------------------------------- printing
def _table(rows: list[dict]) -> str:
    """``rows`` as an indented text table: a column per key, numbers right-aligned, text left-aligned."""
    if not rows:
        return "  (none)"
    cols = list(rows[0])
    cells = [[str(r.get(c, "")) for c in cols] for r in rows]
    width = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(cols)]
    numeric = [all(isinstance(r.get(c), (int, float)) for r in rows) for c in cols]

    def line(values: list[str]) -> str:
        return "  " + "  ".join(v.rjust(w) if n else v.ljust(w) for v, w, n in zip(values, width, numeric)).rstrip()

    return "\n".join([line(cols), *(line(row) for row in cells)])


def _short(text: str, n: int = 48) -> str:
    text = str(text)
    return text if len(text) <= n else "..." + text[-(n - 3) :]


_STATE_WORDS = {
    "done": "done",
    "skipped": "skipped (done)",
    "degenerate": "degenerate (done)",
    "changed": "other settings",
    "files": "files changed",
    "failed": "failed before",
    "new": "not run",
    "recompute": "grid.recompute",
}


def _cells_text(plan: Plan) -> list[str]:
    """The grid, its cells done and left, per method, and the warnings."""
    counts = plan.counts()
    done = counts["done"] + counts["skipped"] + counts["degenerate"]
    out = [
        f"job=plan: experiment {plan.experiment} -> {plan.root} (nothing written, nothing downloaded)",
        f"  model={plan.model}, recipe={plan.recipe}",
        f"grid: {plan.scenes} scenes x {plan.variations} variations x {plan.objects} objects = {plan.groups} groups; "
        f"x {len(plan.methods)} methods = {len(plan.cells)} cells",
    ]
    parts = ", ".join(f"{counts[s]} {_STATE_WORDS[s]}" for s in _STATE_WORDS if counts[s] and s not in ("done",))
    out.append(f"cells: {done} done, {len(plan.left)} left" + (f" ({parts})" if parts else ""))
    rows = []
    for m in plan.methods:
        mine = Counter(c.state for c in plan.cells if c.method == m)
        row = {"method": m, "cells": sum(mine.values())}
        row.update({_STATE_WORDS[s]: mine[s] for s in _STATE_WORDS if counts[s]})
        row["left"] = sum(n for s, n in mine.items() if s not in ("done", "skipped", "degenerate"))
        rows.append(row)
    return [*out, _table(rows), *("WARNING: " + w for w in plan.warnings)]


def _device_line(plan: Plan) -> str:
    """The CUDA device here, and the models of the cells left that need one."""
    gpu_models = [m.name for m in plan.models if m.needs_gpu and m.cells_left]
    if plan.device.cuda:
        dev = f"{plan.device.name}, {plan.device.memory_gb:.0f} GB" + (
            f" (x{plan.device.count})" if plan.device.count > 1 else ""
        )
        return f"device: CUDA {dev}" + (f"; needed by {', '.join(gpu_models)}" if gpu_models else "")
    if gpu_models:
        return (
            f"device: no CUDA GPU here (torch.cuda.is_available() is False); the cells left need one for "
            f"{', '.join(gpu_models)} (model.device: null = CUDA; model.device=cpu runs them on the CPU)"
        )
    return "device: no CUDA GPU here, and none is needed"


def _models_text(plan: Plan) -> list[str]:
    """The models, their weights (what is missing and the key to set) and the memory lines."""
    rows = [
        {
            "kind": m.kind,
            "model": m.name,
            "source": _short(m.source),
            "methods": ",".join(m.methods) if len(m.methods) < len(plan.methods) else "all",
            "cells left": m.cells_left,
            "device": m.device,
            "GB": "—" if m.memory_gb is None else f"{m.memory_gb:g}" + ("*" if m.family == "flux" else ""),
            "weights": m.weights,
        }
        for m in plan.models
    ]
    out = ["models (weights looked up in local folders and the Hugging Face cache only):", _table(rows)]
    if any(m.family == "flux" for m in plan.models):
        shared = plan.basis.memory_gb["shared_text_vae"]
        out.append(f"  * FLUX.1-dev, Fill and Kontext share the text encoders and VAE ({shared:g} GB of each)")
    out += [f"  MISSING {m.name}: {m.where}; {m.fix}" for m in plan.models if m.weights == "missing"]
    out += [f"  {m.name}: {m.where}" for m in plan.models if m.weights in ("random", "unchecked")]
    return [*out, "memory:", *("  " + line for line in plan.memory)]


def _times_text(plan: Plan) -> list[str]:
    """The time per method, per cell and in total, its bases and notes, and the grid's total."""
    rows = [
        {
            "method": t.method,
            "kind": t.kind,
            "per cell": secs(t.per_cell),
            "cells left": t.cells_left,
            "total": secs(t.total) if t.cells_left else "0",
            "GPU GB": f"{t.weights_gb:.0f}" if t.weights_gb else "0",
            "peak GB": "—" if t.peak_gb is None else f"{t.peak_gb:.0f}",
            "basis": t.basis,
        }
        for t in plan.times
    ]
    out = ["time (per cell, over the scenes, and in total):", _table(rows)]
    labels = {"README": README_LABEL, "bench": plan.basis.label, "CPU": CPU_LABEL}
    out += [f"  {b}: {labels[b]}" for b in dict.fromkeys(t.basis for t in plan.times) if b in labels]
    notes: dict[str, list[str]] = {}
    for t in plan.times:
        notes.setdefault(t.note, []).append(t.method)
    out += [f"  {', '.join(methods)}: {note}" for note, methods in notes.items()]
    known = [t for t in plan.times if t.total is not None and t.cells_left]
    unknown = [t for t in plan.times if t.total is None and t.cells_left]
    line = f"total: {sum(t.cells_left for t in plan.times)} cells left"
    if known:
        total = (sum(t.total[0] for t in known), sum(t.total[1] for t in known))
        bases = " + ".join(dict.fromkeys(t.basis for t in known))
        line += f"; {sum(t.cells_left for t in known)} estimated: {secs(total)} ({bases})"
    if unknown:
        line += "; not estimated: " + ", ".join(f"{t.method} ({t.cells_left} cells)" for t in unknown)
    out.append(line)
    if any(t.basis in ("README", "bench") for t in known):
        warps, reference = documented().group_inputs_s
        out.append(
            "  not included: model loads (each model once per sweep), each group's inputs on the CPU (warps and the "
            f"reference render; docs/gpu.md, paper preset on 2 cores: {warps:g} s + {reference:g} s per group)"
        )
    return out


def format_plan(plan: Plan) -> str:
    """The plan as the text ``job=plan`` prints."""
    return "\n".join([*_cells_text(plan), _device_line(plan), *_models_text(plan), *_times_text(plan)])
