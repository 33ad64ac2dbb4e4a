"""The benchmark kit: the inputs a method needs and the truth it is scored against, per (scene,
variation, object) group, in one documented, versioned layout (``job=export`` writes it,
:mod:`snell_bench.experiment.export`).

- :mod:`.schema`: the version, the fields (type, unit, convention), the ids and the layout;
- :mod:`.read`: reading a kit and a folder of submitted images, nothing outside their folders;
- :mod:`.score`: one image against one kit row, as a grid cell scores it (:func:`score_image`).

Read it with ``datasets.load_dataset("parquet", data_files="<kit>/manifest.parquet")``, with pandas
(``pd.read_parquet``), or with the standard library (``manifest.jsonl``, :func:`load_kit`).
"""

from snell_bench.kit.read import Kit, KitError, inside, load_kit, read_image, submitted_images
from snell_bench.kit.schema import FIELDS, FILE_FIELDS, KIT_VERSION, KitField, kit_id, schema_digest
from snell_bench.kit.score import score_image

__all__ = [
    "FIELDS",
    "FILE_FIELDS",
    "KIT_VERSION",
    "Kit",
    "KitError",
    "KitField",
    "inside",
    "kit_id",
    "load_kit",
    "read_image",
    "schema_digest",
    "score_image",
    "submitted_images",
]
