"""The kit's schema: a changed kit is a new schema version; ids and the card."""

from snell_bench.kit.card import dataset_card
from snell_bench.kit.schema import FIELDS, FILE_FIELDS, KIT_VERSION, kit_id, schema_digest

#: The digest of each schema version's fields (names, types, units, descriptions, optionality). A
#: change of the fields without a new KIT_VERSION fails here: bump the version, add its digest.
DIGESTS = {
    "1.0": "0c90b8921e52e45e9f7e27ac86b2dfe27bf4820aa64103b835d644849e7808b6",
    "1.1": "b84ea5b69445cd0ec6900cfe1b61e892d16c1f588b167258637e23f4851c34c5",  # absorption
}


def test_a_changed_kit_is_a_new_schema_version():
    assert KIT_VERSION in DIGESTS, f"add the digest of version {KIT_VERSION}: {schema_digest()}"
    assert schema_digest() == DIGESTS[KIT_VERSION], (
        f"the kit's fields changed without a new KIT_VERSION (digest now {schema_digest()}): bump "
        "snell_bench.kit.schema.KIT_VERSION and add the new digest here"
    )


def test_fields_are_named_once_and_documented():
    names = [f.name for f in FIELDS]
    assert len(names) == len(set(names)) and names[0] == "id"
    assert all(f.description and f.type for f in FIELDS)
    assert set(FILE_FIELDS) <= set(names) and "checksums" in names


def test_ids_are_the_run_folders():
    assert kit_id("living_room", 3, "sphere-ior1.333") == "living_room-3/sphere-ior1.333"


def test_the_card_documents_every_field():
    meta = {
        "schema_digest": schema_digest(),
        "experiment": "x",
        "created_by": "snell_bench",
        "scoring": {"protocol": "paper", "files": "png"},
        "manifest_sha256": {"manifest.parquet": "ab"},
    }
    rows = [{"scene": "s", "object": "o", "licence_scene": "MIT", "licence_object": "CC0"}]
    card = dataset_card(meta, rows)
    assert card.startswith("---\n") and "configs:" in card and f"schema_version: '{KIT_VERSION}'" in card
    for f in FIELDS:
        assert f"| `{f.name}` |" in card, f.name
    assert "MIT" in card and "CC0" in card and "`manifest.parquet` | `ab`" in card
