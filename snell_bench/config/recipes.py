"""The recipes: every switch where the paper's text, the authors' released code and snell_bench's own
options differ, with the value each recipe sets.

``conf/recipe/paper.yaml`` (the default) and ``conf/recipe/authors.yaml`` set exactly these keys
(a test holds them to this table), and the documentation's "Reproducing the paper" (``docs/paper.md``)
prints it with the effect of each switch measured on CPU (``benchmarks/bench_recipes.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["BEFORE_SWITCHES", "RECIPES", "SWITCHES", "Switch", "recipe_values"]

#: The recipe names (``conf/recipe/<name>.yaml``).
RECIPES = ("paper", "authors")


@dataclass(frozen=True)
class Switch:
    """One config key on which the paper, the authors' code and snell_bench may differ.

    Attributes:
        key: the dotted config key (``sampler.tt_mode``).
        paper: the value the paper's text implies.
        authors: the value the authors' released code uses.
        own: snell_bench's own option where it goes beyond both (``None``: none).
        what: one line on what the switch changes.
    """

    key: str
    paper: Any
    authors: Any
    own: Any
    what: str


SWITCHES: tuple[Switch, ...] = (
    Switch(
        "sampler.schedule", "flux", "linear", None, "noise levels: the resolution-shifted FLUX schedule, or unshifted"
    ),
    Switch("sampler.sde", False, True, None, "step: deterministic Euler, or Euler-Maruyama (z + dt v + abs(dt) n)"),
    Switch("sampler.encode", "mean", "sample", None, "VAE encode of the synchronised images: posterior mean or a draw"),
    Switch("sampler.quantize", False, True, None, "8-bit round trip of the decoded and synchronised estimates"),
    Switch("sampler.sync_last_step", True, False, None, "synchronise the last step too"),
    Switch(
        "sampler.tt_mode",
        "guided",
        "guided",
        "repaint",
        "time travel: back from t + l with the estimate at t (guided), or re-predicted at every level (repaint)",
    ),
    Switch(
        "sampler.tt_window_floor",
        False,
        True,
        None,
        "time-travel window: 0.2 T <= i < 0.8 T, or both bounds rounded down (the same at T = 20)",
    ),
    Switch(
        "sampler.tt_renoise", "exact", "euler_maruyama", None, "time travel's renoising: exact kernel or Euler-Maruyama"
    ),
    Switch(
        "sampler.dpa_domain",
        "image",
        "image",
        "bands",
        "where DPA blends: whole images in [-1, 1], or each Laplacian band (low-pass in [-1, 1])",
    ),
    Switch(
        "sampler.lpw_pano",
        True,
        False,
        None,
        "Laplacian pyramid warping also into the panorama, or single-level remaps there",
    ),
    Switch(
        "sampler.pano_to_main",
        "frame",
        "frame",
        "object",
        "pixels of the main view that blend the panorama: the whole frame, or the object only",
    ),
    Switch("reference.reflection", False, False, True, "the reference includes the first-surface reflection"),
    Switch(
        "metrics.protocol",
        "paper",
        "authors",
        None,
        "evaluation: the paper's text, or eval/masked_metrics.py (adds lpips_box)",
    ),
    Switch("relight.lora", None, "kontext-community/relighting-kontext-dev-lora-v3", None, "relighting LoRA"),
)
"""Every recipe switch, in the order of the table in ``docs/paper.md``."""

#: Keys a recipe sets beyond :data:`SWITCHES` (the authors' relighting candidates; the paper's
#: count, 20, is the ``paper`` preset's, a cost setting).
EXTRA = {"authors": {"relight.candidates": 3}, "paper": {}}


def recipe_values(name: str) -> dict[str, Any]:
    """The dotted keys and values recipe ``name`` sets.

    Raises:
        ValueError: for an unknown recipe, naming the choices.
    """
    if name not in RECIPES:
        raise ValueError(f"unknown recipe {name!r}: use recipe=paper or recipe=authors")
    values = {s.key: getattr(s, name) for s in SWITCHES}
    values.update(EXTRA[name])
    return values


#: What the code did before a recipe switch existed, for cells recorded before it: a key absent from
#: a finished cell's record counts as unchanged only if the current value is this one (keys not
#: listed: the schema default). The per-band blend with its low-pass level in [0, 1] and the
#: pyramid-warp switch that also turned band blending off are no longer a setting, so no value
#: matches them.
BEFORE_SWITCHES: dict[str, Any] = {
    "recipe": None,
    "sampler.tt_mode": "repaint",
    "sampler.pano_to_main": "object",
    "sampler.dpa_domain": "<per band, low-pass in [0, 1]>",
    "reference.reflection": True,
}
