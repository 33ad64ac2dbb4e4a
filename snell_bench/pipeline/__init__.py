"""The Snellcaster pipeline: every stage from a config to a scored image, in order.

Every job (``preview``, ``generate``, the experiment grid and the speed/accuracy sweep) calls
these and wires no stage itself::

    pool = ModelPool(cfg.models.memory_gb)          # the models, loaded once each
    inputs = prepare_inputs(cfg, pool=pool)         # 1-5: what every method of a (scene, object) shares
    result = run_method(apply_method(cfg), inputs,  # 6-8: one method's image, scored
                        scorers=scorers_of(cfg.metrics, pool))

1. scene source: I⁻, its depth and camera (:func:`load_scene`);
2. where the object stands (:func:`surface_region`), the object (:func:`build_object`) placed on it
   (:func:`place`);
3. ray-traced warps (:func:`trace_warps`);
4. the reference render and its metric mask (:func:`render_reference`);
5. the true render of a procedural scene (:func:`render_true_scene`);
6. the generator (:func:`build_generator`);
7. sampling with the method's settings (:func:`sample_method`);
   7b. relighting (:func:`relight_image`);
8. masked metrics against the reference (:func:`score`).

Modules: :mod:`.cell` (what flows between stages), :mod:`.inputs` (1-5), :mod:`.methods` (6-7b),
:mod:`.scoring` (8 and :func:`run_method`), :mod:`.pool` (the model pool). Stage times are wall
seconds in ``timings``, keyed ``scene``, ``warps``, ``reference``, ``true_render`` (inputs) and
``generator`` (loading the method's model), ``sampling``, ``relighter``, ``relight``, ``metrics`` (a method); a
model's load time is reported by every cell that uses it.
"""

from snell_bench.pipeline.cell import (
    CellInputs,
    CellResult,
    Degenerate,
    Skip,
    apply_method,
    cell_seed,
    full_prompt,
    generator_on_procedural,
    initial_noise_record,
    object_phrase,
    prompt_of,
    scene_pipeline_record,
)
from snell_bench.pipeline.inputs import (
    build_object,
    load_scene,
    place,
    prepare_inputs,
    render_reference,
    render_true_scene,
    surface_region,
    trace_warps,
)
from snell_bench.pipeline.methods import (
    build_generator,
    inpaint_mask,
    relight_image,
    relight_prompt,
    sample_method,
)
from snell_bench.pipeline.pool import ModelPool, model_bytes
from snell_bench.pipeline.scoring import finish_method, run_method, sample_stage, score, scorers_of
from snell_bench.scene.sources import SceneInputs

__all__ = [
    "SceneInputs",
    "CellInputs",
    "CellResult",
    "Degenerate",
    "Skip",
    "ModelPool",
    "model_bytes",
    "apply_method",
    "full_prompt",
    "object_phrase",
    "prompt_of",
    "cell_seed",
    "generator_on_procedural",
    "initial_noise_record",
    "scene_pipeline_record",
    "load_scene",
    "build_object",
    "surface_region",
    "place",
    "trace_warps",
    "render_reference",
    "render_true_scene",
    "build_generator",
    "sample_method",
    "inpaint_mask",
    "relight_image",
    "relight_prompt",
    "score",
    "scorers_of",
    "prepare_inputs",
    "sample_stage",
    "finish_method",
    "run_method",
]
