"""``snell-bench`` and ``python -m snell_bench``: the Hydra entry point (:func:`cli`). Jobs live in
:mod:`snell_bench.experiment`; ``--help`` lists them (:mod:`snell_bench.config.help`).

Exit status:
    - ``0``: done; also a sweep whose cells failed with ``grid.allow_failures=true``. Skipped cells (a method that cannot
      run here) are never failures.
    - ``1``: an error stopped the run, said in one line (``Error: ...``, no traceback) where it is a
      setting: a config value or folder refused before any work
      (:class:`~snell_bench.config.preflight.Preflight`), a photo or depth file refused before any
      work (its size, values or camera: :class:`~snell_bench.config.ConfigError`), a job that
      cannot do what it was asked (``job=report`` without cells, or a report the system refuses to
      write: :class:`~snell_bench.experiment.JobError`), finished cells of other settings; and any
      other exception, with its traceback (a bug). A grid whose report cannot be written logs that
      as one ERROR line and keeps the status of its cells.
    - ``2``: the command line cannot be parsed (Hydra's override grammar, :func:`override_problem`,
      which says how to quote the argument; or an unknown flag), before anything is written.
    - ``3``: the sweep ran and wrote its report, but cells failed
      (:data:`~snell_bench.experiment.cells.CELLS_FAILED_EXIT`; their reasons are in the summary,
      the records and the report).

    A multirun (``-m``) runs every job whatever the others do (Hydra's basic, joblib and submitit
    launchers), then exits with the status of the first job, in the sweep's order, that did not
    succeed: a job whose cells failed raises :class:`~snell_bench.experiment.CellsFailed`, which
    Hydra reports after the last job.
"""

from __future__ import annotations

import shlex
import sys

import hydra
from omegaconf import DictConfig

from snell_bench.config import register_configs
from snell_bench.config.compose import searchpath_overrides
from snell_bench.config.help import register_help

register_configs()
register_help()
CONFIG_DIR = "conf"

#: Exit statuses (module docs); the one of failed cells is ``experiment.cells.CELLS_FAILED_EXIT``.
EXIT_ERROR = 1
EXIT_USAGE = 2

#: The exit status a single run's job asks for, read by :func:`cli` once Hydra returns.
_status: list[int] = []


def _parses(override: str) -> bool:
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    try:
        OverridesParser.create().parse_overrides([override])
    except (HydraException, ValueError):
        return False
    return True


def _hydra_quoted(value: str) -> str:
    """``value`` as a quoted string of Hydra's override grammar (which takes any character there)."""
    if '"' not in value:
        return f'"{value}"'
    if "'" not in value:
        return f"'{value}'"
    return '"' + value.replace('"', '\\"') + '"'


def quoted_override(arg: str) -> str | None:
    """``arg`` (``key=value``) with its value quoted for Hydra and the whole quoted for a POSIX shell,
    where that form parses; else ``None``.

    A list value (``[a,b]``) gets each element quoted instead.

    Args:
        arg: one override as the shell passed it.

    Returns:
        The argument to type, e.g. ``'experiment_name="café"'``.

    Examples:
        >>> quoted_override("experiment_name=café")
        '\\'experiment_name="café"\\''
        >>> quoted_override("grid.scenes=[café,kitchen]")
        '\\'grid.scenes=["café","kitchen"]\\''
    """
    key, sep, value = arg.partition("=")
    if not sep:
        return None
    v = value.strip()
    if v.startswith("[") and v.endswith("]"):
        items = [x.strip() for x in v[1:-1].split(",")]
        quoted = "[" + ",".join(x if x[:1] in "\"'" else _hydra_quoted(x) for x in items) + "]"
    else:
        quoted = _hydra_quoted(value)
    candidate = f"{key}={quoted}"
    return shlex.quote(candidate) if _parses(candidate) else None


#: Hydra's flags that take the next argument as their value (``--info`` takes one of its choices).
_VALUE_FLAGS = frozenset(
    {"-c", "--cfg", "-p", "--package", "-cp", "--config-path", "-cn", "--config-name", "-cd", "--config-dir"}
    | {"--experimental-rerun", "-i", "--info"}
)


def overrides_of(argv: list[str]) -> list[str]:
    """The overrides of a Hydra command line: the arguments that are neither a flag nor a flag's value.

    Examples:
        >>> overrides_of(["-m", "--cfg", "job", "a=1", "-cn", "other", "b=[x,y]", "--info", "config"])
        ['a=1', 'b=[x,y]']
    """
    out = []
    for i, arg in enumerate(argv):
        previous = argv[i - 1] if i > 0 else ""
        if arg.startswith("-") or (previous in _VALUE_FLAGS and (previous not in ("-i", "--info") or "=" not in arg)):
            continue
        out.append(arg)
    return out


