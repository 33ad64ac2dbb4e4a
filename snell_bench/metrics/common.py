"""What every masked metric shares: the evaluation protocols and their check, the exception a
metric that cannot be computed raises with its reason, and the grayscale weights.

Every name is re-exported by :mod:`snell_bench.metrics.functional` and :mod:`snell_bench.metrics`,
where users import them from.

Convention:
    - Protocol (config key ``metrics.protocol``): one of :data:`PROTOCOLS`; anything else raises
      ``ValueError`` naming the key and the allowed values (:func:`check_protocol`).
    - A metric returns a Python ``float`` or raises :class:`MetricUnavailable` with a ``reason``
      (:data:`EMPTY_MASK_REASON`, :data:`NON_FINITE_REASON`, weights or programs not configured);
      never a placeholder number.
"""

from __future__ import annotations

from typing import Any

from snell_bench.config.choices import Protocol

__all__ = [
    "EMPTY_MASK_REASON",
    "GRAY_WEIGHTS",
    "MetricUnavailable",
    "NON_FINITE_REASON",
    "PROTOCOLS",
    "PROTOCOL_CONFIG_KEY",
    "check_protocol",
]

#: Luma weights (R, G, B) of the grayscale conversion.
GRAY_WEIGHTS = (0.299, 0.587, 0.114)

#: The reason reported for an empty mask.
EMPTY_MASK_REASON = "empty mask: no object pixel refracts onto an observed surface"

#: The reason reported when the scored pixels hold NaN or infinite values.
NON_FINITE_REASON = "non-finite pixel values (NaN or inf) in the generated or reference image"

#: The evaluation protocols: ``"paper"`` (the paper's text) and ``"authors"`` (the authors' code).
PROTOCOLS = Protocol.values()

#: The config key that selects the protocol.
PROTOCOL_CONFIG_KEY = "metrics.protocol"


class MetricUnavailable(Exception):
    """A metric cannot be computed; ``reason`` says why (and, for missing weights or programs, which
    config key to set). Scoring code reports the metric as missing with this reason."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


def check_protocol(protocol: Any) -> str:
    """The protocol name, checked.

    Convention:
        ``protocol`` must be one of :data:`PROTOCOLS` (a ``str``); anything else raises ``ValueError``
        naming the config key ``metrics.protocol`` and the allowed values.

    Args:
        protocol: the protocol name to check.

    Returns:
        ``protocol``, unchanged.

    Raises:
        ValueError: ``protocol`` is not one of :data:`PROTOCOLS`.
    """
    if not isinstance(protocol, str) or protocol not in PROTOCOLS:
        allowed = ", ".join(repr(p) for p in PROTOCOLS)
        raise ValueError(f"unknown evaluation protocol {protocol!r}: set {PROTOCOL_CONFIG_KEY} to one of {allowed}")
    return protocol
