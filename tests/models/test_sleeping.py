"""The sleeping generator: the analytic generator's outputs exactly, each model call a fixed sleep
longer, the CPU left free while it sleeps."""

import time

import pytest
import torch

from snell_bench.config import compose
from snell_bench.models.analytic import AnalyticGenerator
from snell_bench.models.base import Generator
from snell_bench.models.sleeping import SleepingGenerator
from snell_bench.optics import compute_warps
from snell_bench.pipeline.cell import build
from snell_bench.sampler import SamplerSettings, sample
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.placement import place_object
from snell_bench.scene.procedural import ProceduralScene


@pytest.fixture(scope="module")
def room():
    """A glass sphere on the table of a procedural room, 64 x 48, its warps and true panorama."""
    scene = ProceduralScene("room", seed=0)
    r = scene.render(64, 48)
    obj = place_object(GlassObject.sphere(subdivisions=2), r.depth, r.camera, up_hint=scene.up)
    ws = compute_warps(r.depth, r.camera, obj, pano_height=16)
    p = ws.pano
    pano = scene.render_panorama(center=p.center, height=p.height, up=-p.rotation[:, 1], forward=p.rotation[:, 2])
    return r.image, ws, pano


def _both(room, sleep_s=0.0):
    """The analytic generator of ``conf/model/analytic.yaml`` and the sleeping one of
    ``conf/model/sleeping.yaml``, built from the same scene as the grid builds them."""
    image, ws, pano = room
    scene = {"i_minus": image, "object_mask": ws.object_mask, "panorama": pano}
    analytic = build(compose(["model=analytic"]).model.generator, **scene)
    sleeping = build(compose(["model=sleeping", f"model.generator.sleep_s={sleep_s}"]).model.generator, **scene)
    return analytic, sleeping


def test_config_builds_a_sleeping_analytic_generator(room):
    analytic, sleeping = _both(room, sleep_s=0.01)
    assert isinstance(analytic, AnalyticGenerator) and isinstance(sleeping, SleepingGenerator)
    assert isinstance(sleeping, Generator) and sleeping.sleep_s == 0.01
    assert sleeping.geometry == analytic.geometry and sleeping.device == analytic.device
    assert compose(["model=sleeping"]).model.from_scene  # built from the scene, like analytic


def test_outputs_equal_the_analytic_generators(room):
    analytic, sleeping = _both(room)
    image, ws, _ = room
    x = torch.from_numpy(image).permute(2, 0, 1)[None].float()
    z = analytic.encode(x)
    assert torch.equal(sleeping.encode(x), z)
    assert torch.equal(sleeping.decode(z), analytic.decode(z))
    cond = analytic.condition(["p"], ["main"])
    assert torch.equal(sleeping.velocity(z, 0.4, cond), analytic.velocity(z, 0.4, cond))
    assert torch.equal(sleeping.sigmas(4, 48, 64), analytic.sigmas(4, 48, 64))


def test_sampling_gives_the_analytic_generators_images(room):
    """The synchronized sampler (both branches, time travel) with either generator: the same main
    image and panorama, bit for bit; every model call of the run went through the sleep."""
    analytic, sleeping = _both(room)
    image, ws, _ = room
    x = torch.from_numpy(image).permute(2, 0, 1)[None].float()
    settings = SamplerSettings(steps=4, levels=2, progress=False)
    a = sample(analytic, ws, x, "a glass sphere", "a panorama", settings, seed=3)
    s = sample(sleeping, ws, x, "a glass sphere", "a panorama", settings, seed=3)
    assert torch.equal(a.image, s.image) and torch.equal(a.panorama, s.panorama)
    assert s.model_calls == a.model_calls and sleeping.calls >= sum(s.model_calls.values())


def test_each_call_sleeps_and_leaves_the_cpu_free(room):
    """Four calls take at least four sleeps of wall time (``time.sleep`` sleeps at least as long as
    asked) and far less CPU time (a 24 x 8 x 6 latent costs microseconds to transform)."""
    _, sleeping = _both(room, sleep_s=0.05)
    z = torch.zeros(1, 192, 6, 8)
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(2):
        sleeping.encode(sleeping.decode(z))
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    assert sleeping.calls == 4 and wall >= 4 * 0.05
    assert cpu < 0.5 * 4 * 0.05


def test_a_negative_sleep_names_its_key():
    with pytest.raises(ValueError, match=r"model.generator.sleep_s must be finite and >= 0"):
        SleepingGenerator(object(), sleep_s=-1.0)
