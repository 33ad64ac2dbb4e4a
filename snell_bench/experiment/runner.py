"""The grid runner: cells = (scene, variation, object, method), shared inputs, resume, reports.

Layout of an experiment ``E`` under ``runs/``::

    runs/E/<scene>-<variation>/<object>/_inputs/     I⁻, depth, camera, object, warps key, references
    runs/E/<scene>-<variation>/<object>/<method>/    image.png reference.png mask.png metrics.json
                                                     config.yaml I_minus.png depth.npy camera.json object.ply

- Everything a (scene, variation, object) needs, I⁻, depth, warps (content-hashed cache), the
  reference renders, is computed once and shared by every method of that group.
- Every file is written atomically (temporary file, then rename) and ``metrics.json`` last, so a
  cell with a ``metrics.json`` is complete. Re-running skips complete cells (``grid.recompute=true``
  redoes them); an interrupt loses no finished cell.
- A failing cell records its error in its ``metrics.json`` (``status: failed``) and the sweep goes
  on; a method that cannot run here (no GPU, no weights) is ``skipped`` with the reason.
- Several processes (Hydra multirun with the joblib or submitit launchers) can share one
  experiment folder: give each a disjoint part of the grid, e.g. ``grid.scenes=[a],[b]``.
"""

from __future__ import annotations

import itertools
import json
import logging
import os
import shutil
import tempfile
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tqdm.auto import tqdm

from snell_bench.experiment.preview import save_png

log = logging.getLogger(__name__)

__all__ = ["run_grid", "cell_config", "parse_object_spec", "load_group"]

_CONF = Path(__file__).resolve().parents[2] / "conf"


# ---------------------------------------------------------------------------- configs
def load_group(group: str, name: str) -> DictConfig:
    """A config group entry (``conf/<group>/<name>.yaml``) without its defaults list."""
    path = _CONF / group / f"{name}.yaml"
    if not path.is_file():
        options = sorted(p.stem for p in (_CONF / group).glob("*.yaml"))
        raise ValueError(f"unknown {group} {name!r}; choose from {options} (conf/{group}/)")
    node = OmegaConf.load(path)
    node.pop("defaults", None)
    return node


def parse_object_spec(spec: str) -> tuple[str, float | None]:
    """``"sphere"`` or ``"sphere:1.33"`` (a material override)."""
    name, _, ior = str(spec).partition(":")
    return name, (float(ior) if ior else None)


def object_dir_name(spec: str) -> str:
    name, ior = parse_object_spec(spec)
    return name if ior is None else f"{name}-ior{format(ior, '.10g')}"


def cell_config(cfg: DictConfig, scene: str, variation: int, obj_spec: str, method: str) -> DictConfig:
    """The run's config with the scene, object and method of one cell (the experiment's sizes,
    sampler and model settings kept; the method's sampler switches applied)."""
    from snell_bench.experiment.inputs import apply_method

    c = OmegaConf.create(OmegaConf.to_container(cfg, resolve=False))
    OmegaConf.set_struct(c, False)
    c.scene = OmegaConf.merge(c.scene, load_group("scene", scene), {"variation": int(variation)})
    obj_name, ior = parse_object_spec(obj_spec)
    c.object = OmegaConf.merge(c.object, load_group("object", obj_name), {} if ior is None else {"ior": ior})
    c.method = OmegaConf.merge(c.method, load_group("method", method))
    return apply_method(c)


# ---------------------------------------------------------------------------- atomic files
def _atomic_write_bytes(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_json(path: Path, obj) -> None:
    _atomic_write_bytes(path, json.dumps(obj, indent=2, default=_json_default).encode())


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))


def _save_npy(path: Path, arr: np.ndarray) -> None:
    import io

    buf = io.BytesIO()
    np.save(buf, arr)
    _atomic_write_bytes(path, buf.getvalue())


def _link(src: Path, dst: Path) -> None:
    """Hard-link a shared input into a cell (copy where links are not possible)."""
    tmp = dst.with_name(f".{dst.name}.link")
    tmp.unlink(missing_ok=True)
    try:
        os.link(src, tmp)
    except OSError:
        shutil.copyfile(src, tmp)
    os.replace(tmp, dst)


def _finite(x):
    return None if x is None or (isinstance(x, float) and not np.isfinite(x)) else x


# ---------------------------------------------------------------------------- shared inputs
@dataclass
class Shared:
    inputs: object  # SceneInputs
    obj: object  # placed GlassObject
    warps: object  # WarpSet
    i_minus: torch.Tensor  # (1, 3, H, W)
    reference: np.ndarray | None  # (H, W, 3) sRGB
    metric_mask: np.ndarray | None  # (H, W) bool
    true_render: np.ndarray | None
    files: dict  # name -> path of shared files to link into cells
    timings: dict
    reference_reason: str | None = None


