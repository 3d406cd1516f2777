"""The typing and docstring ratchet of pyproject.toml: one list of modules for mypy and ruff's D rules."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _config() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_mypy_and_the_docstring_rules_cover_the_same_modules() -> None:
    config = _config()
    typed = config["tool"]["mypy"]["files"]
    ignores = config["tool"]["ruff"]["lint"]["per-file-ignores"]
    negated = [glob for glob, rules in ignores.items() if glob.startswith("!{") and rules == ["D"]]
    assert len(negated) == 1, ignores
    documented = re.fullmatch(r"!\{(.*)\}", negated[0]).group(1).split(",")
    assert sorted(documented) == sorted(typed)
    assert typed == sorted(typed) and len(set(typed)) == len(typed)
    assert [f for f in typed if not (ROOT / f).is_file()] == []


def test_the_ci_runs_mypy_right_after_the_import_contracts() -> None:
    for path in ("README.md", ".ci/run"):
        assert "lint-imports && .venv/bin/mypy && " in (ROOT / path).read_text(), path
