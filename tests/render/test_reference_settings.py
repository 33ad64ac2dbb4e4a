"""The settings of the reference render: one frozen, checked object whose fields are the
``reference`` node's keys that the renderer takes (same defaults). Imports no Mitsuba."""

import dataclasses

import pytest

from snell_bench.config import ReferenceConfig
from snell_bench.render import ReferenceSettings


def test_shared_keys_have_the_config_defaults():
    node = dataclasses.asdict(ReferenceConfig())
    fields = {f.name: f.default for f in dataclasses.fields(ReferenceSettings)}
    shared = fields.keys() & node.keys()
    assert shared == {
        "spp",
        "sampler",
        "unobserved_spp",
        "crop",
        "crop_margin_px",
        "self_noise",
        "unobserved_threshold",
        "reflection",
    }
    for k in shared:
        assert fields[k] == node[k], k


def test_frozen_and_replaced():
    s = ReferenceSettings()
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.spp = 2
    t = dataclasses.replace(s, spp=2, sampler="independent")
    assert (t.spp, t.sampler_name, s.spp) == (2, "independent", 242)
    assert ReferenceSettings(sampler={"type": "stratified", "jitter": False}).sampler_name == "stratified"


@pytest.mark.parametrize(
    "changes,match",
    [
        ({"spp": 0}, "spp must be a positive integer"),
        ({"spp": 2.5}, "spp must be a positive integer"),
        ({"unobserved_spp": 0}, "unobserved_spp"),
        ({"crop_margin_px": -1}, "crop_margin_px"),
        ({"unobserved_threshold": 0.0}, "unobserved_threshold"),
        ({"sampler": "sobol"}, "reference.sampler='sobol'"),
        ({"sampler": {"type": "stratified", "sample_count": 4}}, "sample_count"),
    ],
)
def test_checked_when_made_and_replaced(changes, match):
    with pytest.raises(ValueError, match=match):
        ReferenceSettings(**changes)
    with pytest.raises(ValueError, match=match):
        dataclasses.replace(ReferenceSettings(), **changes)
