"""Images for a snellcaster benchmark kit, made from the kit alone (numpy, scipy and Pillow: no
snell_bench needed), then scored as any method's are.

    python -m snell_bench +experiment=smoke job=export export.warps=true     # the kit: kits/smoke/
    python examples/make_images.py kits/smoke my_images                     # one image per group
    python -m snell_bench +experiment=smoke 'grid.methods=[snellcaster,t2i,images]' method.images=my_images

Each image is I⁻ seen through the glass by the kit's own warps: every object pixel takes the colour
of I⁻ where its refracted ray lands (π^R, bilinear), the others keep I⁻. A group exported without
warps (``export.warps=false``) gets I⁻ itself, the object-free image. ``--score`` also scores each
image against the kit in this process (``snell_bench.kit.score_image``), as the grid will.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from PIL import Image
from scipy.ndimage import map_coordinates


def through_the_glass(i_minus: np.ndarray, warps_file: Path) -> np.ndarray:
    """``i_minus`` (H, W, 3) uint8 with each object pixel sampled at its refraction warp π^R (x, y at
    pixel centres, NaN where the refracted ray ends nowhere I⁻ shows)."""
    with np.load(warps_file, allow_pickle=False) as z:
        coords, inside = z["refraction"], z["object_mask"]
    ok = inside & np.isfinite(coords).all(-1)
    out = i_minus.astype(np.float64)
    x, y = coords[ok, 0], coords[ok, 1]
    for c in range(3):
        out[ok, c] = map_coordinates(i_minus[..., c].astype(np.float64), [y, x], order=1, mode="nearest")
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("kit", type=Path, help="the kit's folder (job=export)")
    parser.add_argument("out", type=Path, help="where the images go: <out>/<id>.png")
    parser.add_argument("--score", action="store_true", help="also score each image against the kit")
    args = parser.parse_args()
    rows = [json.loads(line) for line in (args.kit / "manifest.jsonl").read_text(encoding="utf-8").splitlines() if line]
    for row in rows:
        i_minus = np.asarray(Image.open(args.kit / row["i_minus"]).convert("RGB"))
        image = through_the_glass(i_minus, args.kit / row["warps"]) if row.get("warps") else i_minus
        path = args.out / f"{row['id']}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(image).save(path)
        line = f"{row['id']}: {path}"
        if args.score:
            from snell_bench.kit import load_kit, score_image

            scores = score_image(path, row, load_kit(args.kit))
            line += "  " + ", ".join(f"{k} {v:.4g}" for k, v in scores["metrics"].items() if v is not None)
        print(line)
    print(f"{len(rows)} images in {args.out}; score them with method=images method.images={args.out}")


if __name__ == "__main__":
    main()
