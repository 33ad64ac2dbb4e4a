"""Errors raised by the model backends, with messages that say which config key to change.

Convention:
    - Every message names the config key that fixes the problem (``model.path``, ``model.device``,
      ``method.model_id``).
    - Both classes subclass :class:`RuntimeError`, so generic handlers keep working.
"""

from __future__ import annotations

__all__ = ["DeviceNotAvailableError", "WeightsNotFoundError"]


class WeightsNotFoundError(RuntimeError):
    """Model weights are not on this machine (neither in a local folder nor in the Hugging Face
    cache) and will not be downloaded."""


class DeviceNotAvailableError(RuntimeError):
    """The requested compute device (normally CUDA) is not available on this machine."""
