"""Reading a kit and a submission: nothing outside the folder, sizes and modes checked from the
header, every refusal naming the file and the fix."""

import json
import os

import numpy as np
import pytest
from PIL import Image

from snell_bench.kit.read import KitError, inside, load_kit, read_image, submitted_images
from snell_bench.kit.schema import KIT_VERSION


def _png(path, w=8, h=6, mode="RGB", value=0):
    path.parent.mkdir(parents=True, exist_ok=True)
    if mode == "I;16":
        Image.fromarray(np.full((h, w), 1000, np.uint16)).save(path)
    else:
        Image.new(mode, (w, h), value).save(path)
    return path


class TestInside:
    def test_paths_inside_pass_and_the_rest_is_refused(self, tmp_path):
        (tmp_path / "sub").mkdir()
        assert inside(tmp_path, "sub/a.png") == (tmp_path / "sub" / "a.png").resolve()
        for bad in ("../x.png", "/etc/passwd", "sub/../../x.png"):
            with pytest.raises(KitError, match="leads outside the folder"):
                inside(tmp_path, bad)

    def test_a_link_to_a_file_elsewhere_is_refused(self, tmp_path):
        outside = _png(tmp_path / "elsewhere.png")
        folder = tmp_path / "sub"
        (folder / "k-0").mkdir(parents=True)
        os.symlink(outside, folder / "k-0" / "sphere.png")
        with pytest.raises(KitError, match="leads outside the folder"):
            inside(folder, "k-0/sphere.png")


class TestReadImage:
    def test_an_rgb_png_of_the_right_size(self, tmp_path):
        _png(tmp_path / "a.png", value=(10, 20, 30))
        px = read_image(tmp_path, "a.png", (8, 6))
        assert px.dtype == np.uint8 and px.shape == (6, 8, 3) and px[0, 0].tolist() == [10, 20, 30]

    def test_gray_and_palette_images_are_read_as_rgb(self, tmp_path):
        _png(tmp_path / "g.png", mode="L", value=77)
        assert read_image(tmp_path, "g.png", (8, 6))[2, 3].tolist() == [77, 77, 77]

    def test_another_size_names_the_file_and_the_size_expected(self, tmp_path):
        _png(tmp_path / "a.png", w=9)
        with pytest.raises(KitError, match=r"a.png is 9 x 6 pixels; the group's camera is 8 x 6"):
            read_image(tmp_path, "a.png", (8, 6))

    def test_16_bit_and_unreadable_files_are_refused(self, tmp_path):
        _png(tmp_path / "deep.png", mode="I;16")
        with pytest.raises(KitError, match="mode 'I;16'.*8-bit"):
            read_image(tmp_path, "deep.png", (8, 6))
        (tmp_path / "bad.png").write_bytes(b"not an image")
        with pytest.raises(KitError, match="bad.png cannot be read as an image"):
            read_image(tmp_path, "bad.png", (8, 6))

    def test_a_huge_header_is_refused_before_decoding(self, tmp_path):
        path = tmp_path / "bomb.png"
        Image.new("L", (9000, 9000)).save(path)  # 81 Mpx: over the limit, refused from the header
        with pytest.raises(KitError, match="9000 x 9000 pixels is not an image of this benchmark"):
            read_image(tmp_path, "bomb.png", (8, 6))


class TestSubmissions:
    def test_a_folder_of_kit_ids(self, tmp_path):
        _png(tmp_path / "kitchen-0" / "sphere.png")
        _png(tmp_path / "kitchen-1" / "fox.jpg")
        (tmp_path / "notes.txt").write_text("x")
        folder, images = submitted_images(tmp_path)
        assert folder == tmp_path
        assert {k: v.as_posix() for k, v in images.items()} == {
            "kitchen-0/sphere": "kitchen-0/sphere.png",
            "kitchen-1/fox": "kitchen-1/fox.jpg",
        }

    def test_two_images_of_one_group_are_refused(self, tmp_path):
        _png(tmp_path / "kitchen-0" / "sphere.png")
        _png(tmp_path / "kitchen-0" / "sphere.jpg")
        with pytest.raises(KitError, match="two images for kitchen-0/sphere"):
            submitted_images(tmp_path)

    @pytest.mark.parametrize("suffix", [".csv", ".jsonl", ".parquet"])
    def test_a_manifest_file(self, tmp_path, suffix):
        import pandas as pd

        table = pd.DataFrame({"id": ["kitchen-0/sphere", "cafe-0/sphere"], "file": ["a/x.png", ""]})
        path = tmp_path / f"m{suffix}"
        {
            ".csv": lambda: table.to_csv(path, index=False),
            ".jsonl": lambda: table.to_json(path, orient="records", lines=True),
            ".parquet": lambda: table.to_parquet(path),
        }[suffix]()
        folder, images = submitted_images(path, "file")
        assert folder == tmp_path and {k: v.as_posix() for k, v in images.items()} == {"kitchen-0/sphere": "a/x.png"}
        with pytest.raises(KitError, match=r"no column\(s\) \['image'\]"):
            submitted_images(path)

    def test_a_missing_source_names_the_key(self, tmp_path):
        with pytest.raises(KitError, match="method.images='.*nope' is neither a folder nor a file"):
            submitted_images(tmp_path / "nope")


class TestLoadKit:
    def test_no_kit_and_another_version_are_refused_naming_the_fix(self, tmp_path):
        with pytest.raises(KitError, match="is not a benchmark kit.*job=export"):
            load_kit(tmp_path)
        (tmp_path / "kit.json").write_text(json.dumps({"schema_version": "0.9"}))
        with pytest.raises(KitError, match=f"schema version '0.9'; this snell_bench reads version '{KIT_VERSION}'"):
            load_kit(tmp_path)

    def test_rows_are_read_without_pandas(self, tmp_path):
        (tmp_path / "kit.json").write_text(json.dumps({"schema_version": KIT_VERSION}))
        (tmp_path / "manifest.jsonl").write_text('{"id": "a-0/sphere", "i_minus": "a-0/sphere/I_minus.png"}\n\n')
        kit = load_kit(tmp_path)
        assert [r["id"] for r in kit.rows] == ["a-0/sphere"] and kit.row("nope") is None
        row = dict(kit.rows[0], i_minus="../../etc/passwd")
        with pytest.raises(KitError, match="i_minus of a-0/sphere '../../etc/passwd' leads outside"):
            kit.path(row, "i_minus")
