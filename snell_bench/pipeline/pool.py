"""One pool of the models a process loads: generators, FLUX Fill, relighters, pipeline baselines,
segmenters, depth estimators and metric backbones.

Convention:
    - A model is identified by its *kind* (``generator``, ``fill``, ``relighter``, ``pipeline``,
      ``segmenter``, ``depth``, ``scorers``) and a *key*: the YAML of the resolved config node that
      builds it (or any string that identifies it). The same kind and key return the same object.
    - Its lifetime is the pool's: whoever creates the pool (the runner of a sweep, one per process)
      decides how long models live; a model is loaded at most once per pool unless the memory
      budget forces it out.
    - ``memory_gb`` (``models.memory_gb``; ``None``: no limit) bounds the bytes of the parameters
      and buffers *resident* at once (:func:`model_bytes`): every tensor counted once, however
      many models hold it (FLUX Fill and Kontext share FLUX.1-dev's text encoders and VAE,
      :mod:`snell_bench.models.shared`). A model loaded for the first time is assumed to need the
      whole budget, so every other model makes room before it loads (least recently used first);
      afterwards its measured size is known and only as many models as needed make room.
    - Making room: with ``offload`` (``models.offload``), a model whose weights are on an
      accelerator is *offloaded*: its modules move to host memory, except those another resident
      model also holds, and move back on its next use (seconds, not a load from disk); a model on
      the host (the CPU stand-ins) is released. A module on the ``meta`` device moves in name
      only, so a memory plan can be checked with shapes alone. Models of a *scope* (a generator
      built from one scene's inputs) are released with :meth:`ModelPool.end_scope`.
    - Every load is recorded (:attr:`ModelPool.loads`: kind, key digest, label, seconds, bytes),
      and so is every release, offload and restore; sweeps write them to ``summary.json``.
"""

from __future__ import annotations

import gc
import hashlib
import logging
import time
import weakref
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import Any

import torch

log = logging.getLogger(__name__)

__all__ = ["ModelPool", "model_bytes", "ModelLoad"]


def _modules(obj: Any, depth: int = 2) -> list[torch.nn.Module]:
    """The torch modules an object holds: itself, its diffusers components, or its attributes (two
    levels down)."""
    if isinstance(obj, torch.nn.Module):
        return [obj]
    if depth == 0 or obj is None or isinstance(obj, (str, bytes, int, float, bool)):
        return []
    found: list[torch.nn.Module] = []
    components = getattr(obj, "components", None)
    values = list(components.values()) if isinstance(components, dict) else []
    if isinstance(obj, dict):
        values += list(obj.values())
    elif hasattr(obj, "__dict__"):
        values += list(vars(obj).values())
    for v in values:
        found += _modules(v, depth - 1)
    return found


def _bytes(modules: list[torch.nn.Module], seen: set[int] | None = None) -> int:
    seen = set() if seen is None else seen
    total = 0
    for m in modules:
        for t in (*m.parameters(), *m.buffers()):
            if id(t) not in seen:
                seen.add(id(t))
                total += t.numel() * t.element_size()
    return total


def model_bytes(obj: Any) -> int:
    """Bytes of the parameters and buffers of every torch module ``obj`` holds (each tensor counted
    once): a model's footprint in device memory, activations not included."""
    return _bytes(_modules(obj))


def _device(module: torch.nn.Module) -> torch.device:
    return next(module.parameters(), torch.empty(0)).device


def _on_accelerator(modules: list[torch.nn.Module]) -> bool:
    return any(t.device.type != "cpu" for m in modules for t in m.parameters())


@dataclass
class ModelLoad:
    """One load (or release) of a model."""

    kind: str
    key: str  #: a digest of the key (the resolved node's YAML)
    label: str
    seconds: float
    bytes: int
    event: str = "load"  #: ``load``, ``release``, ``offload`` (to host memory) or ``restore``

    def as_dict(self) -> dict:
        return {
            "kind": self.kind,
            "key": self.key,
            "label": self.label,
            "event": self.event,
            "seconds": round(self.seconds, 3),
            "bytes": self.bytes,
        }


@dataclass
class _Entry:
    model: Any
    seconds: float
    bytes: int
    label: str
    pinned: bool
    #: its modules are in host memory (``offload``); ``devices``: where each was
    offloaded: bool = False
    devices: dict | None = None

    def modules(self) -> list[torch.nn.Module]:
        return _modules(self.model)


