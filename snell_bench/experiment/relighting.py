"""``job=relight`` (``+experiment=relighting``): the relighting methods against a path-traced truth on
procedural scenes, and its table and figure.

For every procedural scene of ``grid.scenes`` and object of ``grid.objects``: the scene's true
render with the glass (:func:`~snell_bench.pipeline.inputs.render_true_scene`) is the image every
relighter gets, so that only the light differs; the truth is that scene relit by its own lights,
path traced (:func:`~snell_bench.render.light_truth.light_truth`); each method of
:data:`METHODS` relights the image and is scored (:func:`~snell_bench.metrics.relighting.relight_scores`).

Files: ``runs/<experiment>/<scene>-<variation>/<object>/``: ``scores.json`` (a finished cell: it is
kept, delete the folder to recompute it), ``unrelit.png``, ``truth.png``, ``<method>.png``,
``<method>_ratio.png``; ``reports/<experiment>/``: ``relighting.csv``, ``relighting.md`` and
``relighting.png`` (the truth, each method and their ratio images per cell).
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from omegaconf import DictConfig

from snell_bench.config.choices import Source
from snell_bench.metrics.relighting import RELIGHT_METRICS, relight_scores
from snell_bench.reports.writers import csv_safe
from snell_bench.utils.io import write_text

log = logging.getLogger(__name__)

__all__ = ["METHODS", "relighting_table", "run_relighting"]

#: The relighting methods scored, in the table's order: what each one is.
METHODS = {
    "none": "the image as it is (no shadow, no caustic)",
    "shadow": "the CPU stand-in: a traced soft shadow under a jittered directional light, no caustics",
    "traced_true": "relight=traced with the scene's own lights",
    "traced": "relight=traced with the lights estimated from the panorama at the object",
    "kontext": "FLUX.1 Kontext (the paper's relighting), where its weights and a GPU are there",
}


def _relighter(name: str, cfg: DictConfig):
    from snell_bench.relight.shadow import ShadowRelighter
    from snell_bench.relight.traced import TracedRelighter

    node = cfg.relight.get("relighter") or {}
    settings = {k: node[k] for k in node if k not in ("_target_", "lights")}  # the config's settings, all of them
    if name == "shadow":
        return ShadowRelighter()
    if name in ("traced", "traced_true"):
        return TracedRelighter(lights="true" if name == "traced_true" else "panorama", **settings)
    raise KeyError(name)


def _cell(cfg: DictConfig, scene_name: str, obj_name: str, folder: Path) -> list[dict]:
    """Relight one cell with every method and score it; the rows of the table."""
    from PIL import Image

    from snell_bench.experiment.plan import compose_cell
    from snell_bench.pipeline.inputs import prepare_inputs, render_true_scene
    from snell_bench.render.light_truth import light_truth

    c = compose_cell(cfg, [f"scene={scene_name}", f"object={obj_name}"], method=False)
    if c.scene.source is not Source.procedural:
        return [
            {"scene": scene_name, "object": obj_name, "method": m, "missing": "not a procedural scene"} for m in METHODS
        ]
    inputs = prepare_inputs(c, references=False)
    scene, obj, ws = inputs.scene, inputs.obj, inputs.warps
    true = render_true_scene(c, scene, obj)
    t0 = time.perf_counter()
    truth = light_truth(scene.source, scene.camera, scene.image, obj, spp=c.relight.truth_spp, seed=c.seed)
    truth_s = time.perf_counter() - t0
    receivers = truth.receivers
    # the image every method relights: I⁻ where the truth is scored, the true render elsewhere
    unrelit = np.where(receivers[..., None], scene.image, true).astype(np.float32)
    truth_image = np.where(receivers[..., None], truth.image, true)
    pano_cam = ws.pano
    height = min(int(c.warps.pano_height), 512)
    panorama = scene.source.render_panorama(
        pano_cam.center, height, up=-pano_cam.rotation[:, 1], forward=pano_cam.rotation[:, 2]
    )
    folder.mkdir(parents=True, exist_ok=True)
    save = lambda name, img: Image.fromarray((np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)).save(folder / name)  # noqa: E731
    save("unrelit.png", unrelit)
    save("truth.png", truth_image)
    image = torch.from_numpy(np.ascontiguousarray(unrelit.transpose(2, 0, 1)))[None].float()
    base = {
        "scene": scene_name,
        "object": obj_name,
        "truth_noise_db": truth.self_noise_db,
        "truth_seconds": round(truth_s, 2),
    }
    rows = []
    for name in METHODS:
        row = {**base, "method": name}
        t0 = time.perf_counter()
        if name == "none":
            relit = unrelit
        elif name == "kontext":
            rows.append(
                {
                    **row,
                    "missing": "FLUX.1 Kontext needs its weights and a GPU (model=flux_dev method=snellcaster_relit)",
                }
            )
            continue
        else:
            out = _relighter(name, c).relight(image, seed=c.seed, scene=scene, obj=obj, warps=ws, panorama=panorama)
            relit = out[0].numpy().transpose(1, 2, 0)
        row["seconds"] = round(time.perf_counter() - t0, 2)
        save(f"{name}.png", relit)
        row.update(relight_scores(relit, unrelit, truth_image, unrelit, receivers))
        rows.append(row)
    return rows


def run_relighting(cfg: DictConfig) -> int:
    """``job=relight``: every cell (a finished one kept), then the table and the figure."""
    root = Path(cfg.runs_dir) / cfg.experiment_name
    rows = []
    for scene_name in cfg.grid.scenes:
        for obj_name in cfg.grid.objects:
            folder = root / f"{scene_name}-{cfg.grid.variations[0] if cfg.grid.variations else 0}" / str(obj_name)
            done = folder / "scores.json"
            if done.is_file():
                rows += json.loads(done.read_text())
                log.info("relighting %s/%s: already done", scene_name, obj_name)
                continue
            cell = _cell(cfg, str(scene_name), str(obj_name), folder)
            folder.mkdir(parents=True, exist_ok=True)
            tmp = folder / "scores.json.tmp"
            tmp.write_text(json.dumps(_json_safe(cell), indent=1, allow_nan=False))
            tmp.replace(done)
            rows += json.loads(done.read_text())
    out = Path(cfg.reports_dir) / cfg.experiment_name
    write_report(rows, root, out)
    print(relighting_table(rows).to_string(index=False))
    return 0


def _json_safe(x):
    """Rows as JSON: numpy numbers as Python's, non-finite floats as ``None``."""
    if isinstance(x, list):
        return [_json_safe(v) for v in x]
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, (np.integer, np.bool_)):
        return x.item()
    if isinstance(x, (float, np.floating)):
        return float(x) if np.isfinite(x) else None
    return x


