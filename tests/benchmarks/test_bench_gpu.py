"""``benchmarks/bench_gpu.py`` runs on the CPU with the tiny FLUX (so it cannot rot without a GPU),
and its figures agree with what the sampler itself reports."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_bench_gpu_runs_tiny_on_the_cpu_and_writes_its_figures(tmp_path):
    out = tmp_path / "bench.json"
    env = {**os.environ, "HF_HUB_OFFLINE": "1"}
    cmd = [sys.executable, str(ROOT / "benchmarks" / "bench_gpu.py"), "--tiny", "--device", "cpu", "--steps", "4"]
    proc = subprocess.run([*cmd, "--json", str(out)], capture_output=True, text=True, env=env, timeout=600, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    fig = json.loads(out.read_text())
    pair = fig["pair"]
    assert fig["random_weights"] and fig["settings"]["steps"] == 4
    calls = pair["model_calls"]
    # one transformer pass per velocity call of each branch (the two views differ in size: never batched)
    assert pair["transformer_passes"] == calls["main"] + calls["pano"] >= 2 * 4
    step = pair["per_step_s"]
    assert set(step) == {"transformer", "vae_decode", "vae_encode", "warps_blends"}
    assert sum(step.values()) <= pair["total_s"] / 4 * (1 + 1e-6)  # parts of a step, never more than it
    assert pair["host_device_bytes_per_step"] == 0  # one device: nothing crosses
    assert fig["t2i"]["steps"] == 4 and fig["kontext"]["candidates"] == 3
    assert proc.stdout.strip().splitlines()[-1].startswith("ratios: pair / t2i")
