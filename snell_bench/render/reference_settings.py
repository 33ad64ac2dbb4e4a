"""The settings of a reference render: :class:`ReferenceSettings`.

Convention:
    - One frozen object holds every setting of
      :func:`~snell_bench.render.reference.render_reference`, checked when it is made; a caller
      that changes a few makes a new one (``ReferenceSettings(spp=8)``,
      ``dataclasses.replace(settings, spp=2)``, which checks them again).
    - The fields are the keys of the ``reference`` config node that the renderer takes (same names,
      same defaults), plus ``max_depth`` and ``fresnel`` (no config key), ``edge_threshold``
      (``warps.edge_threshold``) and ``seed`` (the run's ``seed``). What they mean: see
      :mod:`snell_bench.render.reference`.
"""

from __future__ import annotations

from dataclasses import dataclass

from snell_bench.render.pieces import check_sampler

__all__ = ["ReferenceSettings"]


@dataclass(frozen=True)
class ReferenceSettings:
    """The settings of a reference render (see the module's conventions).

    Attributes:
        spp: samples per pixel of the image pass (rounded up to a count ``sampler`` accepts).
        sampler: Mitsuba's sampler: a name of :data:`~snell_bench.render.pieces.SAMPLERS`, or a
            dict of its properties (see :func:`~snell_bench.render.pieces.check_sampler`).
        unobserved_spp: samples per pixel of the unobserved pass; ``None``: ``spp``.
        crop: render only the object's window; ``False``: the whole frame.
        crop_margin_px: pixels added on each side of the object's rectangle.
        self_noise: render the image pass in two independent halves and measure the self-noise.
        unobserved_threshold: object pixels whose unobserved share is below this form ``mask``.
        fresnel: ``True`` (default): the object is Mitsuba's ``dielectric`` (reflection and
            refraction sampled with Fresnel weights). ``False``: every pixel sample follows the
            refraction path (refraction at each interface, reflection only under total internal
            reflection) with weight 1, so ``image`` shows what our self-warp π^R predicts, without
            Fresnel reflection or loss: a purely geometric render, for cross-checks.
        reflection: with ``fresnel``: ``True`` (default): the physically complete dielectric;
            ``False``: refraction only, as the paper's Blender reference and the authors'
            ``render_gt``. Without ``fresnel`` there is no reflection either way.
        max_depth: longest light path (surface interactions, the emitter hit included).
        edge_threshold: relative depth jump at which the depth mesh is cut (as in ``compute_warps``).
        seed: seed of Mitsuba's sampler.

    Raises:
        ValueError: ``spp``, ``unobserved_spp``, ``crop_margin_px`` or ``unobserved_threshold``
            out of range, or an unknown sampler.
    """

    spp: int = 242
    sampler: str | dict = "orthogonal"
    unobserved_spp: int | None = 25
    crop: bool = True
    crop_margin_px: int = 4
    self_noise: bool = True
    unobserved_threshold: float = 0.05
    fresnel: bool = True
    reflection: bool = True
    max_depth: int = 16
    edge_threshold: float = 0.05
    seed: int = 0

    def __post_init__(self) -> None:
        spp, u_spp, margin = self.spp, self.unobserved_spp, self.crop_margin_px
        if int(spp) != spp or spp < 1:
            raise ValueError(f"spp must be a positive integer, got {spp!r}")
        if not (0.0 < self.unobserved_threshold <= 1.0):
            raise ValueError(f"unobserved_threshold must be in (0, 1], got {self.unobserved_threshold}")
        if u_spp is not None and (int(u_spp) != u_spp or u_spp < 1):
            raise ValueError(f"unobserved_spp must be a positive integer or None, got {u_spp!r}")
        if int(margin) != margin or margin < 0:
            raise ValueError(f"crop_margin_px must be a non-negative integer, got {margin!r}")
        check_sampler(self.sampler)

    @property
    def sampler_name(self) -> str:
        """The name of Mitsuba's sampler (``sampler``'s ``type`` where it is a dict)."""
        return check_sampler(self.sampler)["type"]
