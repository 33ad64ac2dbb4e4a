"""The sampler's loop as a plan: the ordered visits of the noise levels, decided by the settings alone.

:func:`~snell_bench.sampler.snellcaster.sample` walks the list :func:`visits` returns, one
:class:`Visit` at a time; time travel (guided or repaint, :class:`~snell_bench.config.sampler.SamplerSettings`'s
``tt_*``) is laid out in it as extra visits, as diffusers' RePaint scheduler lays out its jumps, so
the loop itself has no nested repeats.

Convention:
    - Noise levels are indices into the run's schedule ``sigmas`` (``T + 1`` levels, ``0`` the noisiest,
      ``T`` clean); a visit goes from level ``src`` to level ``dst``.
    - Branches are named ``"main"`` (the main view) and ``"pano"`` (the panorama); a visit's branches
      are in that order, and the loop acts on them in that order (the order of the random draws).
    - The four operations:

      ``predict`` (``src == dst``): the model's velocity for ``branches`` at ``src`` (one batched call
      when both), the clean estimates decoded when ``sync`` or ``dump`` asks for images, and with
      ``sync`` the images of the branches in ``blend`` warped, blended and encoded again. A branch
      of ``blend`` missing from ``branches`` reads its latest estimate at this level (repaint: the
      branch stopped repeating; guided: it did not travel);

      ``travel`` (``dst < src``): one branch's latent renoised back to the noisier level ``dst``;

      ``return`` (``dst > src``, guided time travel only): one branch steps back down to ``dst`` with
      its held estimate, no model call;

      ``step`` (``dst = src + 1``): each of ``branches`` steps to ``dst`` with its estimate; ``dump``
      records the level's images, ``last`` marks the last pass over level ``src``.
    - ``travel`` names the time travel a visit belongs to: ``"guided"``, ``"repaint"`` (every visit
      of a block that repeats) or ``""``.

Example:
    Three steps, time travel everywhere, the main view twice (guided: no level to travel back to at
    step 0):

    >>> from snell_bench.config.sampler import SamplerSettings
    >>> for v in visits(SamplerSettings(steps=3, tt_window=[0.0, 1.0], tt_repeats_main=2)):
    ...     print(v)
    predict main+pano 0 sync
    step    main+pano 0->1 sync last
    predict main+pano 1 sync
    travel  main 1->0 guided
    return  main 0->1 guided
    predict main 1 sync main+pano guided
    step    main+pano 1->2 sync last
    predict main+pano 2 sync
    travel  main 2->1 guided
    return  main 1->2 guided
    predict main 2 sync main+pano guided
    step    main+pano 2->3 sync last
    >>> expected_model_calls(SamplerSettings(steps=3, tt_window=[0.0, 1.0], tt_repeats_main=2))
    {'main': 5, 'pano': 3}
"""

from __future__ import annotations

from dataclasses import dataclass

from snell_bench.config.sampler import SamplerSettings

__all__ = ["BRANCHES", "Visit", "expected_model_calls", "visits"]

#: The branches, in the order the loop acts on them.
BRANCHES = ("main", "pano")


@dataclass(frozen=True)
class Visit:
    """One entry of the plan (module docstring).

    Attributes:
        op: ``predict``, ``travel``, ``return`` or ``step``.
        branches: the branches that act (predict: the model evaluates them; travel and return: one).
        src: the level the visit starts from.
        dst: the level it ends at (``src`` for ``predict``).
        travel: ``"guided"``, ``"repaint"`` or ``""`` (no time travel).
        sync: predict and step: the estimates at this level are synchronised.
        blend: predict: the branches whose estimates are synchronised (those that step from this level).
        dump: predict and step: the images at this level are dumped (decoded for it).
        last: step: the last pass over level ``src``.
    """

    op: str
    branches: tuple[str, ...]
    src: int
    dst: int
    travel: str = ""
    sync: bool = False
    blend: tuple[str, ...] = ()
    dump: bool = False
    last: bool = False

    def __str__(self) -> str:
        where = str(self.src) if self.op == "predict" else f"{self.src}->{self.dst}"
        words = [f"{self.op:7}", "+".join(self.branches), where]
        words += ["sync"] * self.sync + ["dump"] * self.dump + ["last"] * self.last
        if self.blend and self.blend != self.branches:
            words.append("+".join(self.blend))
        return " ".join(words + [self.travel] * bool(self.travel))


def in_window(i: int, s: SamplerSettings) -> bool:
    """Step ``i`` lies in the time-travel window ``[tt_window[0] T, tt_window[1] T)`` of a
    synchronised run with time travel (both bounds rounded down with ``tt_window_floor``)."""
    T = s.steps
    lo, hi = T * s.tt_window[0], T * s.tt_window[1]
    if s.tt_window_floor:
        lo, hi = int(lo), int(hi)
    return s.sync == "snellcaster" and s.time_travel and lo <= i < hi


