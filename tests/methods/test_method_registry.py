"""The method registry: the only dispatch on a method's kind; built-in kinds, a user's class by
_target_, an installed plugin by its entry point."""

import importlib

import numpy as np
import pytest
import torch

from snell_bench.config import compose
from snell_bench.methods import BUILTIN, Method, method_class, method_kinds, method_of
from snell_bench.pipeline import CellResult


class Flat(Method):
    """A user's method: I⁻ with the object's pixels painted one grey (``level``)."""

    default_label = "Flat grey"

    def __init__(self, level: float = 0.5) -> None:
        super().__init__(level=level)
        self.level = level

    def run(self, cfg, inputs, warps, t):
        inside = torch.from_numpy(warps.object_mask)[None, None]
        return CellResult(image=torch.where(inside, torch.full_like(inputs.i_minus, self.level), inputs.i_minus))


class NotAMethod:
    pass


def test_every_built_in_kind_is_one_class():
    for kind in BUILTIN:
        cls = method_class(kind)
        assert issubclass(cls, Method) and cls.kind == kind and cls.description
    assert method_kinds()[: len(BUILTIN)] == tuple(BUILTIN)


@pytest.mark.parametrize(
    "name, kind",
    [
        ("snellcaster", "snellcaster"),
        ("no_tt", "snellcaster"),
        ("t2i", "t2i"),
        ("inpaint", "inpaint"),
        ("qwen_image", "external"),
        ("images", "images"),
    ],
)
def test_each_shipped_method_config_names_its_kind(name, kind):
    assert type(method_of(compose([f"method={name}"]))).kind == kind


def test_the_models_each_kind_needs_in_the_order_it_uses_them():
    from snell_bench.experiment.order import cell_models
    from snell_bench.pipeline import apply_method

    def models(*overrides):
        return [k for k, _ in cell_models(apply_method(compose(list(overrides))))]

    assert models("method=snellcaster") == []  # the analytic stand-in is the group's own
    assert models("model=tiny_flux", "method=snellcaster") == ["generator"]
    assert models("model=tiny_flux", "method=snellcaster_relit") == ["generator", "relighter"]
    assert models("model=tiny_flux", "method=qwen_image") == ["pipeline"]
    assert models("model=tiny_flux", "method=inpaint") == ["fill"]
    assert models("method=images", "method.images=/tmp") == []


def test_an_unknown_kind_names_the_kinds_and_target():
    with pytest.raises(ValueError, match=r"method.kind='magic' is unknown; use one of \['snellcaster'.*'images'"):
        method_class("magic")


def test_a_users_class_by_target_with_its_params():
    m = method_of(compose([f"method._target_={__name__}.Flat", "method.kind=flat", "+method.params.level=0.25"]))
    assert isinstance(m, Flat) and m.level == 0.25 and m.params == {"level": 0.25}
    with pytest.raises(ValueError, match="not a subclass of snell_bench.methods.Method"):
        method_class("x", f"{__name__}.NotAMethod")
    with pytest.raises(ValueError, match=r"method._target_='nope.Nope' cannot be loaded"):
        method_class("x", "nope.Nope")
    with pytest.raises(ValueError, match=r"method.params=\{'colour': 1\} do not fit Flat"):
        method_of(compose([f"method._target_={__name__}.Flat", "+method.params.colour=1"]))


def test_a_users_method_runs_in_the_grid_beside_snellcaster(tmp_path):
    """Named by _target_ on the command line (one method in the grid: its keys apply to it alone)."""
    from snell_bench.experiment.runner import run_grid

    over = [
        "+experiment=smoke",
        "scene.width=160",
        "scene.height=96",
        "warps.pano_height=64",
        "warps.cache_dir=null",
        "sampler.steps=4",
        "reference.spp=4",
        "reference.true_spp=1",
        "grid.scenes=[kitchen]",
        "grid.methods=[t2i]",
        f"method._target_={__name__}.Flat",
        "+method.params.level=0.5",
        f"runs_dir={tmp_path / 'runs'}",
        f"reports_dir={tmp_path / 'reports'}",
    ]
    summary = run_grid(compose(over))
    assert summary["ok"] == 1
    from PIL import Image

    cell = tmp_path / "runs" / "smoke" / "kitchen-0" / "sphere" / "t2i"
    img = np.asarray(Image.open(cell / "image.png"))
    inside = np.asarray(Image.open(cell / "mask.png")) > 127
    assert (img[inside] == 128).all()  # 0.5 as 8 bits
    # job=plan and job=status know it as the runner does: done, with no time basis of its own
    from snell_bench.experiment.estimate import format_plan, make_plan
    from snell_bench.experiment.status import grid_status

    plan = make_plan(compose(over))
    assert [c.state for c in plan.cells] == ["done"]
    assert "Flat" in format_plan(plan) and "no time basis" in format_plan(plan)
    assert grid_status(compose(over)).counts["done"] == 1
    # its params are settings: a finished cell of other params is named, then recomputed on request
    from snell_bench.experiment.cells import SettingsChanged

    other = [o if o != "+method.params.level=0.5" else "+method.params.level=0.25" for o in over]
    with pytest.raises(SettingsChanged, match=r"method.params.level: 0.5 -> 0.25"):
        run_grid(compose(other))
    assert run_grid(compose([*other, "grid.on_change=recompute"]))["ok"] == 1


def test_an_installed_plugin_is_a_kind_and_a_method_config(tmp_path, monkeypatch):
    """An entry point of snell_bench.methods, as a pip-installed package declares it: method=<name>
    composes with no YAML of its own."""
    from hydra.core.config_store import ConfigStore
    from plugins import installed_plugin

    from snell_bench.methods import registry

    compose_module = importlib.import_module("snell_bench.config.compose")  # the module, not its function
    source = "from snell_bench.methods import Method\nclass Plugged(Method):\n    default_label = 'Plugged in'\n"
    caches = [registry._entry_points, registry.method_class, compose_module.plugin_methods]
    try:
        with installed_plugin(
            tmp_path,
            monkeypatch,
            "plug_method",
            source,
            {"snell_bench.methods": "plugged = plug_method:Plugged"},
            caches,
        ):
            assert "plugged" in method_kinds()
            cfg = compose(["method=plugged"])
            assert cfg.method.kind == "plugged" and cfg.method.label == "Plugged in"
            assert type(method_of(cfg)).__name__ == "Plugged"
    finally:
        ConfigStore.instance().repo["method"].pop("plugged.yaml", None)
