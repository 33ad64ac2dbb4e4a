"""The entries of the grid's lists: object specs (``sphere``, ``sphere:1.333``, ``sphere:water``),
names of config-group options, no repeats, the named override sets of its axes (the
speed/accuracy sweep, ``grid.axes``), and one cell's identity (:class:`CellId`)."""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from snell_bench.config.compose import group_options
from snell_bench.config.names import setting_slug

__all__ = [
    "parse_object_spec",
    "object_overrides",
    "object_dir_name",
    "group_id",
    "CellId",
    "Setting",
    "BASELINE",
    "PRESET_AXIS",
    "grid_settings",
    "check_names",
    "check_unique",
    "axis_settings",
]


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


def group_id(scene: str, variation: int, object_dir: str) -> str:
    """A scene/object group's id: ``<scene>-<variation>/<object folder>``, its folder in a run and
    in the benchmark kit (where it is the kit id).

    Examples:
        >>> group_id("kitchen", 0, "sphere-ior1.333")
        'kitchen-0/sphere-ior1.333'
    """
    return f"{scene}-{int(variation)}/{object_dir}"


@dataclass(frozen=True)
class Setting:
    """A named override set of the grid's axes (``grid.axes``, ``grid.presets``): one point of the
    speed/accuracy sweep, crossed with every method.

    Examples:
        >>> s = Setting("steps=8", "steps", 8, ("sampler.steps=8",))
        >>> s.slug, Setting("preset:fast", PRESET_AXIS, "fast", ("preset=fast",)).slug
        ('steps=8', 'preset-fast')
    """

    label: str
    #: The axis; ``None`` for the baseline, :data:`PRESET_AXIS` for a preset.
    axis: str | None = None
    #: The axis value (typed as Hydra types it), a mapping's label, or the preset's name.
    value: Any = None
    #: Hydra override strings, applied after the cell's own.
    overrides: tuple = ()

    @property
    def slug(self) -> str:
        """The label as a folder name (every character outside ``[A-Za-z0-9._=+-]`` -> ``-``)."""
        return setting_slug(self.label)


#: The setting without overrides: the run's config as is.
BASELINE = "baseline"
#: The axis of the settings that apply a whole preset (``preset:<name>``).
PRESET_AXIS = "preset"


@dataclass(frozen=True)
class CellId:
    """One cell of the grid, ``grid.scenes x grid.variations x grid.objects x grid.methods`` (x the
    settings of ``grid.axes`` and ``grid.presets`` when there are): what selects it
    (:meth:`overrides`) and where it lives (:meth:`folder`,
    ``<run>/<scene>-<variation>/<object folder>/<entry>``, the entry being the method, or
    ``<method>@<setting slug>``).

    Examples:
        >>> c = CellId("kitchen", 0, "sphere:1.333", "t2i")
        >>> c.group, c.name, c.overrides()
        ('kitchen-0/sphere-ior1.333', 'kitchen-0/sphere-ior1.333/t2i', ['scene=kitchen', 'scene.variation=0', 'object=sphere', 'object.ior=1.333', 'method=t2i'])
        >>> s = CellId("kitchen", 0, "sphere", "snellcaster", Setting("steps=8", "steps", 8, ("sampler.steps=8",)))
        >>> s.entry, s.overrides()[-2:]
        ('snellcaster@steps=8', ['method=snellcaster', 'sampler.steps=8'])
    """

    scene: str
    variation: int
    object: str  #: the object spec, as ``grid.objects`` gives it (``sphere``, ``sphere:1.333``)
    method: str
    setting: Setting | None = None

    @classmethod
    def grid(cls, g: Any) -> Iterator[CellId]:
        """Every cell of the grid node ``g``, in the runner's order (methods, then settings, innermost)."""
        settings = grid_settings(g) or [None]
        for scene, variation, spec, method in itertools.product(g.scenes, g.variations, g.objects, g.methods):
            for setting in settings:
                yield cls(str(scene), int(variation), str(spec), str(method), setting)

    @property
    def object_dir(self) -> str:
        return object_dir_name(self.object)

    @property
    def group(self) -> str:
        return group_id(self.scene, self.variation, self.object_dir)

    @property
    def entry(self) -> str:
        """The cell's entry of the method axis: the method, or ``<method>@<setting slug>``."""
        return self.method if self.setting is None else f"{self.method}@{self.setting.slug}"

    @property
    def name(self) -> str:
        return f"{self.group}/{self.entry}"

    def folder(self, root: str | Path) -> Path:
        """The cell's folder under the run folder ``root``."""
        return Path(root) / self.group / self.entry

    def overrides(self) -> list[str]:
        """The overrides that select this cell (a setting's last, so they win)."""
        scene = [f"scene={self.scene}", f"scene.variation={self.variation}"]
        own = [] if self.setting is None else list(self.setting.overrides)
        return [*scene, *object_overrides(self.object), f"method={self.method}", *own]


