"""Tables and figures of the paper, rebuilt from a run directory alone.

A grid experiment's run directory holds one folder per cell,
``<scene>-<variation>/<object>/<method>/``, with ``image.png``, ``reference.png``, ``mask.png`` and
``metrics.json``; a speed/accuracy sweep's holds ``<scene>-<variation>/<setting>/result.json``.
The reports read those files and nothing else:

- :mod:`.collect`: :func:`collect` gathers every cell into a DataFrame, one row per cell.
- :mod:`.tables`: :func:`method_table` (Table 1: methods x metrics), :func:`scene_table` (scenes x
  methods for one metric), :func:`ablation_table` (the ablation rows in the paper's order) and
  :func:`savings_table` average over the cells whose ``status`` is ``"ok"``;
  :func:`provenance_line` and :func:`cell_notes` say where the numbers come from and which cells
  or values are missing; :func:`rank_marks` ranks best and second best.
- :mod:`.writers`: :func:`to_markdown`, :func:`to_latex` and :func:`to_csv` write a table;
  :func:`tradeoff_markdown` and :func:`stdout_table` a sweep's per-setting table.
- :mod:`.figures`: :func:`qualitative_figure` (reference | Snellcaster | baselines, each tile with
  an inset zoom on the object) and :func:`pareto_figure` (a sweep's cost against fidelity).
- :mod:`.tradeoff`: a sweep's rows (:func:`collect_tradeoff`), per-setting table
  (:func:`tradeoff_table`), Pareto front and reference convergence.
- :mod:`.build`: :func:`build_reports` and :func:`build_tradeoff_report` write everything.

Conventions:
    - A table is a DataFrame whose index holds the row labels (``index.name`` is the row header)
      and whose columns are metric names (``psnr``, ``lpips``, ...) plus ``n``, the number of
      ``ok`` cells averaged; :func:`scene_table` instead has method labels as columns and one
      metric for all of them. Values are floats, NaN where no cell has a value; the writers show
      NaN as "—".
    - Writers read display hints from ``table.attrs``: ``provenance``, ``notes``, ``caption``,
      ``metric`` (the metric of every value column, for scene tables) and ``highlight``
      (``"columns"`` or ``"rows"``: where best and second best are ranked).
    - Best and second best are ranked on the values as displayed (rounded to the metric's
      format), so ties share the mark; a column with fewer than two values gets no mark.
    - Ordering is deterministic: cells sorted by scene, variation, object, method; method rows
      sorted by method name unless an ``order`` is given.
"""

from .build import build_reports, build_tradeoff_report
from .collect import collect
from .figures import clip_outliers, pareto_figure, qualitative_figure
from .spec import (
    ABLATION_METRICS,
    ABLATION_ROWS,
    METRICS,
    MISSING,
    MODEL_DESCRIPTIONS,
    TABLE1_METRICS,
    Metric,
    metric_spec,
)
from .tables import (
    SAVING_METHODS,
    ablation_table,
    cell_notes,
    method_labels,
    method_table,
    provenance_line,
    rank_marks,
    savings_table,
    scene_table,
)
from .tradeoff import (
    PRESET_AXIS,
    RECORD_METRICS,
    SPP_KEY,
    STAGES,
    TOTAL_NOTE,
    TOTAL_STAGES,
    collect_tradeoff,
    fidelity_column,
    pareto_front,
    reference_psnr_vs_max_spp,
    tradeoff_table,
    update_spp_records,
)
from .writers import pipe_table, plain_markdown, stdout_table, to_csv, to_latex, to_markdown, tradeoff_markdown

__all__ = [
    "clip_outliers",
    # grid experiments
    "Metric",
    "METRICS",
    "TABLE1_METRICS",
    "ABLATION_METRICS",
    "ABLATION_ROWS",
    "MODEL_DESCRIPTIONS",
    "MISSING",
    "SAVING_METHODS",
    "metric_spec",
    "collect",
    "provenance_line",
    "cell_notes",
    "method_labels",
    "method_table",
    "scene_table",
    "ablation_table",
    "savings_table",
    "rank_marks",
    "pipe_table",
    "to_markdown",
    "plain_markdown",
    "to_latex",
    "to_csv",
    "qualitative_figure",
    "build_reports",
    # speed/accuracy sweeps
    "STAGES",
    "TOTAL_STAGES",
    "TOTAL_NOTE",
    "RECORD_METRICS",
    "PRESET_AXIS",
    "SPP_KEY",
    "pareto_front",
    "collect_tradeoff",
    "reference_psnr_vs_max_spp",
    "update_spp_records",
    "tradeoff_table",
    "tradeoff_markdown",
    "stdout_table",
    "fidelity_column",
    "pareto_figure",
    "build_tradeoff_report",
]
