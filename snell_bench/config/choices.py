"""The choices of the config's string settings, typed where the schema owns them.

OmegaConf checks an ``Enum`` field when a config is composed (``scene.source=bogus`` fails with
the choices listed), so no stage checks them again. Each choice is a ``str`` too: it compares equal
to its value (``Source.image == "image"``), formats as it (``f"{x}"``, ``str(x)``), and is written as
it into YAML and JSON, so files and hashes of a cell do not depend on it being an enum.
"""

from __future__ import annotations

from enum import Enum

__all__ = [
    "Choice",
    "Job",
    "SWEEP_JOBS",
    "Source",
    "SCENE_KINDS",
    "DepthKind",
    "Normals",
    "PanoPrior",
    "METHOD_KINDS",
    "METHOD_ENTRY_POINTS",
    "PromptKind",
    "InpaintMask",
    "Protocol",
    "RefSampler",
    "RefRenderer",
    "RefMask",
    "OnChange",
    "DTYPE_NAMES",
    "dtype_name",
]


class Choice(str, Enum):
    """A string setting with a closed set of values (the member names are the values)."""

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)

    @classmethod
    def values(cls) -> tuple[str, ...]:
        return tuple(m.value for m in cls)

    @classmethod
    def of(cls, value, key: str):
        """The member ``value`` names (a member or its string; a config read back from YAML holds
        strings). Raises ``ValueError`` naming ``key`` and the choices for any other value."""
        try:
            return cls(str(value))
        except ValueError:
            raise ValueError(f"{key}={value!r} is unknown; use one of {list(cls.values())}") from None


class Job(Choice):
    """What ``python -m snell_bench`` runs (``job``)."""

    preview = "preview"
    generate = "generate"
    grid = "grid"
    report = "report"
    plan = "plan"
    status = "status"
    export = "export"
    relight = "relight"


#: Jobs whose output is an experiment folder under ``runs_dir`` (their logs go to
#: ``runs/<experiment>/logs/``).
SWEEP_JOBS = (Job.grid, Job.report, Job.export, Job.relight)


class Source(Choice):
    """Where I⁻ comes from (``scene.source``)."""

    procedural = "procedural"
    image = "image"
    generated = "generated"


#: The kinds of procedural scene (``scene.kind`` of ``scene.source=procedural``): those of
#: :data:`snell_bench.scene.procedural.scene.SCENE_KINDS`, listed here so that checking a config
#: does not import the scene package.
SCENE_KINDS = ("room", "outdoor", "kitchen")


class DepthKind(Choice):
    """What a depth file holds (``scene.depth_kind``): z along the optical axis, or range along the ray."""

    z = "z"
    range = "range"


class Normals(Choice):
    """Shading normals of the traced object (``warps.normals``)."""

    interpolated = "interpolated"
    face = "face"
    radial = "radial"


class PanoPrior(Choice):
    """The panorama a generator built from the scene starts from (``model.pano_prior``)."""

    other = "other"
    blur = "blur"
    truth = "truth"
    observed = "observed"


#: The built-in method kinds (``method.kind``), one module of :mod:`snell_bench.methods` each;
#: installed plugins add theirs (the ``snell_bench.methods`` entry points), listed here so that
#: checking a config does not import the methods.
METHOD_KINDS = ("snellcaster", "t2i", "inpaint", "external", "images")

#: The entry-point group of users' methods (``[project.entry-points."snell_bench.methods"]``).
METHOD_ENTRY_POINTS = "snell_bench.methods"


class PromptKind(Choice):
    """Which text a pipeline baseline or CLIP sees (``method.prompt``, ``metrics.clip_text``): the
    full prompt p or the object phrase p_obj."""

    full = "full"
    object = "object"


class InpaintMask(Choice):
    """The region ``method=inpaint`` repaints (``method.mask``)."""

    object = "object"
    box = "box"


class Protocol(Choice):
    """The evaluation protocol (``metrics.protocol``): the paper's text or the authors' code."""

    paper = "paper"
    authors = "authors"


class RefSampler(Choice):
    """Mitsuba's sampler of the reference render (``reference.sampler``)."""

    independent = "independent"
    stratified = "stratified"
    multijitter = "multijitter"
    orthogonal = "orthogonal"
    ldsampler = "ldsampler"


class RefRenderer(Choice):
    """The reference renderer (``reference.renderer``)."""

    mitsuba = "mitsuba"
    cycles = "cycles"


class RefMask(Choice):
    """The metric mask of the reference (``reference.mask``)."""

    unobserved = "unobserved"
    authors = "authors"


class OnChange(Choice):
    """What a sweep does with a finished cell computed with other settings (``grid.on_change``)."""

    error = "error"
    recompute = "recompute"


#: The dtype names ``model.dtype`` takes (case-insensitive, optionally prefixed with ``torch.``),
#: each to the name of its ``torch`` dtype (:func:`snell_bench.models.devices.parse_dtype`).
DTYPE_NAMES: dict[str, str] = {
    "bfloat16": "bfloat16",
    "bf16": "bfloat16",
    "float16": "float16",
    "fp16": "float16",
    "half": "float16",
    "float32": "float32",
    "fp32": "float32",
    "float": "float32",
}


def dtype_name(value: str) -> str:
    """The canonical torch dtype name of a ``model.dtype`` value (``" BF16"`` -> ``"bfloat16"``).
    Raises ``KeyError`` for an unknown name."""
    return DTYPE_NAMES[str(value).strip().lower().removeprefix("torch.")]
