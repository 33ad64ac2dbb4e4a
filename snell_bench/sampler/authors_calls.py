"""The model calls of the authors' dual-view loop (github YueYin27/snellcaster @ c4ad33f,
``pipeline_snellcaster_flux_dual_view.py``), the basis the paper's timing was measured on.

Their loop, as it reads:
    - every step ``i`` of ``T`` makes one call of ``_compute_noise_predictions``, which runs the
      transformer on the main latents and on the panorama latents (one call per view);
    - a step in the window ``int(start T) <= i < int(end T)`` with ``R > 1`` repeats then time-travels:
      ``R - 1`` times it renoises the main latents one level back and calls the model on them (both
      views again; the main output is discarded, the step back uses the synchronised ``x0``), then it
      re-predicts once at the step's own level (both views); the panorama never travels but is
      evaluated in every one of these calls.

So a travelling step costs ``1 + (R - 1) + 1 = R + 1`` calls of each view; with the paper's setting
(``T = 20``, window ``[0.2, 0.8)``: steps 4 to 15, ``R = 3``) that is ``20 + 12 * 3 = 56`` per view.
snell_bench's loop makes 32 main-view and 20 panorama calls for the same setting
(:func:`~snell_bench.sampler.expected_model_calls`): guided time travel without the discarded calls, and
the panorama evaluated only when it steps.
"""

from __future__ import annotations

from snell_bench.config.sampler import SamplerSettings

__all__ = ["authors_model_calls"]


def authors_model_calls(s: SamplerSettings) -> dict[str, int]:
    """The transformer calls per view the authors' loop makes with the steps, window and main-view
    repeats of ``s`` (module docstring): ``T + R n`` each, with ``n`` window steps (both bounds
    rounded down, as their ``int(T * ratio)``) when ``R > 1``, else ``T``; ``R - 1`` fewer when the
    window starts at step 0 (no level to travel back to).

    Args:
        s: its ``steps``, ``tt_window`` and ``tt_repeats_main`` are read (their code has one repeat
            count, the main view's; ``time_travel: false`` is ``R = 1``).

    Returns:
        ``{"main": n, "pano": n}``, the same for both views.

    Examples:
        >>> authors_model_calls(SamplerSettings())
        {'main': 56, 'pano': 56}
        >>> authors_model_calls(SamplerSettings(time_travel=False))
        {'main': 20, 'pano': 20}
    """
    T = s.steps
    lo, hi = (min(max(int(T * w), 0), T) for w in s.tt_window)
    R = s.tt_repeats_main if s.time_travel else 1
    n = max(hi - lo, 0) if R > 1 else 0
    calls = T + R * n
    if n and lo == 0:  # at step 0 there is no noisier level: the renoise rounds stop at once
        calls -= R - 1
    return {"main": calls, "pano": calls}
