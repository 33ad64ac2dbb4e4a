"""What a method is: :class:`Method`, the one interface every method kind implements.

A method kind is one class (nerfstudio's method specification, for one cell of the grid): which
models it needs, how it makes its image from a group's shared inputs, what it costs for
``job=plan``, and whether a finished cell of it is still current. The grid, the model-major order,
``job=plan``, ``job=status`` and the reports ask the method and dispatch on nothing else.

A user's method is a subclass in the user's own package, named by ``method._target_`` in a method
YAML (from the user's own config folder on Hydra's search path) or by an entry point of the group
``snell_bench.methods`` (see :mod:`snell_bench.methods.registry`); ``method.params`` are its
constructor's keyword arguments.

Convention:
    - ``cfg`` is one cell's composed config with the method's switches applied
      (:func:`~snell_bench.pipeline.apply_method`); ``inputs`` are its group's shared
      :class:`~snell_bench.pipeline.CellInputs` (stages 1-5), ``warps`` the warps the method runs
      with (the group's, or its own where ``method.warps`` changes them).
    - :meth:`Method.run` returns a :class:`~snell_bench.pipeline.CellResult` whose ``image`` is
      ``(1, 3, H, W)`` float32 sRGB in [0, 1] of the scene's camera; relighting (``method.relight``)
      and scoring follow for every kind alike. It raises :class:`~snell_bench.pipeline.Skip` with
      the reason for a method that cannot run here (no weights, no GPU, no image), which the cell
      records as ``skipped``; any other exception fails the cell with its message.
    - A pool model is ``(kind, key)``: the :class:`~snell_bench.pipeline.ModelPool`'s kind
      (``generator``, ``fill``, ``pipeline``, ``relighter``, ...) and what identifies it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from omegaconf import DictConfig

from snell_bench.methods.cost import Basis, Estimate, ModelNeed, together_gb
from snell_bench.pipeline.cell import CellInputs, CellResult
from snell_bench.utils.timing import Timer

if TYPE_CHECKING:
    from snell_bench.optics.warps import WarpSet

__all__ = ["Method"]


class Method:
    """One kind of method (subclass it; see the module's convention).

    Attributes:
        kind: the kind's name (``method.kind``): a built-in's, or a plugin's entry point name.
        description: one line for the docs and ``job=plan``.
        default_label: a plugin's label in tables where no method YAML sets one.
        params: ``method.params``, the keyword arguments it was built with.
    """

    kind: ClassVar[str] = ""
    description: ClassVar[str] = ""
    #: The label of a plugin's rows where no method YAML sets ``method.label``.
    default_label: ClassVar[str] = ""

    def __init__(self, **params: Any) -> None:
        self.params = dict(params)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(f'{k}={v!r}' for k, v in self.params.items())})"

    # ------------------------------------------------------------------------ what it needs
    def models(self, cfg: DictConfig) -> list[tuple[str, str]]:
        """``(kind, key)`` of the pool's models its image needs (stages 6-7), in the order it uses
        them; the model-major order runs a cell after its last one is loaded. Relighting's model
        (``method.relight``) is added by the caller. Default: none."""
        return []

    def uses_generator(self, cfg: DictConfig) -> bool:
        """Whether it samples with the model's generator (``model.generator``): a generator built
        from the scene (the CPU stand-ins) is then the group's own, and ``job=plan`` lists it."""
        return False

    # ------------------------------------------------------------------------ how it runs
    def run(self, cfg: DictConfig, inputs: CellInputs, warps: WarpSet, t: Timer) -> CellResult:
        """Stage 7: the method's image on the group's ``inputs`` (see the module's convention);
        ``t`` times its stages (``t("sampling")``; a model's load time into ``t.seconds``)."""
        raise NotImplementedError(f"{type(self).__name__}.run")

    # ------------------------------------------------------------------------ what it costs
    def cost(self, scene_cfg: DictConfig, cfg: DictConfig, models: Sequence[ModelNeed], basis: Basis) -> Estimate:
        """``job=plan``: time and GPU memory of one cell (:class:`~snell_bench.methods.cost.Estimate`),
        ``scene_cfg`` the run's config with the cell's scene (its image size), ``models`` the
        models the cell needs, described. Default: no time basis."""
        weights = together_gb([m for m in models if m.needs_gpu], basis)
        return Estimate(None, weights, None, "none", f"{cfg.method.label}: no time basis ({type(self).__name__}.cost)")

    def describe(self, kind: str, key: str, cfg: DictConfig, basis: Basis) -> list[ModelNeed] | None:
        """``job=plan``: what a model of :meth:`models` that the plan does not know is, and whether its
        weights are here; None: the plan describes it (the model's generator, Fill, Kontext)."""
        return None

    # ------------------------------------------------------------------------ a finished cell
    def row_label(self, cfg: DictConfig) -> str:
        """The label of its row in every table and figure (``method.label``)."""
        return cfg.method.label

    def stale(self, cfg: DictConfig, record: dict, folder: Path, group: str) -> str | None:
        """Why a finished cell (its ``record`` in ``folder``; ``group`` is its
        ``<scene>-<variation>/<object>`` id) no longer holds though its settings and files are
        unchanged (an input it read has changed), or None. Default: None."""
        return None

    def check(self, cfg: DictConfig, group: str) -> list[str]:
        """Problems of the cell of ``group`` found before any work (one line each, naming the key and
        the fix). Default: none."""
        return []
