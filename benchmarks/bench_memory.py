"""Benchmark: a photo cell's peak host memory per stage, measured against the estimate of
:mod:`snell_bench.experiment.memory`.

For each size, a photo of that size is made from the bundled RGB-D frame (``tum_office``: colour
resampled with Lanczos, depth by nearest neighbour, the intrinsics scaled; ``--filled`` fills the
depth's holes, which gives the largest peaks), and one cell of ``+experiment=photo`` (Snellcaster,
the analytic stand-in, on CPU, nothing cached) is run in a subprocess of its own. The subprocess
reads its peak resident memory per stage: on Linux the kernel's high-water mark (``VmHWM`` of
``/proc/self/status``) is reset at the start of each stage (``/proc/self/clear_refs``), so each
stage's peak is exact and includes what earlier stages still hold, and the run's peak is the
largest; elsewhere only the whole run's ``ru_maxrss``. Prints, per run, the measured and the
estimated peak of each stage and of the cell in GB (10^9 bytes), their ratio, the reference's
window and the run's time.

Usage::

    python benchmarks/bench_memory.py [--sizes 640x480,1280x960,1920x1440] [--spp 8,50]
        [--pano 256] [--steps 2] [--filled] [--json out.json]

Each run is one process, so runs do not share memory; sizes, sample counts and panorama heights
multiply.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
FRAME = REPO / "snell_bench" / "datasets" / "rgbd" / "tum_fr3_office"
#: The bundled frame's intrinsics at its 640 x 480.
TUM_K = (525.0, 525.0, 319.5, 239.5)
#: The stages recorded, in order, and the functions whose call starts each (module, name).
STAGES = {
    "scene": ("snell_bench.pipeline.inputs", "load_scene"),
    "warps": ("snell_bench.pipeline.inputs", "trace_warps"),
    "reference": ("snell_bench.pipeline.inputs", "render_reference"),
    "true_render": ("snell_bench.pipeline.inputs", "render_true_scene"),
    "files": ("snell_bench.experiment.runner", "save_inputs"),
    "sampler": ("snell_bench.pipeline", "sample_stage"),
    "metrics": ("snell_bench.pipeline", "finish_method"),
}


def make_photo(folder: Path, width: int, height: int, *, filled: bool = False) -> list[str]:
    """Write ``color.png`` and a 16-bit ``depth.png`` of ``width x height`` into ``folder``, made
    from the bundled frame (``filled``: its missing depth filled with the nearest valid pixel's);
    returns the overrides that select them (with the scaled intrinsics)."""
    folder.mkdir(parents=True, exist_ok=True)
    color = Image.open(FRAME / "color.png").convert("RGB").resize((width, height), Image.Resampling.LANCZOS)
    color.save(folder / "color.png")
    raw = np.asarray(Image.open(FRAME / "depth.png"))
    if filled:
        from scipy.ndimage import distance_transform_edt

        _, (iy, ix) = distance_transform_edt(raw == 0, return_indices=True)
        raw = raw[iy, ix]
    h0, w0 = raw.shape
    xs = np.minimum(((np.arange(width) + 0.5) * (w0 / width)).astype(np.int64), w0 - 1)
    ys = np.minimum(((np.arange(height) + 0.5) * (h0 / height)).astype(np.int64), h0 - 1)
    Image.fromarray(np.ascontiguousarray(raw[ys[:, None], xs[None, :]]).astype(np.uint16)).save(folder / "depth.png")
    sx, sy = width / w0, height / h0
    fx, fy, cx, cy = TUM_K
    k = [fx * sx, fy * sy, (cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5]
    return [
        f"scene.image={folder / 'color.png'}",
        f"scene.depth={folder / 'depth.png'}",
        "scene.intrinsics=[" + ",".join(f"{v:.6g}" for v in k) + "]",
    ]


def cell_overrides(
    folder: Path,
    width: int,
    height: int,
    spp: int,
    pano: int,
    steps: int,
    *,
    filled: bool = False,
    scene: str = "photo",
) -> list[str]:
    """The overrides of one measured cell: the photo of ``width x height`` (:func:`make_photo`; or
    the procedural ``scene`` of the smoke experiment at that size), Snellcaster only, the reference
    at ``spp``, the panorama ``pano`` high, ``steps`` sampler steps, nothing cached."""
    if scene == "photo":
        select = ["+experiment=photo", *make_photo(folder / "photo", width, height, filled=filled)]
    else:
        select = ["+experiment=smoke", f"grid.scenes=[{scene}]", f"scene.width={width}", f"scene.height={height}"]
    return [
        *select,
        "grid.methods=[snellcaster]",
        f"reference.spp={spp}",
        f"warps.pano_height={pano}",
        f"sampler.steps={steps}",
        "warps.cache_dir=null",
        "grid.report=false",
        f"runs_dir={folder / 'runs'}",
        f"output_dir={folder}",
    ]


# ---------------------------------------------------------------------------------------------- child
def _hwm_bytes() -> int | None:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def _reset_hwm() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _maxrss() -> int:
    """This process's peak resident memory in bytes (``ru_maxrss``: kB on Linux, bytes on macOS)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * (1 if sys.platform == "darwin" else 1024)


def _child(overrides: list[str]) -> dict:
    """Run the cell of ``overrides`` here; returns the peak bytes per stage and of the whole run."""
    import importlib

    import snell_bench  # noqa: F401
    from snell_bench.config import compose
    from snell_bench.experiment.runner import run_grid

    peaks: dict[str, int] = {}
    state = {"stage": "start", "exact": _reset_hwm()}

    def enter(stage: str) -> None:
        hwm = _hwm_bytes()
        if hwm is not None:
            peaks[state["stage"]] = max(peaks.get(state["stage"], 0), hwm)
        _reset_hwm()
        state["stage"] = stage

    def wrap(stage, fn):
        def wrapped(*args, **kwargs):
            enter(stage)
            return fn(*args, **kwargs)

        return wrapped

    for stage, (module, name) in STAGES.items():
        mod = importlib.import_module(module)
        setattr(mod, name, wrap(stage, getattr(mod, name)))
    cfg = compose(overrides)
    t0 = time.perf_counter()
    summary = run_grid(cfg)
    enter("end")
    cell = next(Path(cfg.runs_dir).rglob("metrics.json"))
    record = json.loads(cell.read_text())
    return {
        "peaks": peaks if state["exact"] else {},
        # ru_maxrss follows the resets: the run's peak is the largest stage's
        "maxrss": max(peaks.values()) if state["exact"] else _maxrss(),
        "ok": summary["ok"],
        "reference": record.get("reference"),
        "scene_info": record.get("scene_info"),
        "seconds": round(time.perf_counter() - t0, 1),
        "status": record.get("status"),
        "reason": record.get("reason"),
    }


def measure(
    width: int, height: int, spp: int, pano: int, steps: int, *, filled: bool = False, timeout: float = 3600
) -> dict:
    """Run one cell in a subprocess; returns its measured peaks (bytes), the config's estimate and
    the cell's record of its reference."""
    from snell_bench.config import compose
    from snell_bench.experiment.memory import estimate_memory

    with tempfile.TemporaryDirectory() as tmp:
        overrides = cell_overrides(Path(tmp), width, height, spp, pano, steps, filled=filled)
        cfg = compose(overrides)
        est = estimate_memory(cfg)
        r = subprocess.run(
            [sys.executable, __file__, "--child", json.dumps(overrides)],
            capture_output=True,
            text=True,
            timeout=timeout,
            env=dict(os.environ, PYTHONPATH=str(REPO)),
        )
        if r.returncode != 0:
            raise RuntimeError(f"the measured run failed ({r.returncode}): {r.stderr[-2000:]}")
        out = json.loads(r.stdout.strip().splitlines()[-1])
    return {"width": width, "height": height, "spp": spp, "pano": pano, "filled": filled, **out, "estimate": est}


def _gb(b) -> str:
    return "-" if b is None else f"{b / 1e9:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="640x480,1280x960,1920x1440")
    ap.add_argument("--spp", default="8,50")
    ap.add_argument("--pano", default="256")
    ap.add_argument("--steps", type=int, default=2)
    ap.add_argument("--filled", action="store_true", help="fill the frame's depth holes (the largest peaks)")
    ap.add_argument("--json", default=None, help="also write every run's numbers to this file")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        print(json.dumps(_child(json.loads(args.child))))
        return

    print(f"{platform.node()} {platform.machine()} {os.cpu_count()} CPUs, Python {platform.python_version()}")
    runs = []
    for size in args.sizes.split(","):
        w, h = (int(v) for v in size.lower().split("x"))
        for spp in (int(v) for v in args.spp.split(",")):
            for pano in (int(v) for v in args.pano.split(",")):
                run = measure(w, h, spp, pano, args.steps, filled=args.filled)
                runs.append(run)
                est = run["estimate"]
                print(
                    f"\n{w}x{h} spp={spp} pano_height={pano}: measured {_gb(run['maxrss'])} GB, "
                    f"estimated {_gb(est.peak_bytes)} GB (peak in {est.stage}), ratio "
                    f"{est.peak_bytes / run['maxrss']:.2f}; window {run['reference'] and run['reference']['window']}, "
                    f"{run['seconds']} s"
                )
                print(f"  {'stage':<10} {'measured':>9} {'estimated':>9}")
                for stage in est.stages:
                    print(f"  {stage:<10} {_gb(run['peaks'].get(stage)):>9} {_gb(est.stages[stage]):>9}")
    if args.json:
        for run in runs:
            run["estimate"] = run["estimate"].as_dict()
        Path(args.json).write_text(json.dumps(runs, indent=1))


if __name__ == "__main__":
    main()
