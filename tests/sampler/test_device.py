"""The sampler runs on the generator's device: every model input and output stays there, and only
the final images and dumps come back to the CPU.

On a CPU-only machine a second device is simulated where it matters: the loop runs with torch's
default device set to ``meta`` (a device without data), so any tensor the loop or a library inside
it creates without naming the generator's device lands there and the run fails; a loop that
creates everything on its generator's device runs unchanged. The recording generator checks every
call's inputs and outputs, and the CUDA test (marked ``gpu``) checks that no byte crosses the bus
per step.
"""

import numpy as np
import pytest
import torch

from snell_bench.models.analytic import AnalyticGenerator
from snell_bench.models.base import generator_device
from snell_bench.optics.warps import compute_warps
from snell_bench.sampler import SamplerSettings, sample
from snell_bench.utils.transfers import TransferCounter
from tests.conftest import sphere_at

H, W = 96, 160


class Recording:
    """A generator wrapper that records the device of every tensor going in and out of the model."""

    def __init__(self, gen):
        self.gen = gen
        self.name, self.geometry = gen.name, gen.geometry
        self.device = generator_device(gen)
        self.dtype = getattr(gen, "dtype", torch.float32)
        self.seen: list[tuple[str, str, torch.device]] = []

    def _note(self, what, where, x):
        if isinstance(x, torch.Tensor):
            self.seen.append((what, where, x.device))

    def _wrap(self, what, fn, *args, **kw):
        for a in args:
            self._note(what, "in", a)
        out = fn(*args, **kw)
        self._note(what, "out", out)
        return out

    def velocity(self, z, sigma, cond):
        return self._wrap("velocity", self.gen.velocity, z, sigma, cond)

    def decode(self, z):
        return self._wrap("decode", self.gen.decode, z)

    def encode(self, x, generator=None):
        return self._wrap("encode", self.gen.encode, x, generator)

    def condition(self, prompts, views):
        return self.gen.condition(prompts, views)

    def sigmas(self, *a, **kw):
        return self.gen.sigmas(*a, **kw)


@pytest.fixture(scope="module")
def scene(small_camera_module):
    depth = np.full((H, W), 4.0)
    ws = compute_warps(depth, small_camera_module, sphere_at([0.0, 0.2, 2.5], 0.4), pano_height=32, cache_dir=None)
    i_minus = torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(1))
    pano = np.random.default_rng(0).random((32, 64, 3)).astype(np.float32)
    return ws, i_minus, pano


@pytest.fixture(scope="module")
def small_camera_module():
    from snell_bench.scene.camera import Camera

    return Camera.from_fov(W, H, 60.0)


SETTINGS = dict(steps=5, progress=False, stochastic=True, tt_window=[0.0, 1.0], dump_every=2)


def run(gen, scene, **kw):
    ws, i_minus, _ = scene
    return sample(gen, ws, i_minus, "a room", "a panorama", SamplerSettings(**{**SETTINGS, **kw}), seed=0)


def test_every_model_call_stays_on_the_generators_device(scene):
    ws, i_minus, pano = scene
    gen = Recording(AnalyticGenerator.from_scene(i_minus[0].permute(1, 2, 0).numpy(), ws.object_mask, pano))
    res = run(gen, scene)
    kinds = {what for what, _, _ in gen.seen}
    assert kinds == {"velocity", "decode", "encode"}
    assert {d for _, _, d in gen.seen} == {gen.device}
    # what comes back: the final images and the dumps, on the CPU
    assert res.image.device.type == "cpu" and res.panorama.device.type == "cpu"
    assert res.dumps and all(v.device.type == "cpu" for d in res.dumps for v in d.values() if torch.is_tensor(v))


def test_the_wrapper_changes_nothing(scene):
    ws, i_minus, pano = scene
    base = AnalyticGenerator.from_scene(i_minus[0].permute(1, 2, 0).numpy(), ws.object_mask, pano)
    assert torch.equal(run(Recording(base), scene).image, run(base, scene).image)


def test_generator_alone_decodes_only_the_final_image(scene):
    """``sync="none"``: one decode at the end, as ``FluxPipeline`` does (no per-step decode)."""
    ws, i_minus, pano = scene
    gen = Recording(AnalyticGenerator.from_scene(i_minus[0].permute(1, 2, 0).numpy(), ws.object_mask, pano))
    res = run(gen, scene, sync="none", dump_every=0, stochastic=False)
    decodes = [1 for what, where, _ in gen.seen if what == "decode" and where == "out"]
    assert len(decodes) == 1 and res.model_calls == {"main": 5, "pano": 0}
    assert not [1 for what, _, _ in gen.seen if what == "encode"]


