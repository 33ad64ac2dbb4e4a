"""Tables and figures of the paper, rebuilt from a run directory alone.

A grid experiment's run directory holds one folder per cell,
``<scene>-<variation>/<object>/<method>/``, with ``image.png``, ``reference.png``, ``mask.png`` and
``metrics.json``; a speed/accuracy sweep is a grid whose cells are ``<method>@<setting>``.
The reports read those files and nothing else:

- :mod:`.records`: what a record file must hold to be a cell (the JSON Schemas
  :data:`GRID_RECORD`) and :func:`load_record`, which reads one and
  says what is wrong with it; a file that is not a cell record is left out of every report, with a
  warning naming it, and listed in the report's "Files skipped" section.
- :mod:`.collect`: :func:`collect` gathers every cell into a DataFrame, one row per cell.
- :mod:`.tables`: :func:`method_table` (Table 1: methods x metrics), :func:`block_table` (Table 3:
  a block of method rows per scene, or per object for the IOR sweep), :func:`scene_table` (scenes x
  methods for one metric), :func:`ablation_table` (Tables 2 and 4: the ablation rows in the
  paper's order), :func:`time_travel_table` (a block per variant, a row per R_main) and
  :func:`savings_table` average over the cells whose ``status`` is ``"ok"``;
  :func:`provenance_line` and :func:`cell_notes` say where the numbers come from and which cells
  or values are missing; :func:`rank_marks` ranks best and second best.
- :mod:`.writers`: :func:`to_markdown` (a pipe table by :meth:`pandas.DataFrame.to_markdown`),
  :func:`to_latex` and :func:`to_csv` write a table; :mod:`.tradeoff_text`
  (:func:`tradeoff_markdown`) the speed/accuracy part's per-setting table.
- :mod:`.text`: the helpers every module shares: missing values, reasons on one line, slugs, and
  escaping every string from the cells for its format (:func:`md_escape`, :func:`md_code`,
  :func:`tex_escape`; the HTML page's templates escape every string themselves).
- :mod:`.figures`: :func:`qualitative_figure` (reference | Snellcaster | baselines, each tile with
  an inset zoom on the object; :func:`qualitative_pages` draws every row, ``max_rows`` a page),
  :func:`panorama_figure` (main image beside its panorama), :func:`time_travel_figure` (PSNR and
  LPIPS against R_main) and :func:`pareto_figure` (a sweep's cost against fidelity).
- :mod:`.tradeoff`: a sweep's rows (:func:`collect_tradeoff`), per-setting table
  (:func:`tradeoff_table`), Pareto front and reference convergence.
- :mod:`.html`: ``index.html``, the report as one static page (sortable tables, plots, gallery,
  missing values) from the Jinja2 templates of ``templates/``; :mod:`.gallery` its images (copies,
  thumbnails, the |error| maps of the metrics protocol, :func:`error_map`); :mod:`.plots` its
  Plotly figures (each metric against every swept axis, a sweep's settings and Pareto front).
- :mod:`.build`: :func:`build_reports` writes everything, a grid with settings' speed/accuracy
  part included (:class:`NoCells` where there is nothing to report; :func:`summary_line` says
  where it went).

Conventions:
    - A table is a DataFrame whose index holds the row labels (``index.name`` is the row header)
      and whose columns are metric names (``psnr``, ``lpips``, ...) plus ``n``, the number of
      ``ok`` cells averaged; :func:`scene_table` instead has method labels as columns and one
      metric for all of them. Block tables have a two-level index (scene, method) and are
      ranked per column within each block. Values are floats, NaN where no cell has a value; the writers show
      NaN as "—".
    - Writers read display hints from ``table.attrs``: ``provenance``, ``notes``, ``caption``,
      ``metric`` (the metric of every value column, for scene tables) and ``highlight``
      (``"columns"``, ``"rows"`` or ``"blocks"``: where best and second best are ranked).
    - The provenance line names the model, the scene source, the recipe and the metrics
      protocol the cells record, and the cell counts.
    - Best and second best are ranked on the values as displayed (rounded to the metric's
      format), so ties share the mark; a column with fewer than two values gets no mark.
    - Ordering is deterministic: cells sorted by scene, variation, object, method; method rows
      sorted by method name unless an ``order`` is given.
    - A table never averages over a swept axis (:func:`swept_axes`: the IOR, when one object ran at
      two or more IORs): where it varies within a row's cells, it is the table's outer index level.
"""

