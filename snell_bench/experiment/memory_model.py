"""The memory guard's model (:mod:`snell_bench.experiment.memory`): a cell's peak host memory per
stage from the sizes of its images and its object's mesh.

The coefficients, what they hold and the peaks they were measured against: see
:mod:`snell_bench.experiment.memory` (images) and :mod:`snell_bench.experiment.memory_mesh` (the
object's mesh).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from snell_bench.config.choices import Source
from snell_bench.experiment.memory_mesh import MESH_BYTES_PER_FACE

__all__ = ["COEFFICIENTS", "MARGIN", "PROCEDURAL_SCENE", "STAGES", "MemoryEstimate", "stage_bytes"]

#: The stages whose peaks are estimated, in the order they run (``true_render``: procedural
#: scenes with ``reference.true_render``).
STAGES = ("scene", "warps", "reference", "true_render", "sampler", "metrics")
#: Per stage ``(base GB, a, b, c)``: the peak is ``base * 1e9 + a P + b Q + c P0`` bytes (the table
#: of :mod:`snell_bench.experiment.memory`). ``base`` holds the process with its libraries (Python,
#: PyTorch, Open3D, Hydra: 0.99 GB measured) and what a stage loads once (Mitsuba's LLVM back end).
COEFFICIENTS: dict[str, tuple[float, float, float, float]] = {
    "scene": (1.0, 100.0, 0.0, 30.0),
    "warps": (1.0, 520.0, 145.0, 0.0),
    "reference": (1.2, 2650.0, 30.0, 0.0),
    "true_render": (1.2, 950.0, 0.0, 0.0),
    "sampler": (1.25, 780.0, 360.0, 0.0),
    "metrics": (1.35, 550.0, 220.0, 0.0),
}
#: The scene stage of a procedural scene, which renders ``scene.supersample``² pixels per pixel
#: (``P0 = P x supersample²``).
PROCEDURAL_SCENE = (1.1, 250.0, 0.0, 30.0)
#: The estimate is the model times this: the model lies above every measured peak, and the margin
#: covers images larger than the largest measured (4.3 Mpx) and other scene content.
MARGIN = 1.15


def stage_bytes(
    pixels: float,
    pano_pixels: float,
    read_pixels: float,
    *,
    reference: bool = True,
    true_render: bool = False,
    procedural: bool = False,
    faces: float = 0,
) -> dict[str, float]:
    """The model's peak bytes per stage (:mod:`snell_bench.experiment.memory`), :data:`MARGIN` included.

    Args:
        pixels: ``P``, pixels of I⁻.
        pano_pixels: ``Q``, pixels of the panorama.
        read_pixels: ``P0``, pixels of the photo as read (of a procedural scene: ``P`` times
            ``scene.supersample``²).
        reference: whether the reference is rendered (``reference.enabled``).
        true_render: whether the true render of a procedural scene is (``reference.true_render``).
        procedural: a procedural scene (its scene stage is :data:`PROCEDURAL_SCENE`).
        faces: faces of the object's mesh (:data:`~snell_bench.experiment.memory_mesh.MESH_BYTES_PER_FACE`
            each, in every stage).

    Returns:
        ``{stage: bytes}`` for the stages that run.

    Examples:
        >>> round(stage_bytes(640 * 480, 512 * 1024, 640 * 480)["reference"] / 1e9, 2)
        2.33
    """
    out = {}
    for stage in STAGES:
        if (stage == "reference" and not reference) or (stage == "true_render" and not true_render):
            continue
        base, a, b, c = PROCEDURAL_SCENE if (stage == "scene" and procedural) else COEFFICIENTS[stage]
        out[stage] = MARGIN * (
            base * 1e9 + a * pixels + b * pano_pixels + c * read_pixels + MESH_BYTES_PER_FACE * faces
        )
    return out


@dataclass(frozen=True)
class MemoryEstimate:
    """A cell's estimated peak host memory (:func:`estimate_memory`).

    Attributes:
        size: ``(width, height)`` of I⁻ as the cell uses it.
        pano_height: ``warps.pano_height`` (the panorama is twice as wide).
        source: ``scene.source``.
        scene: ``scene.name``.
        read_size: ``(width, height)`` of the photo as read (upright, before ``scene.max_side``);
            ``None`` for other sources.
        supersample: ``scene.supersample`` of a procedural scene (1 otherwise).
        reference: whether the reference is rendered.
        true_render: whether the true render of a procedural scene is.
        photo: what :func:`~snell_bench.scene.image_source.inspect_photo` found (photos only).
        faces: faces of the object's mesh (a bound from above where not ``faces_exact``).
        mesh: the setting they come from (``object.path=<path>``, ``object=<name>``).
        faces_exact: whether ``faces`` was counted rather than bounded by the file's size.
    """

    size: tuple[int, int]
    pano_height: int
    source: str
    scene: str = ""
    read_size: tuple[int, int] | None = None
    supersample: int = 1
    reference: bool = True
    true_render: bool = False
    photo: dict | None = field(default=None, compare=False)
    faces: int = 0
    mesh: str = ""
    faces_exact: bool = True

    def at(self, size: tuple[int, int] | None = None, pano_height: int | None = None) -> dict[str, float]:
        """Bytes per stage at ``size`` and ``pano_height`` (default: the cell's own); a photo is
        still read at its own size."""
        w, h = self.size if size is None else size
        ph = self.pano_height if pano_height is None else int(pano_height)
        read = w * h * self.supersample**2 if self.read_size is None else self.read_size[0] * self.read_size[1]
        procedural = self.source == Source.procedural.value
        flags = dict(reference=self.reference, true_render=self.true_render, procedural=procedural)
        return stage_bytes(w * h, 2 * ph * ph, read, faces=self.faces, **flags)

    @property
    def stages(self) -> dict[str, float]:
        """Bytes at the peak of each stage that runs (:data:`STAGES`)."""
        return self.at()

    @property
    def peak_bytes(self) -> float:
        """Bytes at the cell's peak: the largest stage's."""
        return max(self.stages.values())

    @property
    def stage(self) -> str:
        """The stage that peaks."""
        stages = self.stages
        return max(stages, key=stages.get)

    @property
    def mesh_bytes(self) -> float:
        """Bytes of the object's mesh in each stage, :data:`MARGIN` included."""
        return MARGIN * MESH_BYTES_PER_FACE * self.faces

    def describe(self) -> str:
        """``"scene=<name>: a cell needs about <GB> of host memory at its peak (<stage> ...)"``; the
        object's mesh named where it takes 0.1 GB or more (``object.path=<path> has <n> faces: about
        <GB>``)."""
        w, h = self.size
        photo = mesh = ""
        if self.read_size is not None and tuple(self.read_size) != (w, h):
            photo = f" from a photo of {self.read_size[0]}x{self.read_size[1]}"
        if self.mesh_bytes >= 0.05e9:
            count = f"{self.faces:,} faces" if self.faces_exact else f"at most {self.faces:,} faces (by its file size)"
            mesh = f"; {self.mesh} has {count}: about {_gb(self.mesh_bytes)}"
        return (
            f"scene={self.scene}: a cell needs about {_gb(self.peak_bytes)} of host memory at its peak (the "
            f"{self.stage} stage, I⁻ of {w}x{h}{photo}, panorama {2 * self.pano_height}x{self.pano_height}{mesh})"
        )

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: GB per stage, the peak, the stage and the sizes."""
        return {
            "peak_gb": round(self.peak_bytes / 1e9, 3),
            "stage": self.stage,
            "stages_gb": {k: round(v / 1e9, 3) for k, v in self.stages.items()},
            "size": list(self.size),
            "read_size": None if self.read_size is None else list(self.read_size),
            "pano_height": self.pano_height,
            "source": self.source,
            "scene": self.scene,
            "faces": self.faces,
            "mesh_gb": round(self.mesh_bytes / 1e9, 3),
        }


def _gb(b: float) -> str:
    return f"{b / 1e9:.1f} GB"