def prepare_shared(cfg: DictConfig, group_dir: Path) -> Shared:
    from snell_bench.experiment.inputs import make_object, make_scene_inputs, place_from_config, warps_from_config

    d = group_dir / "_inputs"
    d.mkdir(parents=True, exist_ok=True)
    t = {}
    t0 = time.perf_counter()
    inputs = make_scene_inputs(cfg.scene)
    obj = place_from_config(make_object(cfg.object), inputs, cfg.object, seed=int(cfg.seed))
    t["scene"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    w = cfg.warps
    ws = warps_from_config(inputs, obj, w)
    t["warps"] = time.perf_counter() - t0
    files = {}
    save_png(d / "I_minus.png", inputs.image)
    files["I_minus.png"] = d / "I_minus.png"
    _save_npy(d / "depth.npy", inputs.depth.astype(np.float32))
    files["depth.npy"] = d / "depth.npy"
    cam = dict(inputs.camera.to_dict(), ior=obj.ior, object=obj.name, up=obj.up.tolist() if obj.up is not None else None)
    write_json(d / "camera.json", cam)
    files["camera.json"] = d / "camera.json"
    _atomic_write_bytes(d / "object.ply", obj.mesh.export(file_type="ply"))
    files["object.ply"] = d / "object.ply"

    reference = mask = true = None
    reason = None
    t0 = time.perf_counter()
    if cfg.reference.enabled:
        try:
            from snell_bench.render.mitsuba_ref import render_reference

            ref = render_reference(
                inputs.image, inputs.depth, inputs.camera, obj, spp=int(cfg.reference.spp),
                edge_threshold=float(w.edge_threshold), seed=int(cfg.seed),
                unobserved_threshold=float(cfg.reference.unobserved_threshold),
            )
            reference, mask = ref.image, ref.mask
            save_png(d / "reference.png", reference)
            save_png(d / "mask.png", mask.astype(np.float32))
            _save_npy(d / "unobserved.npy", ref.unobserved.astype(np.float16))
            files["reference.png"], files["mask.png"] = d / "reference.png", d / "mask.png"
        except ImportError as e:
            reason = f"reference renderer unavailable ({e}); install the render extra: make setup EXTRAS=test,render"
            log.warning(reason)
    else:
        reason = "reference.enabled=false"
    t["reference"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if cfg.reference.true_render and cfg.scene.source == "procedural":
        try:
            from snell_bench.render.mitsuba_ref import render_true

            true = render_true(inputs.source, inputs.camera, obj, spp=int(cfg.reference.true_spp),
                               max_bounces=int(cfg.reference.get("true_max_bounces") or w.max_bounces),
                               seed=int(cfg.seed))
            save_png(d / "true.png", true)
            files["true.png"] = d / "true.png"
        except ImportError as e:
            log.warning("true render unavailable: %s", e)
    t["true_render"] = time.perf_counter() - t0
    i_minus = torch.from_numpy(inputs.image).permute(2, 0, 1)[None].float()
    return Shared(inputs, obj, ws, i_minus, reference, mask, true, files, t, reason)


def _with_method_warps(ccfg: DictConfig, base: DictConfig, shared: Shared) -> Shared:
    """``shared`` itself, or a copy with the warps of a method whose warp options differ from the
    group's (e.g. far background at infinity); its warp time replaces the group's."""
    if OmegaConf.to_container(ccfg.warps, resolve=True) == OmegaConf.to_container(base.warps, resolve=True):
        return shared
    import dataclasses

    from snell_bench.experiment.inputs import warps_from_config

    t0 = time.perf_counter()
    ws = warps_from_config(shared.inputs, shared.obj, ccfg.warps)
    return dataclasses.replace(shared, warps=ws, timings={**shared.timings, "warps": time.perf_counter() - t0})


# ---------------------------------------------------------------------------- methods
class Skip(Exception):
    """A method that cannot run here; the message says why."""


def _requirements(cfg: DictConfig) -> None:
    req = list(cfg.method.requires or [])
    if "gpu" in req and not torch.cuda.is_available():
        raise Skip(
            f"{cfg.method.label} needs a CUDA GPU and its weights ({cfg.method.model_id}); none here"
        )


def generate_image(cfg: DictConfig, shared: Shared, gen_cache: dict, gen_key: int | None = None) -> tuple[torch.Tensor, dict]:
    """The method's image ``(1, 3, H, W)`` and its statistics. ``gen_key`` identifies the scene whose
    generator ``gen_cache`` may hold (default: ``shared`` itself)."""
    from snell_bench.experiment.inputs import make_generator
    from snell_bench.sampler.snellcaster import sample

    _requirements(cfg)
    kind = cfg.method.kind
    prompt = str(cfg.scene.prompt).replace("{object}", str(cfg.object.noun))
    if kind == "external":
        from snell_bench.models.external import generate_external

        img = generate_external(cfg.method.model_id, prompt, shared.warps.camera.shape, seed=int(cfg.seed),
                                steps=int(cfg.sampler.steps))
        return img, {}
    if kind not in ("snellcaster", "t2i", "inpaint"):
        raise ValueError(f"method.kind={kind!r} is unknown; use snellcaster, t2i, inpaint or external")
    if kind == "inpaint" and cfg.model.name != "analytic":
        from snell_bench.models.external import inpaint_external

        img = inpaint_external(cfg.method.model_id, prompt, shared.i_minus, shared.warps.object_mask,
                               seed=int(cfg.seed), steps=int(cfg.sampler.steps))
        return img, {}
    key = (cfg.model.name, id(shared) if gen_key is None else gen_key)
    if key not in gen_cache:
        gen_cache.clear()  # one scene's generator at a time (the analytic one is built from the scene)
        gen_cache[key] = make_generator(cfg.model, shared.inputs, shared.warps)
    settings = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(_settings_schema()), cfg.sampler))
    settings.progress = False
    res = sample(gen_cache[key], shared.warps, shared.i_minus, prompt, str(cfg.scene.pano_prompt), settings,
                 seed=int(cfg.seed))
    img = res.image
    if kind == "inpaint":  # CPU stand-in: the generator fills the object region of I⁻, no optics
        m = torch.from_numpy(shared.warps.object_mask)[None, None]
        img = torch.where(m, img, shared.i_minus)
    return img, {"model_calls": res.model_calls, "sampler_timings_s": {k: round(v, 3) for k, v in res.timings.items()},
                 "decisions": res.decisions}