def _repeats(travels: bool, s: SamplerSettings) -> dict[str, int]:
    """How often each branch runs a level (or block): ``tt_repeats_*`` where it ``travels``, else 1;
    the panorama 0 without its branch."""
    main = s.tt_repeats_main if travels else 1
    pano = (s.tt_repeats_pano if travels else 1) if s.uses_panorama else 0
    return {"main": main, "pano": pano}


def _level(k: int, running: tuple[str, ...], last: bool, repaint: bool, s: SamplerSettings) -> list[Visit]:
    """The visits of one pass over level ``k`` by the ``running`` branches: predict, guided time
    travel (every branch with ``R > 1`` renoises ``tt_length`` levels back and returns ``R - 1``
    times, the main view's first, then the branches that moved are predicted again) and the step.

    ``last``: the last pass over ``k``; ``repaint``: the level is part of a repeating block."""
    sync = s.sync == "snellcaster" and (s.sync_last_step or k < s.steps - 1)
    dump = bool(s.dump_every) and k % s.dump_every == 0 and last
    block = "repaint" if repaint else ""
    plan = [Visit("predict", running, k, k, travel=block, sync=sync, blend=running, dump=dump)]
    guided = _repeats(s.tt_mode == "guided" and in_window(k, s), s)
    back = k - s.tt_length  # the noisier level
    if max(guided.values()) > 1 and back >= 0:
        moved = tuple(b for b in BRANCHES if guided[b] > 1)
        for b in moved:
            for _ in range(guided[b] - 1):
                plan += [Visit("travel", (b,), k, back, "guided"), Visit("return", (b,), back, k, "guided")]
        plan.append(Visit("predict", moved, k, k, travel="guided", sync=sync, blend=running, dump=dump))
    plan.append(Visit("step", running, k, k + 1, travel=block, sync=sync, dump=dump, last=last))
    return plan


def visits(s: SamplerSettings) -> list[Visit]:
    """The ordered visits of a run with settings ``s`` (module docstring).

    The steps go in blocks: with ``tt_mode: repaint``, a block starting in the time-travel window is
    ``tt_length`` levels (fewer at the end) run ``tt_repeats_main`` / ``tt_repeats_pano`` times,
    each branch that runs it again travelling back to the block's start after each pass (the main
    view first); a branch that stops early keeps its latent and lends its latest estimates. Any
    other block is one level, run once (with ``guided``, its travel is inside the level's visits).
    """
    plan: list[Visit] = []
    i = 0
    while i < s.steps:
        repaint = s.tt_mode == "repaint" and in_window(i, s)
        length = min(s.tt_length, s.steps - i) if repaint else 1
        repeats = _repeats(repaint, s)
        passes = max(repeats.values())
        for r in range(passes):
            running = tuple(b for b in BRANCHES if r < repeats[b])
            for k in range(i, i + length):
                plan += _level(k, running, r == passes - 1, repaint and passes > 1, s)
            plan += [Visit("travel", (b,), i + length, i, "repaint") for b in BRANCHES if r + 1 < repeats[b]]
        i += length
    return plan


def expected_model_calls(s: SamplerSettings) -> dict[str, int]:
    """The velocity calls per branch that :func:`~snell_bench.sampler.snellcaster.sample` makes with
    settings ``s``: the branches of the plan's ``predict`` visits.

    In closed form, with ``T`` steps, the time-travel window's steps ``a <= i < b``
    (``a = ceil(tt_window[0] T)``, ``b = ceil(tt_window[1] T)``; ``floor`` of both with
    ``tt_window_floor``), ``n = b - a`` of them, the travel length ``l`` and ``R`` repeats of a branch
    (``tt_repeats_main`` / ``tt_repeats_pano``):

    - no time travel (``time_travel: false``, ``sync: none``, or ``R = 1``): ``T``;
    - ``guided``: ``T + [R > 1] max(0, b - max(a, l))``: one re-prediction per window step that
      has a level ``l`` steps back to travel to, however many repeats;
    - ``repaint``: ``T + (R - 1) min(T - a, ceil(n / l) l)``: every step of the ``ceil(n / l)``
      blocks of ``l`` steps that start in the window (the last one cut at ``T``) runs ``R`` times.

    The panorama's count is 0 without its branch (``sync: none`` or ``panorama: false``). A batched
    call on both latents counts once for each branch, as
    :attr:`~snell_bench.sampler.snellcaster.SampleResult.model_calls` does.

    Args:
        s: the settings the run uses (with ``skip_panorama_above``, the panorama's decision is the
            scene's: pass the settings with ``panorama`` as the run's ``decisions`` record it).

    Returns:
        ``{"main": n_main, "pano": n_pano}``.

    Examples:
        The paper's settings (T = 20, window [0.2 T, 0.8 T), main view x3, panorama x1):

        >>> expected_model_calls(SamplerSettings())
        {'main': 32, 'pano': 20}
        >>> expected_model_calls(SamplerSettings(tt_mode="repaint"))
        {'main': 44, 'pano': 20}
    """
    calls = dict.fromkeys(BRANCHES, 0)
    for v in visits(s):
        if v.op == "predict":
            for b in v.branches:
                calls[b] += 1
    return calls