def grid_settings(g: Any) -> list[Setting]:
    """The settings of the grid node ``g``: none without ``axes`` and ``presets``; else
    :data:`BASELINE`, the settings of the axes named by ``only`` (all, when null) in order
    (:func:`axis_settings`), then one per preset (``preset:<name>``, the override
    ``preset=<name>``).

    Raises:
        ValueError: naming the key, for an unknown axis in ``only``, a reserved axis name, an axis
            :func:`axis_settings` rejects, or two settings with the same label or folder.
    """
    from omegaconf import OmegaConf

    axes = g.axes if isinstance(g.axes, dict) else OmegaConf.to_container(g.axes, resolve=True)
    axes = axes or {}
    only = [str(a) for a in g.only] if g.only is not None else list(axes)
    unknown = [a for a in only if a not in axes]
    if unknown:
        raise ValueError(f"grid.only: unknown axes {unknown}; choose from {list(axes)}")
    presets = [str(p) for p in (g.presets or [])]
    if not only and not presets:
        return []
    settings = [Setting(BASELINE)]
    for name in only:
        if name in (BASELINE, PRESET_AXIS):
            raise ValueError(f"grid.axes.{name}: {name!r} is reserved; rename the axis")
        spec = axes[name]
        for label, overrides in axis_settings(name, spec):
            value = label.split("=", 1)[1]  # "steps=8" -> 8 (typed as Hydra types it); a mapping's label as is
            settings.append(Setting(label, name, _typed(value) if isinstance(spec, str) else value, tuple(overrides)))
    settings += [Setting(f"{PRESET_AXIS}:{p}", PRESET_AXIS, p, (f"preset={p}",)) for p in presets]
    for what, names in (("label", [s.label for s in settings]), ("folder name", [s.slug for s in settings])):
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"grid.axes: duplicate setting {what}(s) {dup}; give the axis distinct values or labels")
    return settings


def _typed(text: str) -> Any:
    """A sweep value as Hydra types it (``"8"`` -> 8)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    return OverridesParser.create().parse_override(f"x={text}").value()


def check_names(group: str, names: Sequence[str], key: str, overrides: Sequence[str] = ()) -> None:
    """Raise ``ValueError`` naming ``key`` unless every name is an entry of the config group (with the
    config folders of ``overrides``' ``hydra.searchpath``)."""
    options = group_options(group, overrides)
    for n in names:
        if str(n) not in options:
            raise ValueError(
                f"{key}: unknown {group} {str(n)!r}; choose from {options} (snell_bench/conf/{group}/, installed "
                f"plugins, or a {group}/{n}.yaml in a config folder of your own: hydra.searchpath=[file://my_conf])"
            )


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


def axis_settings(name: str, spec: Any) -> list[tuple[str, list[str]]]:
    """``(label, overrides)`` of each setting of the grid's axis ``name`` (``grid.axes``).

    ``spec`` is a Hydra override (``"sampler.steps=4,8,12"``: one setting per value, labelled
    ``steps=4``, ...) or a mapping ``label -> [override, ...]`` (labelled ``name=label``).

    Args:
        name: the axis (``grid.axes.<name>``).
        spec: its value, as plain Python (lists, dicts, strings).

    Returns:
        The settings in order.

    Raises:
        ValueError: naming ``grid.axes.<name>``, for a spec of neither form, an override that
            Hydra cannot parse, or no values.
    """
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    where = f"grid.axes.{name}"
    if isinstance(spec, str):
        try:
            ov = OverridesParser.create().parse_override(spec)
        except HydraException as e:  # the parser's and the lexer's errors
            first = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise ValueError(
                f"{where}: {spec!r} is not a Hydra override ({first}); write e.g. sampler.steps=4,8,12"
            ) from None
        values = list(ov.sweep_string_iterator()) if ov.is_sweep_override() else [ov.get_value_element_as_str()]
        if not values:
            raise ValueError(f"{where}: {spec!r} has no values; write e.g. sampler.steps=4,8,12 (non-empty)")
        return [(f"{name}={v}", [f"{ov.get_key_element()}={v}"]) for v in values]
    if isinstance(spec, dict) and spec and all(isinstance(v, list) for v in spec.values()):
        return [(f"{name}={label}", [str(o) for o in ovs]) for label, ovs in spec.items()]
    raise ValueError(
        f"{where}: expected a Hydra sweep override (sampler.steps=4,8) or a mapping label -> [override, ...] "
        f"(non-empty), got {spec!r}"
    )