class ModelPool:
    """Models by (kind, key), loaded once each; see the module docs.

    Args:
        memory_gb: the budget of resident model bytes (GiB); ``None``: no limit.
        offload: make room by moving a model on an accelerator to host memory (``True``) rather
            than releasing it.
        host: where offloaded modules go.
    """

    def __init__(self, memory_gb: float | None = None, *, offload: bool = True, host: str = "cpu") -> None:
        if memory_gb is not None and not memory_gb > 0:
            raise ValueError(f"models.memory_gb={memory_gb!r}: must be a positive number of GiB, or null (no limit)")
        self.offload = bool(offload)
        self.host = torch.device(host)
        self.budget = None if memory_gb is None else int(float(memory_gb) * 2**30)
        self._held: OrderedDict[tuple[str, str, Hashable], _Entry] = OrderedDict()
        self._sizes: dict[tuple[str, str], int] = {}  #: measured sizes of models loaded before
        self._finalized: set = set()  #: scopes whose end is already tied to an object's lifetime
        self.loads: list[ModelLoad] = []

    @staticmethod
    def digest(key: str) -> str:
        return hashlib.sha256(key.encode()).hexdigest()[:12]

    def held(self, kind: str | None = None) -> list[str]:
        """Labels of the models held now (of one kind)."""
        return [e.label for (k, _, _), e in self._held.items() if kind in (None, k)]

    def get(
        self,
        kind: str,
        key: str,
        build: Callable[[], Any],
        *,
        label: str = "",
        scope: Hashable | None = None,
        pin: bool = False,
        size: Callable[[], int | None] | None = None,
    ) -> tuple[Any, float]:
        """The model of ``(kind, key)`` (within ``scope``) and the seconds its load took, reported by
        every use so a cell's timings show the cost of the model it ran, whichever cell loaded it.

        ``build()`` loads it the first time; an exception it raises propagates and nothing is kept.
        A ``pin``-ned model (the metric backbones every cell needs) counts against the budget but
        is never released to make room. ``size()`` tells the bytes a first load will add
        (:func:`~snell_bench.models.sizes.node_weights_bytes`), so only that much room is made;
        ``None`` (or no ``size``): the whole budget.
        """
        k = (kind, key, scope)
        if k in self._held:
            self._held.move_to_end(k)
            e = self._held[k]
            if e.offloaded:
                self._restore(k)
            return e.model, e.seconds
        known = self._sizes.get((kind, key))
        if known is None and size is not None and self.budget is not None:
            known = size()
        self._make_room(known)
        t0 = time.perf_counter()
        model = build()
        seconds = time.perf_counter() - t0
        size = model_bytes(model)
        self._sizes[(kind, key)] = size
        self._held[k] = _Entry(model, seconds, size, label or kind, pin)
        self.loads.append(ModelLoad(kind, self.digest(key), label or kind, seconds, size))
        log.info("loaded %s %s in %.2f s (%.2f GiB)", kind, label, seconds, size / 2**30)
        self._make_room(0, keep=k)
        return model, seconds

    def put(self, kind: str, key: str, model: Any, *, label: str = "", scope: Hashable | None = None) -> None:
        """Hand the pool a model built elsewhere (a pipeline loaded by hand, a wrapped generator):
        later :meth:`get` calls of ``(kind, key)`` return it. It is recorded as a load of 0 s,
        replaces (releases) a model held under the same key, and counts against the budget."""
        k = (kind, key, scope)
        self.release(k)
        size = model_bytes(model)
        self._make_room(size)
        self._sizes[(kind, key)] = size
        self._held[k] = _Entry(model, 0.0, size, label or kind, False)
        self.loads.append(ModelLoad(kind, self.digest(key), label or kind, 0.0, size))

    def end_with(self, obj: Any, scope: Hashable) -> None:
        """Release the models of ``scope`` when ``obj`` is garbage-collected (once per scope)."""
        if scope not in self._finalized:
            self._finalized.add(scope)
            weakref.finalize(obj, self._end_finalized, scope)

    def _end_finalized(self, scope: Hashable) -> None:
        self._finalized.discard(scope)
        self.end_scope(scope)

    def _make_room(self, need: int | None, keep: tuple | None = None) -> None:
        """Offload or release models, least recently used first, until ``need`` more bytes fit in
        the budget (``None``: an unknown size, taken as the whole budget)."""
        if self.budget is None:
            return
        need = self.budget if need is None else need
        for k in list(self._held):
            if self.held_bytes() + need <= self.budget:
                break
            e = self._held.get(k)  # a finalizer may have released it meanwhile
            if e is None or k == keep or e.pinned or e.offloaded:
                continue
            if self.offload and _on_accelerator(e.modules()):
                keeping = self._held.get(keep) if keep is not None else None
                self._offload(k, protect={id(m) for m in keeping.modules()} if keeping is not None else set())
            else:
                self.release(k)

    def _resident_modules(self, but: tuple | None = None) -> list[torch.nn.Module]:
        return [m for k, e in self._held.items() if not e.offloaded and k != but for m in e.modules()]

    def held_bytes(self) -> int:
        """Bytes of the tensors of the resident models (not offloaded), each counted once."""
        return _bytes(self._resident_modules())

    def resident(self, kind: str | None = None) -> list[str]:
        """Labels of the models held and not offloaded (of one kind)."""
        return [e.label for (k, _, _), e in self._held.items() if kind in (None, k) and not e.offloaded]

    def _move(self, module: torch.nn.Module, device: torch.device) -> None:
        """Move one module (a ``meta`` module moves in name only: it has no data)."""
        if _device(module).type != "meta":
            module.to(device)

    def _offload(self, k: tuple, protect: set[int] = frozenset()) -> None:
        """Move model ``k``'s modules to host memory, except those another resident model (or the
        one being made room for, ``protect``) holds."""
        e = self._held[k]
        t0 = time.perf_counter()
        others = {id(m) for m in self._resident_modules(but=k)} | set(protect)
        mine = [m for m in e.modules() if id(m) not in others]
        freed = _bytes(mine)
        e.devices = {id(m): _device(m) for m in e.modules()}
        for m in mine:
            self._move(m, self.host)
        e.offloaded = True
        if torch.cuda.is_available():
            torch.cuda.empty_cache()
        seconds = time.perf_counter() - t0
        self.loads.append(ModelLoad(k[0], self.digest(k[1]), e.label, seconds, freed, "offload"))
        log.info("offloaded %s to %s in %.2f s (%.2f GiB)", e.label, self.host, seconds, freed / 2**30)

    def _restore(self, k: tuple) -> None:
        """Bring an offloaded model back to where its modules were, making room first."""
        e = self._held[k]
        resident = {id(m) for m in self._resident_modules(but=k)}
        away = [m for m in e.modules() if id(m) not in resident]
        self._make_room(_bytes(away), keep=k)
        t0 = time.perf_counter()
        devices = e.devices or {}
        for m in e.modules():
            if id(m) in devices and _device(m) != devices[id(m)]:
                self._move(m, devices[id(m)])
        e.offloaded, e.devices = False, None
        seconds = time.perf_counter() - t0
        self.loads.append(ModelLoad(k[0], self.digest(k[1]), e.label, seconds, _bytes(away), "restore"))
        log.info("restored %s in %.2f s", e.label, seconds)

    def release(self, k: tuple) -> None:
        """Drop one model (and the device memory it holds)."""
        e = self._held.pop(k, None)
        if e is None:
            return
        self.loads.append(ModelLoad(k[0], self.digest(k[1]), e.label, 0.0, e.bytes, "release"))
        del e
        gc.collect()
        if torch.cuda.is_available():
            torch.cuda.empty_cache()

    def in_scope(self, scope: Hashable) -> bool:
        """Whether any model of ``scope`` is held."""
        return any(k[2] == scope for k in self._held)

    def end_scope(self, scope: Hashable) -> None:
        """Release the models built for ``scope`` (e.g. a generator built from one scene's inputs)."""
        for k in [k for k in self._held if k[2] == scope and scope is not None]:
            self.release(k)

    def clear(self) -> None:
        for k in list(self._held):
            self.release(k)

    def summary(self) -> dict:
        """``{"budget_gb": ..., "loads": [...]}`` for ``summary.json``: every load and release in
        order."""
        return {
            "budget_gb": None if self.budget is None else self.budget / 2**30,
            "offload": self.offload,
            "loads": [x.as_dict() for x in self.loads],
        }