def override_problem(argv: list[str]) -> str | None:
    """What is wrong with the first override of ``argv`` that Hydra's override grammar refuses,
    with how to type it, or ``None`` when every override parses.

    Hydra's own parser (:class:`~hydra.core.override_parser.overrides_parser.OverridesParser`) reads
    each override alone (:func:`overrides_of`), as Hydra will; Hydra's unquoted values take ASCII
    letters, digits, spaces and ``_ - + . / : @ ? % * \\ | $``; accented and other non-ASCII letters,
    ``' & # ! ; <`` and the grammar's ``= , ( ) [ ] { }`` need a quoted value
    (``experiment_name="café"``, typed inside single quotes in a POSIX shell).

    Args:
        argv: the command line after the program name.

    Returns:
        Hydra's message, then one line: the quoted form of that argument; or, for a word without
        ``=`` after a ``key=value`` (the shell split a value at a space), both joined and quoted.
        ``None`` also for shell completion (``-sc``), whose arguments are not overrides.
    """
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    if "-sc" in argv or "--shell-completion" in argv:
        return None
    overrides = overrides_of(argv)
    parser = OverridesParser.create()
    for i, arg in enumerate(overrides):
        try:
            parser.parse_overrides([arg])
        except (HydraException, ValueError) as e:
            return f"Error: cannot parse the override {arg!r}:\n{str(e).strip()}\nHint: {_hint(arg, overrides[:i])}"
        moved = _moved(arg)
        if moved:
            return f"Error: {arg!r}: {moved}"
    return None


#: The keys of the speed/accuracy sweep's former node (``tradeoff``) that the grid names otherwise.
_TRADEOFF_KEYS = {"variation": "grid.variations=[N]", "object": "grid.objects=[NAME]", "method": "grid.methods=[NAME]"}


def _moved(arg: str) -> str | None:
    """What replaced an override of the former ``job=tradeoff`` and its ``tradeoff`` node, or ``None``.

    Examples:
        >>> _moved("tradeoff.only=[steps]")
        'the speed/accuracy sweep is a grid (+experiment=tradeoff): write grid.only=...'
        >>> _moved("sampler.steps=8") is None
        True
    """
    key, _, _ = arg.lstrip("+~").partition("=")
    if key == "job" and arg.partition("=")[2].strip() == "tradeoff":
        return "the speed/accuracy sweep is a grid: run +experiment=tradeoff (job=grid)"
    if key.startswith("tradeoff."):
        name = key.split(".", 2)[1]
        instead = _TRADEOFF_KEYS.get(name, f"grid.{key.split('.', 1)[1]}=...")
        return f"the speed/accuracy sweep is a grid (+experiment=tradeoff): write {instead}"
    return None


def _hint(arg: str, before: list[str]) -> str:
    previous = before[-1] if before else None
    if "=" not in arg and previous is not None and "=" in previous:
        fix = quoted_override(f"{previous} {arg}")
        if fix:
            return (
                f"{arg!r} is not key=value: if it belongs to the value of {previous!r} (the shell split it "
                f"at a space), quote both as one argument: {fix}"
            )
        return f"{arg!r} is not key=value (write key=value)"
    fix = quoted_override(arg)
    if fix:
        return f"quote the value (and, in a POSIX shell, the whole argument): {fix}"
    return (
        "write it as key=value, the key an ASCII name of the config (python -m snell_bench --help "
        'lists them) and the value quoted where it holds other characters: key="café"'
    )


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="config")
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    from snell_bench.config import ConfigError
    from snell_bench.experiment import CellsFailed, JobError, run_job
    from snell_bench.experiment.cells import SettingsChanged

    hc = HydraConfig.get()
    # a sweep composes its cells from them, with the user's own config folders (hydra.searchpath)
    cfg.overrides = list(hc.overrides.task) + searchpath_overrides(hc.overrides.hydra)
    multirun = hc.mode == RunMode.MULTIRUN
    try:
        status = run_job(cfg)
    except (JobError, ConfigError, SettingsChanged) as e:  # said in full by the message: no traceback
        if multirun:  # Hydra reports it once every job has run
            raise JobError(str(e)) from None
        print(f"Error: {e}", file=sys.stderr)
        _status.append(EXIT_ERROR)
        return
    if status:
        message = f"cells of experiment_name={cfg.experiment_name} failed (the summary above lists them)"
        if multirun:
            raise CellsFailed(message)
        print(f"Error: {message}: exit status {status}", file=sys.stderr)
        _status.append(status)


def _cells_failed_exit() -> int:
    from snell_bench.experiment.cells import CELLS_FAILED_EXIT

    return CELLS_FAILED_EXIT


def cli() -> None:
    """The ``snell-bench`` command (``python -m snell_bench``): Hydra's command line, its overrides
    checked first (:func:`override_problem`: exit status 2, nothing written), and the exit status of the module
    docs. A command of its own is what Hydra's shell completion needs
    (``eval "$(snell-bench -sc install=bash)"``)."""
    from snell_bench.experiment import CellsFailed

    argv = sys.argv[1:]
    problem = override_problem(argv)
    if problem is not None:
        print(problem, file=sys.stderr)
        sys.exit(EXIT_USAGE)
    _status.clear()
    try:
        main()
    except SystemExit as e:  # Hydra exits 1 for a job's exception; 3 when it was a job's failed cells
        if e.code == EXIT_ERROR and isinstance(e.__context__, CellsFailed):
            raise SystemExit(_cells_failed_exit()) from None
        raise
    except CellsFailed as e:  # HYDRA_FULL_ERROR=1: Hydra raises it instead
        print(f"Error: {e}", file=sys.stderr)
        sys.exit(_cells_failed_exit())
    if any(_status):
        sys.exit(max(_status))


if __name__ == "__main__":
    cli()
