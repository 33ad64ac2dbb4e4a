"""``method.kind=images``: score images made anywhere (another sampler, a closed model behind an
API, a 3-D renderer, an artist) by exactly the protocol, references and masks of the built-in
methods, as a row of their own in every table, figure and page.

``method.images`` is a folder of one image per (scene, variation, object) group, named by the
benchmark kit's ids (``<folder>/<scene>-<variation>/<object>.png``, or ``.jpg``), or a manifest file
with the columns ``id`` and ``method.images_column`` (:func:`~snell_bench.kit.read.submitted_images`).
Nothing outside that folder is read (a path or a link that leads out is refused). A group without
an image is ``skipped`` with the reason (a missing value in the tables, never a number); an image
that cannot be read or has another size than the group's camera fails its cell, naming the file and
the size expected; with ``method.kit`` the kit the images were made from must be this run's (its
schema version, and each group's camera, I⁻ and object).

A finished cell is known by its image's content: a changed, added or removed image makes it
unfinished again (:meth:`Images.stale`).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from snell_bench.kit.read import Kit, KitError, inside, load_kit, read_image, submitted_images
from snell_bench.kit.schema import kit_id
from snell_bench.methods.base import Method
from snell_bench.methods.cost import Basis, Estimate, ModelNeed
from snell_bench.optics.warps import WarpSet
from snell_bench.pipeline.cell import CellInputs, CellResult, Skip
from snell_bench.utils.io import file_sha256, from_uint8, to_uint8
from snell_bench.utils.tensors import hwc_to_bchw
from snell_bench.utils.timing import Timer

__all__ = ["Images", "DEFAULT_LABEL", "group_of", "kit_problems"]

#: ``conf/method/images.yaml``'s label: the rows are then labelled by the submission's folder.
DEFAULT_LABEL = "Images"


def _source(cfg: DictConfig) -> tuple[Path, dict[str, Path]]:
    if not cfg.method.get("images"):
        raise KitError(
            f"method={cfg.method.name} (kind images) needs method.images: the folder of <scene>-<variation>/<object>.png "
            "images (the kit's ids, job=export) or a manifest file with columns id and image"
        )
    # read at every cell, not once: images may be added while a grid runs
    return submitted_images(cfg.method.images, str(cfg.method.get("images_column") or "image"))


def group_of(cfg: DictConfig, inputs: CellInputs | None = None) -> str:
    """The kit id of a cell: the grid's group (``inputs.group``), else from the config's scene,
    variation and object name."""
    if inputs is not None and inputs.group:
        return inputs.group
    return kit_id(cfg.scene.name, cfg.scene.variation, cfg.object.name)


@functools.lru_cache(maxsize=4)
def _kit(folder: str) -> Kit:
    return load_kit(folder)


def kit_problems(kit: Kit, group: str, inputs: CellInputs) -> list[str]:
    """How this run's inputs of ``group`` differ from the kit's row (the images were made from the
    kit): the group is missing, or its camera, IOR, absorption, object or I⁻ differ beyond float rounding
    (intrinsics 1e-6 relative; vertices 1e-5 of the object's size; I⁻ at most one 8-bit level in at
    most 0.1 % of the pixels: a last-bit difference between machines can flip a rounding)."""
    row = kit.row(group)
    if row is None:
        return [f"the kit {kit.folder} has no group {group}"]
    out = []
    cam = inputs.scene.camera
    if (int(row["width"]), int(row["height"])) != (cam.width, cam.height):
        out.append(f"its image is {row['width']} x {row['height']}, this run's {cam.width} x {cam.height}")
    K = np.array([row["fx"], row["fy"], row["cx"], row["cy"]], np.float64)
    ours = np.array([cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]], np.float64)
    if not np.allclose(K, ours, rtol=1e-6, atol=1e-9):
        out.append(f"its intrinsics (fx, fy, cx, cy) are {K.tolist()}, this run's {ours.tolist()}")
    if abs(float(row["ior"]) - float(inputs.obj.ior)) > 1e-9:
        out.append(f"its IOR is {row['ior']}, this run's {inputs.obj.ior}")
    if not np.allclose(row["absorption"], inputs.obj.absorption, rtol=1e-9, atol=1e-12):
        out.append(f"its absorption is {list(row['absorption'])} per metre, this run's {list(inputs.obj.absorption)}")
    import trimesh

    mesh = trimesh.load(kit.path(row, "object_mesh"), process=False, force="mesh")
    v = np.asarray(inputs.obj.vertices, np.float64)
    scale = float(np.ptp(v, axis=0).max()) or 1.0
    if mesh.vertices.shape != v.shape or np.abs(mesh.vertices - v).max() > 1e-5 * scale:
        out.append("its object is another shape, size or placement")
    kit_i = kit.array(row, "i_minus")
    ours_i = to_uint8(inputs.scene.image)
    if kit_i is None or kit_i.shape != ours_i.shape:
        out.append("its I⁻ has another size")
    else:
        diff = np.abs(kit_i.astype(np.int16) - ours_i.astype(np.int16))
        if diff.max() > 1 or (diff > 0).mean() > 1e-3:
            out.append(f"its I⁻ differs ({(diff > 0).mean():.2%} of the values, by up to {int(diff.max())} levels)")
    return out


class Images(Method):
    """Images made anywhere, read from ``method.images`` (see the module's docs)."""

    kind = "images"
    description = "images made anywhere (method.images), scored as the built-in methods are"

    def run(self, cfg: DictConfig, inputs: CellInputs, warps: WarpSet, t: Timer) -> CellResult:
        folder, images = _source(cfg)
        group = group_of(cfg, inputs)
        if group not in images:
            raise Skip(
                f"no image for {group} in {cfg.method.images} (expected {group}.png there, or a row with id {group}): "
                "a missing value, not a score"
            )
        if cfg.method.get("kit"):
            problems = kit_problems(_kit(cfg.method.kit), group, inputs)
            if problems:
                raise KitError(
                    f"the image {images[group]} was made from the kit method.kit={cfg.method.kit!r}, whose group "
                    f"{group} is not this run's: {'; '.join(problems)}. Run with the kit's settings, or export the kit "
                    "again from this run and make the image from it"
                )
        cam = inputs.scene.camera
        with t("sampling"):
            pixels = read_image(folder, images[group], (cam.width, cam.height))
        path = inside(folder, images[group])
        stats = {"images": {"file": images[group].as_posix(), "folder": str(folder), "sha256": file_sha256(path)}}
        return CellResult(image=hwc_to_bchw(from_uint8(pixels)), warps=warps, stats=stats)

    def cost(self, scene_cfg: DictConfig, cfg: DictConfig, models: Sequence[ModelNeed], basis: Basis) -> Estimate:
        return Estimate((0.0, 0.0), 0.0, None, "CPU", "images made elsewhere: one file read (and the metrics)")

    def row_label(self, cfg: DictConfig) -> str:
        label = cfg.method.label
        if label == DEFAULT_LABEL and cfg.method.get("images"):
            return f"{DEFAULT_LABEL}: {Path(cfg.method.images).expanduser().name}"
        return label

    def stale(self, cfg: DictConfig, record: dict, folder: Path, group: str) -> str | None:
        try:
            root, images = _source(cfg)
        except KitError as e:
            return str(e)
        recorded = (record.get("images") or {}).get("sha256")
        if group not in images:
            return None if record.get("status") == "skipped" else f"its image ({group}) is gone from {root}"
        if record.get("status") == "skipped":
            return f"an image for {group} has been added to {root}"
        try:
            now = file_sha256(inside(root, images[group]))
        except (KitError, OSError) as e:
            return str(e)
        return None if now == recorded else f"its image {images[group]} has changed since the cell finished"

    def check(self, cfg: DictConfig, group: str) -> list[str]:
        try:
            root, images = _source(cfg)
            if cfg.method.get("kit"):
                _kit(cfg.method.kit)
            if group in images:
                inside(root, images[group], f"the image of {group}")
        except KitError as e:
            return [str(e)]
        return []