class Preconditioned:
    """A generator whose text conditions are computed beforehand (tokenising runs on the host once
    per run, outside the loop)."""

    def __init__(self, gen, prompts):
        self.gen, self.name, self.geometry = gen, gen.name, gen.geometry
        self.device, self.dtype = generator_device(gen), getattr(gen, "dtype", torch.float32)
        self.cache = {(tuple(p), tuple(v)): gen.condition(p, v) for p, v in prompts}

    def condition(self, prompts, views):
        return self.cache[(tuple(prompts), tuple(views))]

    def __getattr__(self, name):
        return getattr(self.gen, name)


@pytest.mark.parametrize("backend", ["analytic", "tiny_flux"])
def test_no_tensor_of_the_loop_is_created_off_the_generators_device(scene, backend):
    """With ``meta`` as torch's default device the whole loop (both branches, time travel,
    stochastic steps, reflection, dumps) gives the same image: every tensor it makes is made on the
    generator's device (maps, masks, noise, pyramid kernels, schedule, model inputs)."""
    from snell_bench.models.tiny_flux import TinyFluxGenerator

    ws, i_minus, pano = scene
    if backend == "analytic":
        gen = AnalyticGenerator.from_scene(i_minus[0].permute(1, 2, 0).numpy(), ws.object_mask, pano)
    else:
        prompts = ((["a room"], ["main"]), (["a panorama"], ["pano"]), (["a room", "a panorama"], ["main", "pano"]))
        gen = Preconditioned(TinyFluxGenerator(seed=0), prompts)
    kw = dict(steps=3) if backend == "tiny_flux" else {}
    ref = run(gen, scene, **kw)
    with torch.device("meta"):
        out = run(gen, scene, **kw)
    assert torch.equal(out.image, ref.image) and torch.equal(out.panorama, ref.panorama)


def test_a_generator_on_meta_makes_the_real_runs_calls(scene):
    """Tiny FLUX on ``meta`` (shapes, no data; the run's random generator on the CPU): every stage
    that reads values on the host takes its general path, and the run makes the CPU run's model
    calls and gives its shapes and dtypes (images and dumps stay on ``meta``). The paper's sizes:
    tests/sampler/test_full_size_meta.py."""
    from snell_bench.models.flux import FluxGenerator
    from snell_bench.models.tiny_flux import TinyFluxGenerator, build_tiny_flux_pipeline

    kw = dict(steps=3, sde=True, stochastic=False, encode="sample", quantize=True, dump_every=1)
    ref = run(TinyFluxGenerator(seed=0), scene, **kw)
    out = run(FluxGenerator(build_tiny_flux_pipeline(0), device="meta", dtype=torch.float32), scene, **kw)
    assert out.model_calls == ref.model_calls == {"main": 5, "pano": 3}
    for a, b in [(out.image, ref.image), (out.panorama, ref.panorama)] + [
        (d[k], e[k]) for d, e in zip(out.dumps, ref.dumps, strict=True) for k in d if torch.is_tensor(e[k])
    ]:
        assert a.is_meta and (a.shape, a.dtype) == (b.shape, b.dtype)


def test_no_bytes_cross_devices_on_one_device(scene):
    ws, i_minus, pano = scene
    gen = AnalyticGenerator.from_scene(i_minus[0].permute(1, 2, 0).numpy(), ws.object_mask, pano)
    with TransferCounter() as moved:
        run(gen, scene)
    assert moved.bytes == 0


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_no_bytes_cross_the_bus_per_step_on_cuda(scene):
    """Tiny FLUX on CUDA: the bytes moved do not grow with the number of steps (the warps cross
    once, the final images once)."""
    from snell_bench.models.tiny_flux import TinyFluxGenerator

    gen = TinyFluxGenerator(seed=0, device="cuda")
    moved = []
    for steps in (2, 4):
        with TransferCounter() as m:
            run(gen, scene, steps=steps, dump_every=0, stochastic=False, time_travel=False)
        moved.append(m.bytes)
    assert moved[0] == moved[1], moved


def test_unsynchronised_last_step(scene):
    """``sync_last_step=false`` (the authors' code): the last step takes each branch's own estimate,
    so its decode/encode and blend are skipped and the result differs from the synchronised one."""
    ws, i_minus, pano = scene
    base = AnalyticGenerator.from_scene(i_minus[0].permute(1, 2, 0).numpy(), ws.object_mask, pano)
    counts = {}
    images = {}
    for last in (True, False):
        gen = Recording(base)
        images[last] = run(gen, scene, sync_last_step=last, dump_every=0, stochastic=False, time_travel=False).image
        counts[last] = sum(1 for what, where, _ in gen.seen if what == "encode" and where == "out")
    assert counts[True] - counts[False] == 2  # one encode per branch (main, panorama) at the last step
    assert not torch.equal(images[True], images[False])
