"""The entries of the grid's and the sweep's lists: object specs (``sphere``, ``sphere:1.333``,
``sphere:water``), names of config-group options, no repeats."""

from __future__ import annotations

from collections.abc import Sequence

from snell_bench.config.compose import group_options

__all__ = ["parse_object_spec", "object_overrides", "object_dir_name", "check_names", "check_unique"]


def parse_object_spec(spec: str) -> tuple[str, float | str | None]:
    """``"sphere"`` or ``"sphere:1.33"`` / ``"sphere:water"`` (a material override)."""
    name, _, ior = str(spec).partition(":")
    if not ior:
        return name, None
    try:
        return name, float(ior)
    except ValueError:
        return name, ior


def object_overrides(spec: str) -> list[str]:
    """The overrides of an object spec: ``["object=sphere", "object.ior=1.33"]``."""
    name, ior = parse_object_spec(spec)
    return [f"object={name}"] + ([] if ior is None else [f"object.ior={ior}"])


def object_dir_name(spec: str) -> str:
    """The folder of an object spec: ``sphere``, ``sphere-ior1.333``."""
    name, ior = parse_object_spec(spec)
    if ior is None:
        return name
    return f"{name}-ior{format(ior, '.10g') if isinstance(ior, float) else ior}"


def check_names(group: str, names: Sequence[str], key: str) -> None:
    """Raise ``ValueError`` naming ``key`` unless every name is an entry of the config group."""
    options = group_options(group)
    for n in names:
        if str(n) not in options:
            raise ValueError(f"{key}: unknown {group} {str(n)!r}; choose from {options} (snell_bench/conf/{group}/)")


def check_unique(values: Sequence, key: str, name=str) -> None:
    """Raise ``ValueError`` naming ``key`` and the repeated entries if two entries of a list name
    the same thing (``name`` maps an entry to what identifies it: its folder, for objects)."""
    seen: dict[str, object] = {}
    repeated = []
    for v in values:
        k = name(v)
        if k in seen and k not in repeated:
            repeated.append(k)
        seen.setdefault(k, v)
    if repeated:
        raise ValueError(
            f"{key} lists {', '.join(repr(r) for r in repeated)} more than once ({list(values)}); "
            "each entry is one set of cells: remove the repeats"
        )
