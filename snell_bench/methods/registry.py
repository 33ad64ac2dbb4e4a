"""The one registry of methods: ``method.kind`` (or ``method._target_``) to its
:class:`~snell_bench.methods.Method` class, the only dispatch on a method's kind.

- The built-in kinds (:data:`BUILTIN`): ``snellcaster``, ``t2i``, ``inpaint``, ``external`` (a
  diffusers pipeline) and ``images``, one module of :mod:`snell_bench.methods` each, imported when
  first used.
- Installed plugins: an entry point of the group ``snell_bench.methods`` (``name =
  "my_pkg.methods:MyMethod"``) adds the kind ``name``; each gets a method config of its own
  (:func:`snell_bench.config.compose.register_configs`), so ``method=name`` and
  ``grid.methods=[..., name]`` work with no YAML.
- A user's class by path: ``method._target_: my_pkg.methods.MyMethod`` in a method YAML (from the
  user's own config folder, ``hydra.searchpath=[file://my_conf]``), ``method.kind`` then naming it
  in tables and plans.

Nothing here imports a method module or a plugin before it is asked for.
"""

from __future__ import annotations

import functools
import importlib
import logging
from importlib.metadata import entry_points
from typing import Any

from omegaconf import DictConfig, OmegaConf

from snell_bench.config.choices import METHOD_ENTRY_POINTS, METHOD_KINDS

log = logging.getLogger(__name__)

__all__ = ["BUILTIN", "method_class", "method_of", "method_kinds", "installed_methods"]

#: The built-in kinds: ``method.kind`` -> ``module:Class``.
BUILTIN: dict[str, str] = {
    "snellcaster": "snell_bench.methods.snellcaster:Snellcaster",
    "t2i": "snell_bench.methods.t2i:TextToImage",
    "inpaint": "snell_bench.methods.inpaint:Inpaint",
    "external": "snell_bench.methods.pipeline:DiffusersPipeline",
    "images": "snell_bench.methods.images:Images",
}
assert tuple(BUILTIN) == METHOD_KINDS


@functools.lru_cache(maxsize=1)
def _entry_points() -> dict[str, Any]:
    return {ep.name: ep for ep in entry_points(group=METHOD_ENTRY_POINTS) if ep.name not in BUILTIN}


def installed_methods() -> tuple[str, ...]:
    """The kinds installed plugins add (entry points of ``snell_bench.methods``), sorted."""
    return tuple(sorted(_entry_points()))


def method_kinds() -> tuple[str, ...]:
    """Every kind ``method.kind`` may name here: the built-in ones, then the installed ones."""
    return tuple(BUILTIN) + installed_methods()


def _import(path: str) -> Any:
    module, sep, attr = path.partition(":")
    if not sep:
        module, _, attr = path.rpartition(".")
    obj = importlib.import_module(module)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


def _checked(obj: Any, where: str) -> type:
    from snell_bench.methods.base import Method

    if not (isinstance(obj, type) and issubclass(obj, Method)):
        raise ValueError(f"{where} is {obj!r}, not a subclass of snell_bench.methods.Method")
    return obj


@functools.cache
def method_class(kind: str, target: str | None = None) -> type:
    """The class of a method: ``target`` (``method._target_``, a dotted path) where given, else
    the built-in or installed kind ``kind``.

    Raises:
        ValueError: naming ``method.kind`` or ``method._target_``, the value and the choices, when it
            names no class or the class is no :class:`~snell_bench.methods.Method`.
    """
    if target:
        try:
            return _checked(_import(str(target)), f"method._target_={target!r}")
        except (ImportError, AttributeError, ValueError) as e:
            raise ValueError(
                f"method._target_={target!r} cannot be loaded ({type(e).__name__}: {e}); give the dotted path of a "
                "snell_bench.methods.Method subclass in an installed package (my_pkg.methods.MyMethod)"
            ) from None
    kind = str(kind)
    if kind in BUILTIN:
        return _checked(_import(BUILTIN[kind]), f"the built-in method kind {kind!r}")
    eps = _entry_points()
    if kind in eps:
        try:
            return _checked(eps[kind].load(), f"the entry point {kind!r} ({eps[kind].value})")
        except (ImportError, AttributeError, ValueError) as e:
            raise ValueError(
                f"method.kind={kind!r}: the installed plugin's entry point {eps[kind].value!r} cannot be loaded "
                f"({type(e).__name__}: {e})"
            ) from None
    raise ValueError(
        f"method.kind={kind!r} is unknown; use one of {list(method_kinds())} (installed plugins add theirs), or "
        "set method._target_ to a snell_bench.methods.Method subclass"
    )


def method_of(cfg: DictConfig):
    """The method of a cell's config: its class (:func:`method_class`) built with
    ``method.params`` as keyword arguments."""
    m = cfg.method
    cls = method_class(m.kind, m.get("_target_"))
    params = OmegaConf.to_container(m.params, resolve=True) if m.get("params") else {}
    try:
        return cls(**params)
    except TypeError as e:
        raise ValueError(f"method.params={params!r} do not fit {cls.__name__}: {e}") from None
