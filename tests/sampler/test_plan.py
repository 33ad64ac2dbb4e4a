"""The sampler's plan of visits (:mod:`snell_bench.sampler.plan`): a small plan checked by hand, the
closed-form model calls, the plan's own consistency over many settings, and a run that follows it."""

import doctest
import itertools
import math

import pytest
import torch

from snell_bench.models.analytic import AnalyticGenerator
from snell_bench.sampler import SamplerSettings, expected_model_calls, sample
from snell_bench.sampler import plan as plan_module
from snell_bench.sampler.plan import BRANCHES, visits
from tests.sampler.room import room_sphere
from tests.sampler.test_switches import Recorder

H, W, HP = 64, 96, 32  # the two latents differ in size: one call per branch, told apart by shape


def closed_form(s: SamplerSettings) -> dict[str, int]:
    """The model calls per branch in closed form (:func:`~snell_bench.sampler.plan.expected_model_calls`)."""
    T, length = s.steps, s.tt_length
    rnd = math.floor if s.tt_window_floor else math.ceil
    a, b = (min(max(rnd(T * w), 0), T) for w in s.tt_window)
    travels = s.sync == "snellcaster" and s.time_travel and b > a

    def calls(repeats: int) -> int:
        if not travels or repeats == 1:
            return T
        if s.tt_mode == "guided":
            return T + max(0, b - max(a, length))
        return T + (repeats - 1) * min(T - a, -(-(b - a) // length) * length)

    return {"main": calls(s.tt_repeats_main), "pano": calls(s.tt_repeats_pano) if s.uses_panorama else 0}


def many_settings():
    windows = [[0.2, 0.8], [0.0, 1.0], [0.0, 0.5], [0.5, 1.0], [0.3, 0.3], [0.25, 0.65], [0.1, 0.35]]
    for steps, win, floor, length, rm, rp, mode in itertools.product(
        [1, 2, 5, 7, 10, 20], windows, [False, True], [1, 2, 3], [1, 2, 3], [1, 2, 3], ["guided", "repaint"]
    ):
        yield SamplerSettings(
            steps=steps,
            tt_window=win,
            tt_window_floor=floor,
            tt_length=length,
            tt_repeats_main=rm,
            tt_repeats_pano=rp,
            tt_mode=mode,
            dump_every=(steps + length) % 4,
            sync_last_step=bool(rm % 2),
            progress=False,
        )
    for kw in (
        {"time_travel": False},
        {"sync": "none"},
        {"panorama": False},
        {"panorama": False, "tt_mode": "repaint"},
    ):
        for rp in (1, 3):
            yield SamplerSettings(tt_repeats_pano=rp, tt_length=2, progress=False, **kw)


SETTINGS = list(many_settings())


def test_the_docstring_examples():
    assert doctest.testmod(plan_module).failed == 0


def test_a_small_repaint_plan_by_hand():
    # T = 4, window [0.25 T, 0.5 T): step 1 only starts a block of 2 levels (1, 2); the main view runs
    # it twice, the panorama three times; level 2 is dumped on the last pass only, level 3 is not
    # synchronised (the last step)
    s = SamplerSettings(
        steps=4,
        tt_mode="repaint",
        tt_window=[0.25, 0.5],
        tt_length=2,
        tt_repeats_main=2,
        tt_repeats_pano=3,
        dump_every=2,
        sync_last_step=False,
    )
    assert [str(v) for v in visits(s)] == [
        "predict main+pano 0 sync dump",
        "step    main+pano 0->1 sync dump last",
        "predict main+pano 1 sync repaint",
        "step    main+pano 1->2 sync repaint",
        "predict main+pano 2 sync repaint",
        "step    main+pano 2->3 sync repaint",
        "travel  main 3->1 repaint",
        "travel  pano 3->1 repaint",
        "predict main+pano 1 sync repaint",
        "step    main+pano 1->2 sync repaint",
        "predict main+pano 2 sync repaint",
        "step    main+pano 2->3 sync repaint",
        "travel  pano 3->1 repaint",
        "predict pano 1 sync repaint",
        "step    pano 1->2 sync last repaint",
        "predict pano 2 sync dump repaint",
        "step    pano 2->3 sync dump last repaint",
        "predict main+pano 3",
        "step    main+pano 3->4 last",
    ]
    assert expected_model_calls(s) == {"main": 6, "pano": 8}


def test_a_small_guided_plan_by_hand():
    # every step travels, the panorama three times, the main view not at all: the panorama travels
    # and returns twice, is predicted again, then both are synchronised (the main view's estimate
    # unchanged); at step 0 there is no level to travel back to
    s = SamplerSettings(steps=2, tt_window=[0.0, 1.0], tt_repeats_main=1, tt_repeats_pano=3)
    assert [str(v) for v in visits(s)] == [
        "predict main+pano 0 sync",
        "step    main+pano 0->1 sync last",
        "predict main+pano 1 sync",
        "travel  pano 1->0 guided",
        "return  pano 0->1 guided",
        "travel  pano 1->0 guided",
        "return  pano 0->1 guided",
        "predict pano 1 sync main+pano guided",
        "step    main+pano 1->2 sync last",
    ]
    assert expected_model_calls(s) == {"main": 2, "pano": 3}


@pytest.mark.parametrize("recipe", ["paper", "authors"])
def test_the_recipes(recipe):
    from snell_bench.config.recipes import recipe_values

    keys = {k.split(".", 1)[1]: v for k, v in recipe_values(recipe).items() if k.startswith("sampler.")}
    s = SamplerSettings(**keys)
    assert expected_model_calls(s) == closed_form(s) == {"main": 32, "pano": 20}


def test_the_calls_of_the_plan_are_the_closed_form():
    assert len(SETTINGS) > 4500
    for s in SETTINGS:
        assert expected_model_calls(s) == closed_form(s), s


def test_every_plan_is_consistent():
    """Each branch goes from level 0 to T through its own visits; a predict evaluates branches at
    the level they are at and blends only branches with an estimate there; each level has one last
    step, the only dumped one; time travel goes back and returns to where it left."""
    for s in SETTINGS:
        T, used = s.steps, [b for b in BRANCHES if b != "pano" or s.uses_panorama]
        level = dict.fromkeys(used, 0)
        seen: dict[str, set] = {b: set() for b in used}  # (level) a branch has an estimate at
        last_steps, dumped = [], []
        for v in visits(s):
            assert set(v.branches) <= set(used) and v.branches == tuple(b for b in BRANCHES if b in v.branches)
            assert all(level[b] == v.src for b in v.branches), (s, str(v))
            if v.op == "predict":
                assert v.src == v.dst and set(v.branches) <= set(v.blend)
                for b in v.branches:
                    seen[b].add(v.src)
                assert all(v.src in seen[b] for b in v.blend), (s, str(v))
                assert all(level[b] == v.src for b in v.blend)
            elif v.op == "travel":
                assert len(v.branches) == 1 and v.dst < v.src and s.time_travel and s.sync == "snellcaster"
            elif v.op == "return":
                assert len(v.branches) == 1 and v.dst > v.src and v.travel == "guided"
            else:
                assert v.op == "step" and v.dst == v.src + 1
                last_steps += [v.src] * v.last
                dumped += [v.src] * v.dump
                assert not v.dump or v.last
                assert v.sync == (s.sync == "snellcaster" and (s.sync_last_step or v.src < T - 1))
            level.update({b: v.dst for b in v.branches})
        assert level == dict.fromkeys(used, T), s
        assert last_steps == list(range(T))
        assert dumped == [k for k in range(T) if s.dump_every and k % s.dump_every == 0]


@pytest.fixture(scope="module")
def setup():
    scene, r, ws, i_minus = room_sphere(W, H, HP)
    p = ws.pano
    pano = scene.render_panorama(center=p.center, height=p.height, up=-p.rotation[:, 1], forward=p.rotation[:, 2])
    return ws, i_minus, AnalyticGenerator.from_scene(r.image, ws.object_mask, pano)


@pytest.mark.parametrize(
    "kw",
    [
        {"tt_repeats_pano": 2, "dump_every": 2},
        {"tt_mode": "repaint", "tt_length": 2, "tt_repeats_main": 2, "tt_repeats_pano": 3, "sync_last_step": False},
        {"sde": True, "tt_renoise": "euler_maruyama", "tt_window_floor": True, "tt_length": 2, "panorama": False},
    ],
)
def test_the_run_follows_its_plan(setup, kw):
    ws, i_minus, gen = setup
    s = SamplerSettings(steps=6, tt_window=[0.0, 0.7], progress=False, levels=3, **kw)
    rec = Recorder(gen)
    out = sample(rec, ws, i_minus, "p", "p360", s, seed=0)
    sig = [float(x) for x in gen.sigmas(s.steps, H, W, kind=s.schedule)]
    main_shape = (1,) + gen.geometry.latent_shape(H, W)
    got = [("main" if tuple(z.shape) == main_shape else "pano", sg) for z, sg in rec.velocity_calls]
    plan = visits(s)
    assert got == [(b, sig[v.src]) for v in plan if v.op == "predict" for b in v.branches]
    assert out.model_calls == expected_model_calls(s)
    assert [d["step"] for d in out.dumps] == [v.src for v in plan if v.op == "step" and v.dump]
    assert torch.isfinite(out.image).all()