def _settings_schema():
    from snell_bench.sampler.settings import SamplerSettings

    return SamplerSettings


# ---------------------------------------------------------------------------- scoring
class Scorers:
    """LPIPS / CLIP / ImageReward scorers built once per run; a scorer that cannot be built is
    missing, with its reason."""

    def __init__(self, mcfg: DictConfig) -> None:
        self.lpips = self.clip = self.image_reward = None
        self.reasons: dict[str, str] = {}
        try:
            from snell_bench.metrics import CLIPScore, ImageRewardScorer, MaskedLPIPS, MetricUnavailable
        except ImportError as e:  # pragma: no cover - metrics are a core dependency
            self.reasons = {k: f"metrics unavailable: {e}" for k in ("lpips", "clip", "image_reward")}
            return
        for name, build in (
            ("lpips", lambda: MaskedLPIPS(weights_path=mcfg.lpips_weights)),
            ("clip", lambda: CLIPScore(weights_path=mcfg.clip_weights)),
            ("image_reward", lambda: ImageRewardScorer(python=mcfg.image_reward_python)),
        ):
            try:
                setattr(self, name, build())
            except MetricUnavailable as e:
                self.reasons[name] = e.reason if hasattr(e, "reason") else str(e)
            except Exception as e:  # a broken weights file must not stop the sweep
                self.reasons[name] = f"{type(e).__name__}: {e}"


def score(img: torch.Tensor, shared: Shared, prompt: str, scorers: Scorers, image_path: Path) -> dict:
    from snell_bench.metrics import masked_psnr, score_all, MetricUnavailable

    gen = img[0].permute(1, 2, 0).numpy()
    if shared.reference is None:
        out = {"metrics": {k: None for k in ("psnr", "mae", "lpips", "clip", "image_reward")},
               "missing": {k: shared.reference_reason or "no reference" for k in ("psnr", "mae", "lpips")}}
        if scorers.clip is not None:
            try:
                out["metrics"]["clip"] = float(scorers.clip(gen, prompt))
            except MetricUnavailable as e:
                out["missing"]["clip"] = e.reason
    else:
        out = score_all(gen, shared.reference, shared.metric_mask, prompt, lpips=scorers.lpips, clip=scorers.clip,
                        image_reward=scorers.image_reward, generated_path=image_path)
    for k, r in scorers.reasons.items():
        if out["metrics"].get(k) is None:
            out["missing"][k] = r
    if shared.true_render is not None:
        try:
            out["metrics"]["psnr_true"] = float(masked_psnr(gen, shared.true_render, shared.warps.object_mask))
        except MetricUnavailable as e:
            out["metrics"]["psnr_true"] = None
            out["missing"]["psnr_true"] = e.reason
    out["metrics"] = {k: _finite(v) for k, v in out["metrics"].items()}
    return out


# ---------------------------------------------------------------------------- the sweep
def _cell_done(cell_dir: Path) -> bool:
    p = cell_dir / "metrics.json"
    if not p.is_file():
        return False
    try:
        return json.loads(p.read_text()).get("status") in ("ok", "skipped")
    except (OSError, ValueError):
        return False