from .build import NoCells, Written, build_reports, summary_line
from .collect import collect, recipe_and_protocol, skipped_files
from .figures import (
    clip_outliers,
    figure_rows,
    pages,
    panorama_figure,
    panorama_pages,
    pareto_figure,
    qualitative_figure,
    qualitative_pages,
    time_travel_figure,
)
from .gallery import error_map, gallery
from .html import table_view, write_grid_page, write_tradeoff_page
from .plots import axis_plots, pareto_plot, tradeoff_axis_plot
from .records import GRID_RECORD, load_record
from .spec import (
    ABLATION_METRICS,
    ABLATION_ROWS,
    ABLATION_TABLE2_METRICS,
    MEASURES,
    METRICS,
    MISSING,
    MODEL_DESCRIPTIONS,
    OPTIONAL_METRICS,
    SCENE_METRICS,
    TABLE1_METRICS,
    TIME_TRAVEL_ROWS,
    TIME_TRAVEL_VARIANTS,
    Metric,
    metric_spec,
)
from .tables import (
    DEFAULT_IOR,
    SAVING_METHODS,
    TIME_TRAVEL_METRICS,
    ablation_table,
    block_table,
    cell_notes,
    ior_label,
    method_labels,
    method_table,
    object_ior,
    provenance_line,
    rank_marks,
    savings_table,
    scene_table,
    swept_axes,
    time_travel_table,
    with_recorded_metrics,
)
from .text import md_code, md_escape, tex_escape
from .tradeoff import (
    CONVERGED_METRICS,
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
)
from .tradeoff_text import tradeoff_markdown
from .writers import (
    pipe_table,
    plain_markdown,
    to_csv,
    to_latex,
    to_markdown,
)

__all__ = [
    "clip_outliers",
    # grid experiments
    "Metric",
    "METRICS",
    "TABLE1_METRICS",
    "ABLATION_METRICS",
    "ABLATION_ROWS",
    "ABLATION_TABLE2_METRICS",
    "SCENE_METRICS",
    "OPTIONAL_METRICS",
    "MEASURES",
    "TIME_TRAVEL_ROWS",
    "TIME_TRAVEL_VARIANTS",
    "TIME_TRAVEL_METRICS",
    "MODEL_DESCRIPTIONS",
    "MISSING",
    "SAVING_METHODS",
    "metric_spec",
    "collect",
    "skipped_files",
    "GRID_RECORD",
    "load_record",
    "recipe_and_protocol",
    "provenance_line",
    "cell_notes",
    "method_labels",
    "with_recorded_metrics",
    "object_ior",
    "ior_label",
    "DEFAULT_IOR",
    "swept_axes",
    "method_table",
    "scene_table",
    "block_table",
    "ablation_table",
    "time_travel_table",
    "savings_table",
    "rank_marks",
    "pipe_table",
    "to_markdown",
    "plain_markdown",
    "to_latex",
    "to_csv",
    "md_escape",
    "md_code",
    "tex_escape",
    "figure_rows",
    "pages",
    "qualitative_figure",
    "qualitative_pages",
    "panorama_figure",
    "panorama_pages",
    "time_travel_figure",
    "build_reports",
    "NoCells",
    "Written",
    "summary_line",
    # the HTML page
    "table_view",
    "write_grid_page",
    "write_tradeoff_page",
    "gallery",
    "error_map",
    "axis_plots",
    "tradeoff_axis_plot",
    "pareto_plot",
    # speed/accuracy sweeps
    "STAGES",
    "TOTAL_STAGES",
    "TOTAL_NOTE",
    "RECORD_METRICS",
    "CONVERGED_METRICS",
    "PRESET_AXIS",
    "SPP_KEY",
    "pareto_front",
    "collect_tradeoff",
    "reference_psnr_vs_max_spp",
    "tradeoff_table",
    "tradeoff_markdown",
    "fidelity_column",
    "pareto_figure",
]
