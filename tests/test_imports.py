"""The import-cycle check (tools/check_imports.py): it finds a cycle through an import inside a
function, names its modules and a chain with line numbers, passes an acyclic package, and finds no
cycle through snell_bench.scene."""

import importlib.util
import sys
from pathlib import Path

import pytest

_TOOL = Path(__file__).resolve().parents[1] / "tools" / "check_imports.py"


@pytest.fixture(scope="module")
def check_imports():
    spec = importlib.util.spec_from_file_location("check_imports", _TOOL)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while being created
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(spec.name, None)


def _write_package(root: Path, name: str, files: dict[str, str]) -> None:
    (root / name).mkdir()
    for module, text in {"__init__": "", **files}.items():
        (root / name / f"{module}.py").write_text(text)


def test_finds_two_module_cycle(check_imports, tmp_path, monkeypatch, capsys):
    name = "cycle_pkg_two"
    _write_package(
        tmp_path,
        name,
        {
            "a": f"from {name}.b import value\n\nVALUE = value + 1\n",
            "b": f"value = 1\n\n\ndef twice():\n    from {name} import a\n\n    return 2 * a.VALUE\n",
            "c": f"from {name} import a\n",
        },
    )
    monkeypatch.syspath_prepend(str(tmp_path))

    cycles = check_imports.find_cycles(check_imports.build_graph(name))
    assert len(cycles) == 1
    cycle = cycles[0]
    assert cycle.modules == (f"{name}.a", f"{name}.b")
    assert [(i.importer, i.imported, i.line_number, i.line) for i in cycle.chain] == [
        (f"{name}.a", f"{name}.b", 1, f"from {name}.b import value"),
        (f"{name}.b", f"{name}.a", 5, f"from {name} import a"),
    ]

    assert check_imports.main([name]) == 1
    out = capsys.readouterr().out
    assert f"{name}.b -> {name}.a  (l.5: from {name} import a)" in out
    assert f"{name}.c" not in out
    assert f"{name}: 1 import cycle(s) among 4 modules" in out


def test_passes_acyclic_package(check_imports, tmp_path, monkeypatch, capsys):
    name = "cycle_pkg_none"
    _write_package(tmp_path, name, {"a": f"from {name}.b import value\n", "b": "value = 1\n"})
    monkeypatch.syspath_prepend(str(tmp_path))

    assert check_imports.find_cycles(check_imports.build_graph(name)) == []
    assert check_imports.main([name]) == 0
    assert "0 import cycle(s)" in capsys.readouterr().out


def test_scene_is_on_no_cycle(check_imports):
    cycles = check_imports.find_cycles(check_imports.build_graph("snell_bench"))
    on_scene = [c.modules for c in cycles if any(m.startswith("snell_bench.scene") for m in c.modules)]
    assert on_scene == []
