"""The benchmark kit's schema: its version, its fields (what each is, its type, unit and convention),
its ids and its layout. One place: the exporter writes these fields, the dataset card documents
them, the readers check them.

Layout of a kit (``job=export``, ``<export.dir>/<experiment>/``)::

    README.md            the dataset card (YAML front matter for the Hugging Face Hub and ``datasets``)
    kit.json             the schema version, the experiment, the scoring settings, counts and checksums
    manifest.parquet     one row per (scene, variation, object) group: the fields of :data:`FIELDS`
    manifest.jsonl       the same rows as JSON Lines (no pandas needed)
    summary.json         the counts of the export's last run (exported, kept, failed)
    <scene>-<variation>/<object>/   the group's files (each named in its row, relative to the kit),
                         its config.yaml (the settings it was made with) and entry.json (its record)

A group's id is ``<scene>-<variation>/<object>`` (:func:`kit_id`), the same as its folder in the
run and in the kit; an image made for it is ``<id>.png`` in a submission folder
(``method.images``).

A changed kit is a new schema version: :data:`KIT_VERSION` names the fields and their meaning, and
``tests/kit/test_schema.py`` holds the digest of each version's fields (:func:`schema_digest`).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass

from snell_bench.config.grid import group_id

__all__ = [
    "KIT_VERSION",
    "KitField",
    "FIELDS",
    "FILE_FIELDS",
    "IMAGE_SUFFIXES",
    "MANIFEST",
    "MANIFEST_JSONL",
    "KIT_JSON",
    "CARD",
    "kit_id",
    "schema_digest",
]

#: The version of the kit's fields and layout. Bump it for any change a reader could notice (a field
#: added, removed, renamed, or a meaning, unit or convention changed).
#: 1.1: ``absorption``.
KIT_VERSION = "1.1"

MANIFEST = "manifest.parquet"
MANIFEST_JSONL = "manifest.jsonl"
KIT_JSON = "kit.json"
CARD = "README.md"

#: The image files a submission may hold for a group (``<id>.png`` first).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


@dataclass(frozen=True)
class KitField:
    """One field of a kit's rows.

    Attributes:
        name: the column.
        type: ``string``, ``int64``, ``float64``, ``bool``, ``list<float64>`` or ``file`` (a path
            relative to the kit folder, a string; null where the group has no such file).
        unit: its unit or convention.
        description: what it is.
        optional: null in some rows (a file the group does not have, a value not measured).
    """

    name: str
    type: str
    unit: str
    description: str
    optional: bool = False


_OPENCV = "OpenCV camera frame: x right, y down, z forward, camera at the origin; metres"

#: The fields of a kit's rows, in order.
FIELDS: tuple[KitField, ...] = (
    KitField("id", "string", "<scene>-<variation>/<object>", "the group's id; a submitted image is <id>.png"),
    KitField("schema_version", "string", "", "the kit's schema version (KIT_VERSION)"),
    KitField("experiment", "string", "", "the experiment the kit was exported from (experiment_name)"),
    KitField("scene", "string", "", "the scene's config name (conf/scene/<scene>.yaml)"),
    KitField("variation", "int64", "", "the variation: a seed offset of the scene and of the sampling"),
    KitField("object", "string", "", "the object's folder name (sphere, or sphere-ior1.333 with an IOR)"),
    KitField("object_name", "string", "", "the object's config name (conf/object/<name>.yaml)"),
    KitField("scene_source", "string", "procedural | image | generated", "where I⁻ comes from"),
    KitField("seed", "int64", "", "the group's sampling seed (seed + variation) the built-in methods use"),
    KitField("prompt", "string", "", "p: the full prompt, with the object"),
    KitField("prompt_minus", "string", "", "p⁻: the prompt without the object (the surface clean and empty)"),
    KitField("prompt_360", "string", "", "p³⁶⁰: the panorama's prompt, centred on the object"),
    KitField("object_phrase", "string", "", "p_obj: the object phrase of p"),
    KitField("surface", "string", "", "the surface the object stands on, as the prompt names it", True),
    KitField("clip_prompt", "string", "", "the text CLIP and ImageReward score an image against"),
    KitField("width", "int64", "pixels", "the image's width"),
    KitField("height", "int64", "pixels", "the image's height"),
    KitField("fx", "float64", "pixels", "focal length along x (K[0, 0])"),
    KitField("fy", "float64", "pixels", "focal length along y (K[1, 1])"),
    KitField("cx", "float64", "pixels, integer values at pixel centres", "principal point x (K[0, 2])"),
    KitField("cy", "float64", "pixels, integer values at pixel centres", "principal point y (K[1, 2])"),
    KitField("ior", "float64", "", "the object's index of refraction (air around it: 1)"),
    KitField(
        "absorption",
        "list<float64>",
        "per metre, linear R, G, B",
        "the object material's absorption coefficients σ: a path of length L inside keeps exp(-σ L) of its light "
        "(Beer–Lambert); [0, 0, 0]: clear",
    ),
    KitField(
        "object_pose",
        "list<float64>",
        "4 x 4 row-major, " + _OPENCV,
        "camera from object: the transform that places the canonical mesh (object_canonical) in the camera frame",
    ),
    KitField("object_up", "list<float64>", "unit vector, " + _OPENCV, "the supporting surface's normal (up)"),
    KitField("i_minus", "file", "PNG, 8-bit sRGB, width x height", "I⁻: the scene without the object"),
    KitField("depth", "file", "NumPy .npy float32 (height, width), metres along z; NaN: unknown", "I⁻'s depth"),
    KitField("camera", "file", "JSON: K, width, height (and a photo's resize)", "the camera of I⁻"),
    KitField("object_mesh", "file", "PLY (float32 coordinates), " + _OPENCV, "the object's closed mesh, placed"),
    KitField(
        "object_canonical",
        "file",
        "PLY (float32 coordinates), the object's own frame (y up)",
        "the object's mesh before placement",
    ),
    KitField("object_mask", "file", "PNG, 8-bit, 255 inside", "pixels whose camera ray hits the object first"),
    KitField("reference", "file", "PNG, 8-bit sRGB", "the reference render of the scene with the object", True),
    KitField(
        "reference_float",
        "file",
        "NumPy .npy float32 (height, width, 3), sRGB in [0, 1]",
        "the reference as scored (the PNG rounds it)",
        True,
    ),
    KitField(
        "metric_mask",
        "file",
        "PNG, 8-bit, 255 inside",
        "the scored pixels: object pixels whose refracted light comes from surfaces I⁻ shows",
        True,
    ),
    KitField(
        "unobserved",
        "file",
        "NumPy .npy float32 (height, width) in [0, 1]",
        "each pixel's share of refracted light from surfaces I⁻ does not show",
        True,
    ),
    KitField(
        "unobserved_mask",
        "file",
        "PNG, 8-bit, 255 inside",
        "object pixels left out of the metric mask: their light comes from surfaces I⁻ does not show",
        True,
    ),
    KitField("true_render", "file", "PNG, 8-bit sRGB", "a procedural scene's true render with the object", True),
    KitField(
        "true_render_float",
        "file",
        "NumPy .npy float32 (height, width, 3), sRGB in [0, 1]",
        "the true render as scored (PSNR (true), over object_mask)",
        True,
    ),
    KitField(
        "warps",
        "file",
        "NumPy .npz (snell_bench WarpSet): backward maps (H, W, 2) float32 x, y at pixel centres, NaN invalid",
        "π^R (refraction), π⁻¹ (pano_refraction), π^-R (pano_reflection), π (pano_to_persp), their masks, "
        "Fresnel reflectance (export.warps=true)",
        True,
    ),
    KitField("reference_reason", "string", "", "why the group has no reference (null where it has one)", True),
    KitField("reference_renderer", "string", "mitsuba | cycles", "the reference's renderer", True),
    KitField("reference_spp", "int64", "samples per pixel", "the reference's samples", True),
    KitField(
        "reference_self_noise_db",
        "float64",
        "dB",
        "the reference's self-noise: about the highest masked PSNR an image can score",
        True,
    ),
    KitField("licence_scene", "string", "", "the licence of I⁻ and its depth"),
    KitField("licence_object", "string", "", "the licence of the object's mesh"),
    KitField("checksums", "struct<string>", "SHA-256, hex", "each file field's SHA-256 (null where none)"),
)

#: The fields that are files (paths relative to the kit folder).
FILE_FIELDS = tuple(f.name for f in FIELDS if f.type == "file")


#: A group's id, ``<scene>-<variation>/<object>``: its folder in the run and in the kit.
kit_id = group_id


def schema_digest() -> str:
    """The SHA-256 of :data:`FIELDS` (names, types, units, descriptions, optionality) with
    :data:`KIT_VERSION`: a changed field is a changed digest, which a test holds to its version."""
    data = {"version": KIT_VERSION, "fields": [asdict(f) for f in FIELDS]}
    return hashlib.sha256(json.dumps(data, sort_keys=True, ensure_ascii=False).encode()).hexdigest()