def run_grid(cfg: DictConfig) -> dict:
    g = cfg.grid
    exp = str(cfg.experiment_name)
    root = Path(cfg.runs_dir) / exp
    root.mkdir(parents=True, exist_ok=True)
    groups = list(itertools.product(g.scenes, g.variations, g.objects))
    methods = list(g.methods)
    for m in methods:  # fail fast on a typo, before any work
        load_group("method", m)
    for s in g.scenes:
        load_group("scene", s)
    for o in g.objects:
        load_group("object", parse_object_spec(o)[0])
    total = len(groups) * len(methods)
    print(f"experiment {exp}: {len(groups)} scene/object groups x {len(methods)} methods = {total} cells -> {root}")
    scorers = Scorers(cfg.metrics)
    counts = {"ok": 0, "failed": 0, "skipped": 0, "cached": 0}
    failures = []
    gen_cache: dict = {}
    bar = tqdm(total=total, desc=exp, unit="cell")
    for scene, variation, obj_spec in groups:
        group_dir = root / f"{scene}-{variation}" / object_dir_name(obj_spec)
        todo = []
        for m in methods:
            cdir = group_dir / m
            if not g.recompute and _cell_done(cdir):
                counts["cached"] += 1
                bar.update(1)
            else:
                todo.append(m)
        if not todo:
            continue
        base = cell_config(cfg, scene, variation, obj_spec, todo[0])
        base.warps = cfg.warps  # the group's warps; a method with its own warp options gets its own
        try:
            shared = prepare_shared(base, group_dir)
            shared_error = None
        except Exception as e:
            shared, shared_error = None, e
            log.error("inputs of %s failed: %s", group_dir, e)
        for m in todo:
            ccfg = cell_config(cfg, scene, variation, obj_spec, m)
            cdir = group_dir / m
            cdir.mkdir(parents=True, exist_ok=True)
            record = {
                "experiment": exp, "scene": scene, "variation": int(variation), "object": object_dir_name(obj_spec),
                "method": m, "method_label": str(ccfg.method.label), "model": str(ccfg.model.name),
                "scene_source": str(ccfg.scene.source), "status": "ok", "reason": None,
                "metrics": {}, "missing": {}, "timings_s": {},
            }
            t0 = time.perf_counter()
            try:
                if shared is None:
                    raise shared_error
                for name, path in shared.files.items():
                    _link(path, cdir / name)
                cell_shared = _with_method_warps(ccfg, base, shared)
                t0 = time.perf_counter()
                img, stats = generate_image(ccfg, cell_shared, gen_cache, gen_key=id(shared))
                record["timings_s"]["sampling"] = round(time.perf_counter() - t0, 3)
                save_png(cdir / "image.png", img[0].permute(1, 2, 0).numpy())
                t1 = time.perf_counter()
                prompt = str(ccfg.scene.prompt).replace("{object}", str(ccfg.object.noun))
                record.update(score(img, shared, prompt, scorers, cdir / "image.png"))
                record["timings_s"]["metrics"] = round(time.perf_counter() - t1, 3)
                record["timings_s"].update({k: round(v, 3) for k, v in cell_shared.timings.items()})
                record.update(stats)
                record["warps"] = {k: cell_shared.warps.stats.get(k) for k in ("roi", "traced_primary_rays", "far_background")
                                   if k in cell_shared.warps.stats}
            except Skip as e:
                record.update(status="skipped", reason=str(e))
            except KeyboardInterrupt:
                raise
            except Exception as e:
                record.update(status="failed", reason=f"{type(e).__name__}: {e}", traceback=traceback.format_exc())
                failures.append((str(cdir), record["reason"]))
                log.error("cell %s failed: %s", cdir, record["reason"])
            ccfg.output_dir = str(cdir)
            _atomic_write_bytes(cdir / "config.yaml", OmegaConf.to_yaml(ccfg, resolve=True).encode())
            write_json(cdir / "metrics.json", record)  # last: marks the cell complete
            counts[record["status"]] += 1
            bar.update(1)
            bar.set_postfix(ok=counts["ok"], failed=counts["failed"], skipped=counts["skipped"])
    bar.close()
    summary = {"experiment": exp, "cells": total, **counts, "failures": failures}
    write_json(root / "summary.json", summary)
    print(f"{exp}: {counts['ok']} ok, {counts['cached']} already done, {counts['skipped']} skipped, {counts['failed']} failed")
    for cdir, reason in failures:
        print(f"  FAILED {cdir}: {reason}")
    if g.report:
        try:
            from snell_bench.experiment.reports import build_reports

            out = Path(cfg.reports_dir) / exp
            paths = build_reports(root, out, exp)
            print(f"reports: {out} ({len(paths)} files)")
            summary["reports"] = [str(p) for p in paths]
        except ImportError as e:
            log.warning("reports unavailable: %s", e)
    return summary
