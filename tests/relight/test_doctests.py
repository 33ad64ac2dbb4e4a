"""The examples in the relighting modules' docstrings."""

import doctest
import importlib

import pytest


@pytest.mark.parametrize("name", ["base", "select", "kontext", "shadow"])
def test_doctests(name):
    module = importlib.import_module(f"snell_bench.relight.{name}")
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0
