"""tools/check_size.py: the module and function limits, and the exceptions that may only shrink."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parents[1] / "tools" / "check_size.py"


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("check_size", TOOL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def package(tmp_path):
    root = tmp_path / "pkg"
    root.mkdir()
    body = "\n".join(f"        x{i} = {i}" for i in range(5))
    (root / "a.py").write_text(
        f"def short():\n    return 1\n\n\nclass C:\n    def long(self):\n{body}\n\n        def inner():\n            pass\n"
    )
    (root / "b.py").write_text("\n" * 12)
    return root


def test_sizes_count_physical_lines_and_qualified_names(tool, package):
    assert tool.module_sizes(package) == {"pkg/a.py": 14, "pkg/b.py": 12}
    assert tool.function_sizes(package) == {"pkg/a.py::short": 2, "pkg/a.py::C.long": 9, "pkg/a.py::C.long.inner": 2}


def test_limits_and_exceptions(tool, package, tmp_path, capsys):
    exceptions = tmp_path / "exceptions.txt"
    args = [str(package), "--exceptions", str(exceptions), "--max-file", "14", "--max-function", "5"]
    assert tool.main(args) == 1  # b.py (12 lines) is within 14; C.long (9) is over, and not excepted
    err = capsys.readouterr().err
    assert "pkg/b.py" not in err and "pkg/a.py::C.long: function of 9 lines (limit 5)" in err
    assert tool.main([*args, "--record"]) == 0
    assert tool.read_exceptions(exceptions) == {"pkg/a.py::C.long": 9}
    (package / "b.py").write_text("\n" * 15)  # a module over the limit, not excepted
    assert tool.main(args) == 1 and "pkg/b.py: module of 15 lines (limit 14)" in capsys.readouterr().err
    (package / "b.py").unlink()
    source = (package / "a.py").read_text()
    (package / "a.py").write_text(source.replace("x0 = 0", "x0 = 0\n        y = 1"))  # grew past its record
    assert tool.main(args) == 1 and "grew to 10 lines (recorded 9" in capsys.readouterr().err
    (package / "a.py").write_text(source.replace("        x0 = 0\n", ""))  # 8 lines: still over, shrunk: fine
    assert tool.main(args) == 0
    (package / "a.py").write_text("def short():\n    return 1\n")  # within the limit: the exception must go
    assert tool.main(args) == 1 and "no such function: delete its exception" in capsys.readouterr().err
