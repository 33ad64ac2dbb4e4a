"""The ``--help`` page of ``snell-bench`` (``python -m snell_bench``), listed from the package itself.

``conf/hydra/help/snell_bench.yaml`` is Hydra's help template; its lists come from the
``snell_help`` resolver (``${snell_help:jobs}``, ``${snell_help:experiments}``,
``${snell_help:groups}``), so a new job, experiment or config option shows up without editing it:

- jobs: every :class:`~snell_bench.config.choices.Job`, with its line from :data:`JOB_LINES`;
- experiments: every option of the ``experiment`` group, with the first sentence of its file's
  leading comment;
- config groups: every group and its options, without the schema nodes (``base_*``) the structured
  config registers, and with Hydra's ``hydra/launcher`` (for ``-m``).

Convention:
    Each list is plain text, one entry per line (a long experiment description wraps under its
    name), indented by two spaces, with ``$`` doubled: Hydra fills ``$FLAGS_HELP`` and the like
    into the template with :class:`string.Template` after OmegaConf resolves it.
"""

from __future__ import annotations

import re
import textwrap
from importlib.resources import files

from omegaconf import OmegaConf

from snell_bench.config.choices import Job
from snell_bench.config.compose import CONFIG_MODULE, config_context, group_options

__all__ = ["JOB_LINES", "register_help", "help_section", "jobs_text", "experiments_text", "groups_text"]

#: What each job does, one line each (``job=NAME``).
JOB_LINES = {
    Job.preview: "the refraction preview of one scene and object: what Snell's law alone says the glass must show",
    Job.generate: "one generated image: one scene, one object, one method",
    Job.grid: "an experiment grid: every (scene, variation, object, method) cell, then its report",
    Job.report: "rebuild the report of an experiment's finished cells (reports/<experiment>/)",
    Job.plan: "what a grid will do on this machine (cells, models, time, memory) before doing it; writes nothing",
    Job.status: "where a grid stands across all the jobs working on it (done, running, failed, left); writes nothing",
    Job.export: "the benchmark kit of an experiment: every group's inputs and truth, a manifest and a dataset card",
    Job.relight: "the relighting methods against a path-traced truth on procedural scenes (+experiment=relighting)",
}

#: Width of the page's lines (descriptions wrap under their name).
WIDTH = 100

#: Config groups listed apart (experiments) or not chosen on the command line (Hydra's own, except
#: the launchers that ``-m`` uses; ``scene_source``, which a model's config selects).
_SKIP = ("experiment", "hydra", "scene_source")
_LAUNCHER = "hydra/launcher"


def _entries(rows: list[tuple[str, str]]) -> str:
    """``name  text`` rows, the names padded to one column and long texts wrapped under them."""
    width = max((len(name) for name, _ in rows), default=0)
    lines = []
    for name, text in rows:
        head = f"  {name.ljust(width)}  "
        lines.append(
            textwrap.fill(text, WIDTH, initial_indent=head, subsequent_indent=" " * len(head)) or head.rstrip()
        )
    return "\n".join(lines)


def jobs_text() -> str:
    """The jobs, one line each.

    Returns:
        ``  name  what it does`` lines in :class:`~snell_bench.config.choices.Job` order.

    Raises:
        KeyError: a job without a line in :data:`JOB_LINES`.
    """
    return _entries([(job.value, JOB_LINES[job]) for job in Job])


def first_sentence(yaml_text: str) -> str:
    """The first sentence of a config file's leading comment (``# @package`` lines skipped).

    Args:
        yaml_text: the file's text.

    Returns:
        The sentence, up to and including its full stop (the whole comment when it has none), or
        ``""`` without a leading comment.

    Examples:
        >>> first_sentence("# @package _global_\\n# A fast look: half resolution. More.\\njob: grid\\n")
        'A fast look: half resolution.'
    """
    lines = []
    for line in yaml_text.splitlines():
        if not line.startswith("#"):
            break
        if not line.lstrip("# ").startswith("@package"):
            lines.append(line.lstrip("#").strip())
    text = " ".join(x for x in lines if x)
    match = re.match(r"(.+?\.)(?:\s|$)", text)
    return match.group(1) if match else text


def experiments_text() -> str:
    """The experiments (``+experiment=NAME``), each with the first sentence of its file's comment.

    Returns:
        ``  name  description`` lines, sorted by name; an experiment found on another search path
        than the package's is listed without a description.
    """
    folder = files(CONFIG_MODULE).joinpath("experiment")
    rows = []
    for name in group_options("experiment"):
        file = folder.joinpath(f"{name}.yaml")
        rows.append((name, first_sentence(file.read_text(encoding="utf-8")) if file.is_file() else ""))
    return _entries(rows)


def _groups() -> list[str]:
    """Every config group but Hydra's own and ``experiment``, sorted, then ``hydra/launcher``."""
    from hydra.core.global_hydra import GlobalHydra

    with config_context():
        names = GlobalHydra.instance().config_loader().list_groups("")
    return [*sorted(n for n in names if n not in _SKIP), _LAUNCHER]


def _chosen(group: str) -> str | None:
    """The option the running application composed for ``group`` (``None`` outside one)."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return None
    return OmegaConf.select(HydraConfig.get(), "runtime.choices", default={}).get(group)


def groups_text() -> str:
    """The config groups and their options, without the schema nodes (``base_*``).

    Returns:
        ``  group  option, option, ...`` lines; inside a running application the option composed
        now is marked with ``*``.
    """
    rows = []
    for group in _groups():
        chosen = _chosen(group)
        rows.append((group, ", ".join(f"{o}*" if o == chosen else o for o in group_options(group))))
    return _entries(rows)


_SECTIONS = {"jobs": jobs_text, "experiments": experiments_text, "groups": groups_text}


def help_section(name: str) -> str:
    """The ``snell_help`` resolver: one list of the help page, ``$`` doubled for Hydra's template.

    Args:
        name: ``jobs``, ``experiments`` or ``groups``.

    Returns:
        The list as text.

    Raises:
        ValueError: an unknown name (the message lists the known ones).
    """
    if name not in _SECTIONS:
        raise ValueError(f"${{snell_help:{name}}} is unknown; use one of {sorted(_SECTIONS)}")
    return _SECTIONS[name]().replace("$", "$$")


def register_help() -> None:
    """Register the ``snell_help`` resolver with OmegaConf (idempotent)."""
    if not OmegaConf.has_resolver("snell_help"):
        OmegaConf.register_new_resolver("snell_help", help_section)
