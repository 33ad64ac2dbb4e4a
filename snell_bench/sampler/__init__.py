"""Flow-matching sampling: closed-form schedules, pure steps, and the synchronized Snellcaster loop.

The loop takes its noise schedule from the generator (:meth:`~snell_bench.models.base.Generator.sigmas`).
"""

from snell_bench.config.sampler import SYNC_MODES, SamplerSettings
from snell_bench.sampler.schedule import flux_shift, flux_sigmas, linear_sigmas
from snell_bench.sampler.steps import euler_estimate, renoise, stochastic_step, sync_step

__all__ = [
    "flux_shift",
    "flux_sigmas",
    "linear_sigmas",
    "euler_estimate",
    "renoise",
    "stochastic_step",
    "sync_step",
    "SYNC_MODES",
    "SamplerSettings",
    "SampleResult",
    "expected_model_calls",
    "sample",
]


def __getattr__(name):  # the loop pulls in the imaging stack; load it on first use
    if name == "expected_model_calls":  # the plan alone
        from snell_bench.sampler.plan import expected_model_calls

        return expected_model_calls
    if name in ("SampleResult", "sample"):
        from snell_bench.sampler import snellcaster

        return getattr(snellcaster, name)
    raise AttributeError(name)