def relighting_table(rows: list[dict]) -> pd.DataFrame:
    """The per-cell scores, then each method's mean over the cells (``scene = "mean"``).

    ``noise_gap_db`` is the truth's self-noise less the method's region PSNR: a perfect relighting
    scores the self-noise (gap 0 up to the noise estimate's own spread); under ``10 log10 2 = 3.01``
    dB the method's own error is smaller than the truth's noise (its mean squared error is the sum
    of the two)."""
    df = pd.DataFrame(rows)
    for k in RELIGHT_METRICS:
        if k not in df:
            df[k] = np.nan
    if "truth_noise_db" in df:  # a perfect relighting scores the truth's self-noise: what is left is the method's
        df["noise_gap_db"] = df["truth_noise_db"] - df["psnr_region"]
    cols = ["scene", "object", "method", *RELIGHT_METRICS, "truth_noise_db", "noise_gap_db", "seconds"]
    df = df.reindex(columns=[c for c in cols if c in df] + (["missing"] if "missing" in df else []))
    averaged = [c for c in [*RELIGHT_METRICS, "noise_gap_db", "seconds"] if c in df]
    means = df.groupby("method", sort=False)[averaged].mean(numeric_only=True).reset_index()
    means.insert(0, "object", "")
    means.insert(0, "scene", "mean")
    return pd.concat([df, means], ignore_index=True)


def write_report(rows: list[dict], runs: Path, out: Path) -> None:
    """``relighting.csv`` (atomically; every string that starts like a formula with a ``'`` in front,
    :func:`~snell_bench.reports.writers.csv_safe`), ``relighting.md`` and ``relighting.png`` under
    ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    table = relighting_table(rows)
    write_text(out / "relighting.csv", csv_safe(table).to_csv(index=False, lineterminator="\n"))
    lines = ["# Relighting against a path-traced truth", "", "Methods:", ""]
    lines += [f"- `{k}`: {v}" for k, v in METHODS.items()]
    lines += [
        "",
        table.to_markdown(index=False, floatfmt=".3g"),
        "",
        "![the truth, each method, ratio images](relighting.png)",
        "",
    ]
    (out / "relighting.md").write_text("\n".join(lines))
    _figure(rows, runs, out / "relighting.png")


def _figure(rows: list[dict], runs: Path, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from snell_bench.reports.canvas import load_rgb

    cells = sorted({(r["scene"], r["object"]) for r in rows})
    shown = ["truth"] + [m for m in METHODS if any(r["method"] == m and "missing" not in r for r in rows)]
    if not cells:
        return
    fig, axes = plt.subplots(2 * len(cells), len(shown), figsize=(2.6 * len(shown), 3.0 * len(cells)), squeeze=False)
    for i, (scene, obj) in enumerate(cells):
        folder = next((p for p in runs.glob(f"{scene}-*/{obj}") if p.is_dir()), None)
        if folder is None:
            continue
        unrelit = load_rgb(folder / "unrelit.png", runs)  # bounded, no link followed (utils.trust)
        if unrelit is None:
            continue
        for j, name in enumerate(shown):
            f = folder / f"{name}.png"
            ax, axr = axes[2 * i, j], axes[2 * i + 1, j]
            ax.axis("off")
            axr.axis("off")
            img = load_rgb(f, runs)
            if img is None:
                continue
            ax.imshow(img)
            ax.set_title(f"{name}\n{scene}/{obj}" if j == 0 else name, fontsize=8)
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = np.where(unrelit > 1e-3, (img / unrelit) ** 2.2, 1.0).mean(-1)
            axr.imshow(np.clip(ratio, 0, 2), cmap="coolwarm_r", vmin=0, vmax=2)
            axr.set_title("ratio (0-2)", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
