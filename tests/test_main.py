"""The command line's own checks (``snell_bench.__main__``): an override Hydra's grammar refuses is
said before anything is written, with Hydra's message and the argument to type instead."""

import shlex
import sys

import pytest
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException

from snell_bench.__main__ import EXIT_USAGE, cli, override_problem, quoted_override


def hydra_value(arg: str):
    """The value Hydra's own parser reads from one override."""
    return OverridesParser.create().parse_overrides([arg])[0].value()


def typed(fix: str) -> str:
    """What a POSIX shell passes for the hint's text (one argument)."""
    (arg,) = shlex.split(fix)
    return arg


# What Hydra's lexer takes unquoted: ASCII letters, digits, spaces and some punctuation.
@pytest.mark.parametrize("value", ["my run", "a:b", "runs/a", "x@y", "a?b", "50%", "a*b", "a|b", "${oc.env:HOME}"])
def test_values_hydra_takes_unquoted_pass(value):
    assert hydra_value(f"experiment_name={value}") == value  # the reference: Hydra reads it as written
    assert override_problem([f"experiment_name={value}"]) is None


# What it refuses unquoted: non-ASCII letters (accented, other scripts, emoji), ' & # ! ; < and
# the grammar's own = [ ] ( ).
@pytest.mark.parametrize(
    "value", ["café", "naïve", "日本", "Ωmega", "😀", "a'b", "x&y", "a#b", "hi!", "a;b", "a<b", "a=b"]
)
def test_a_value_hydra_refuses_gets_its_quoted_form(value):
    arg = f"experiment_name={value}"
    with pytest.raises(HydraException):
        hydra_value(arg)
    problem = override_problem(["job=report", arg])
    assert problem.startswith(f"Error: cannot parse the override {arg!r}:\n")
    assert "See https://hydra.cc/docs" in problem  # Hydra's own message
    hint = problem.splitlines()[-1]
    assert hint.startswith("Hint: quote the value (and, in a POSIX shell, the whole argument): ")
    fix = hint.split(": ", 2)[2]
    assert fix == quoted_override(arg)
    assert hydra_value(typed(fix)) == value  # typed in a shell, Hydra reads the value as meant


def test_words_the_shell_split_at_a_space_are_joined_and_quoted():
    problem = override_problem(["experiment_name=my", "run", "job=report"])
    assert "missing EQUAL" in problem
    hint = problem.splitlines()[-1]
    assert hint.endswith("""quote both as one argument: 'experiment_name="my run"'""")
    assert hydra_value(typed(hint.rsplit(": ", 1)[1])) == "my run"


def test_a_list_gets_each_element_quoted():
    fix = quoted_override("grid.scenes=[café,kitchen]")
    assert fix == """'grid.scenes=["café","kitchen"]'"""
    assert hydra_value(typed(fix)) == ["café", "kitchen"]


def test_a_key_cannot_be_quoted():
    problem = override_problem(["expérience=1"])
    assert "the key an ASCII name of the config" in problem.splitlines()[-1]


def test_flags_and_shell_completion_are_not_overrides():
    assert override_problem(["-m", "--cfg", "job", "+experiment=smoke", "grid.scenes=[kitchen,living_room]"]) is None
    assert override_problem(["-sc", "install=bash"]) is None
    assert override_problem(["--info", "config"]) is None


@pytest.mark.parametrize(
    "arg, instead",
    [
        ("job=tradeoff", "run +experiment=tradeoff (job=grid)"),
        ("tradeoff.only=[steps]", "write grid.only=..."),
        ("+tradeoff.axes.lam='sampler.lam=0.3,0.7'", "write grid.axes.lam=..."),
        ("tradeoff.variation=2", "write grid.variations=[N]"),
        ("tradeoff.object=sphere:1.5", "write grid.objects=[NAME]"),
    ],
)
def test_the_former_sweeps_keys_name_the_grids(arg, instead):
    """The speed/accuracy sweep is a grid: its former job and keys say what replaced them."""
    problem = override_problem(["+experiment=tradeoff", arg])
    assert problem.startswith(f"Error: {arg!r}: the speed/accuracy sweep is a grid") and problem.endswith(instead)
    assert override_problem(["+experiment=tradeoff", "grid.only=[steps]", "job=grid"]) is None


def test_the_command_exits_2_before_anything_is_written(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["snell_bench", "+experiment=smoke", "experiment_name=café"])
    with pytest.raises(SystemExit) as e:
        cli()
    assert e.value.code == EXIT_USAGE == 2
    err = capsys.readouterr().err
    assert """Hint: quote the value (and, in a POSIX shell, the whole argument): 'experiment_name="café"'""" in err
    assert list(tmp_path.iterdir()) == []  # no runs/, no Hydra folder
