"""The documentation cannot drift from the code (issue 18).

* docs/scene.md documents exactly the keys the loader accepts, section by section — read from the page's
  tables and from the loader's own refusal of an unknown key — and every documented default, read as TOML,
  is accepted by the loader and means the same as leaving the key out;
* docs/commands.md has every sub-command of the real parser (the ``controllers`` ones, added through the
  entry point, included) and every one of its options, each with a meaning;
* the generated blocks are what ``python -m flexlink.tools.reference`` writes today;
* the README is a front door (at most 15 KB, the two quick-start commands, links into docs/), no page links
  outside the repository or to a file that is not there, and ``mkdocs build --strict`` passes.
"""

from __future__ import annotations

import argparse
import copy
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from flexlink.cli import build_parser
from flexlink.errors import SceneError
from flexlink.scene.loader import parse_scene
from flexlink.scene.schema import SECTIONS
from flexlink.tools import reference

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
SOURCE = "docs.toml"
QUICK_START = (
    "python3 -m venv .venv && .venv/bin/pip install -q -e . && .venv/bin/flexlink demo",
    "python3 -m venv .venv && .venv/bin/pip install -q -e '.[test]' && .venv/bin/ruff check . && "
    ".venv/bin/lint-imports && .venv/bin/mypy && .venv/bin/pytest -q -n auto --dist loadfile",
)


# ------------------------------------------------------------------------------------------ scene reference


def documented_keys() -> dict[str, dict[str, str]]:
    """section header (as the page writes it) → {key: documented default cell}, from docs/scene.md's tables."""
    text = (DOCS / "scene.md").read_text(encoding="utf-8")
    block = text.split(reference.SCENE_BLOCK[0], 1)[1].split(reference.SCENE_BLOCK[1], 1)[0]
    found: dict[str, dict[str, str]] = {}
    header = None
    for line in block.splitlines():
        if line.startswith("### "):
            header = line[4:].strip().strip("`")
            found[header] = {}
        elif line.startswith("| `") and header is not None:
            cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
            found[header][cells[0].strip("`")] = cells[3]
    return found


def _scenes() -> dict[str, tuple[dict, tuple]]:
    """A valid scene for every section, and where in it that section's table sits."""
    beam = {"name": "robot",
            "joint": [{"name": "hub"}, {"name": "elbow", "drive": "position",
                                        "trajectory": {"segments": [{"until": 1.0, "poly": [0.0, 1.0]}]}}],
            "link": [{"name": "arm", "length": 2.2, "linear_density": 0.349, "EI": 93.72,
                      "shapes": {"kind": "clamped-free", "count": 2}, "payload": {"mass": 0.5}},
                     {"name": "fore", "length": 1.0, "linear_density": 0.3, "EI": 50.0}],
            "tool": {}, "fmu": {}}
    shell = {"name": "box", "joint": [{"name": "hub"}],
             "link": [{"name": "tube", "length": 1.0, "density": 2700.0, "E": 7e10, "poisson": 0.3,
                       "shapes": {"kind": "shell", "section": "box", "width": 0.1, "height": 0.05,
                                  "thickness": 0.002, "mesh": [4, 2, 2]}}]}
    return {"scene": (beam, ()), "joint": (beam, ("joint", 0)), "joint.trajectory": (beam, ("joint", 1, "trajectory")),
            "joint.trajectory.segments": (beam, ("joint", 1, "trajectory", "segments", 0)),
            "link": (beam, ("link", 0)), "link.shapes": (beam, ("link", 0, "shapes")),
            "link.payload": (beam, ("link", 0, "payload")), "shell_link": (shell, ("link", 0)),
            "shell_link.shapes": (shell, ("link", 0, "shapes")), "tool": (beam, ("tool",)), "fmu": (beam, ("fmu",))}


def _table(section: str) -> tuple[dict, dict]:
    doc, path = _scenes()[section]
    doc = copy.deepcopy(doc)
    node = doc
    for p in path:
        node = node[p]
    return doc, node


def accepted_keys(section: str) -> list[str]:
    """What the loader accepts in a section, in its own words: the list its unknown-key message gives."""
    doc, table = _table(section)
    parse_scene(copy.deepcopy(doc), SOURCE)                 # the scene is valid as it stands
    table["no_such_key_in_any_section"] = 1
    with pytest.raises(SceneError) as info:
        parse_scene(doc, SOURCE)
    message = str(info.value)
    assert "unknown key; expected one of: " in message, message
    return message.split("expected one of: ", 1)[1].split(", ")


HEADERS = {s.id: s.header for s in SECTIONS}


@pytest.mark.parametrize("section", list(_scenes()))
def test_scene_page_documents_exactly_the_accepted_keys(section):
    documented = documented_keys()[HEADERS[section]]
    accepted = accepted_keys(section)
    if section == "link":       # a beam link names the shell keys E, poisson (to refuse them with a reason)
        shell_only = set(documented_keys()[HEADERS["shell_link"]]) - set(documented)
        accepted = [k for k in accepted if k not in shell_only]
    assert sorted(documented) == sorted(accepted), f"undocumented: {set(accepted) - set(documented)}; " \
                                                   f"documented but refused: {set(documented) - set(accepted)}"


def test_scene_page_has_every_section():
    assert set(documented_keys()) == set(HEADERS.values())


@pytest.mark.parametrize("section", list(_scenes()))
def test_documented_defaults_are_accepted_and_mean_absent(section):
    """Each default the page gives, pasted into a scene as TOML, is accepted and changes nothing."""
    checked = 0
    for key, cell in documented_keys()[HEADERS[section]].items():
        if not cell.startswith("`"):                       # **required** / (absent): no value to paste
            continue
        value = tomllib.loads(f"v = {cell.strip('`')}")["v"]
        doc, table = _table(section)
        table.pop(key, None)
        absent = repr(parse_scene(copy.deepcopy(doc), SOURCE))
        table[key] = value
        assert repr(parse_scene(doc, SOURCE)) == absent, (section, key, cell)
        checked += 1
    assert checked or section in ("shell_link.shapes", "joint.trajectory")


# ---------------------------------------------------------------------------------------- command reference


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def command_sections() -> dict[str, str]:
    """sub-command → its part of docs/commands.md (from its heading to the next)."""
    text = (DOCS / "commands.md").read_text(encoding="utf-8")
    parts = re.split(r"^### flexlink (\S+)\s*$", text, flags=re.M)
    return dict(zip(parts[1::2], parts[2::2], strict=True))


def test_commands_page_has_every_sub_command_and_no_other():
    commands = set(_subparsers())
    assert {"build", "simulate", "check", "control", "linearize", "sweep", "demo"} <= commands
    assert set(command_sections()) == commands


@pytest.mark.parametrize("command", list(_subparsers()))
def test_commands_page_has_every_option(command):
    section = command_sections()[command]
    rows = {line.split("|")[1].strip(): line for line in section.splitlines() if line.startswith("| `")}
    for action in _subparsers()[command]._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        names = action.option_strings or [action.metavar or action.dest]
        key = ", ".join(f"`{n}`" for n in names)
        assert key in rows, f"flexlink {command}: {key} is not in docs/commands.md"
        meaning = rows[key].rstrip().rstrip("|").rsplit("|", 1)[1].strip()
        assert meaning and not meaning.startswith("("), f"flexlink {command} {key}: no meaning documented"


def test_generated_blocks_are_up_to_date():
    stale = [str(p.relative_to(ROOT)) for p, text in reference.pages().items() if p.read_text(encoding="utf-8")
             != text]
    assert not stale, f"run `python -m flexlink.tools.reference`: {stale} are stale"


def test_commands_page_writes_a_tuple_metavar_as_argparse_does():
    """An option taking two values (``metavar=("X", "Y")``) is documented as argparse's own usage line spells
    it, ``X Y``, not as the Python tuple (a bug mypy found in the table writer)."""
    parser = argparse.ArgumentParser(prog="flexlink")
    sub = parser.add_subparsers().add_parser("point", help="a point")
    sub.add_argument("--at", nargs=2, metavar=("X", "Y"), help="where")
    sub.add_argument("pair", nargs=2, metavar=("A", "B"), help="two names")
    usage = sub.format_usage()
    assert "--at X Y" in usage and "A B" in usage
    block = reference.commands_block(parser)
    assert "| `--at` | `X Y` | where |" in block
    assert "| `A B` |  | two names |" in block


# ----------------------------------------------------------------------------------------- README, links, site


def test_readme_is_a_front_door():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.encode()) <= 15_000
    commands = re.findall(r"```sh\n(.*?)\n```", text, flags=re.S)
    assert tuple(commands) == QUICK_START
    linked = set(re.findall(r"\]\((docs/[^)#]+)", text))
    assert {"docs/scene.md", "docs/commands.md", "docs/getting-started.md", "docs/embedding.md"} <= linked
    assert "perf:begin" not in text and "scaling:begin" not in text
    # issue 15 asks for its table in the README: benchmarks/scaling.py writes it there (and nothing else)
    assert text.count("<!-- robot-scale:begin -->") == 1 and text.count("<!-- robot-scale:end -->") == 1


def test_performance_page_holds_the_generated_blocks():
    text = (DOCS / "performance.md").read_text(encoding="utf-8")
    for marker in ("perf", "scaling"):
        assert text.count(f"<!-- {marker}:begin -->") == 1 and text.count(f"<!-- {marker}:end -->") == 1
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import report
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    assert report.PAGE == DOCS / "performance.md"


def _pages() -> list[Path]:
    return [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]


@pytest.mark.parametrize("page", _pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_links_stay_in_the_repository_and_resolve(page):
    text = re.sub(r"```.*?```", "", page.read_text(encoding="utf-8"), flags=re.S)
    assert not re.search(r"https?://|file://", text), f"{page}: a link out of the repository"
    home = ROOT if page.name == "README.md" else DOCS
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        path = target.split("#", 1)[0]
        if not path:
            continue
        resolved = (page.parent / path).resolve()
        assert resolved.is_relative_to(home) and resolved.exists(), f"{page.name}: broken link {target}"


@pytest.mark.skipif(shutil.which("mkdocs", path=str(Path(sys.executable).parent)) is None,
                    reason="mkdocs not installed (pip install -e '.[docs]')")
def test_mkdocs_strict_build(tmp_path):
    mkdocs = shutil.which("mkdocs", path=str(Path(sys.executable).parent))
    result = subprocess.run([mkdocs, "build", "--strict", "--site-dir", str(tmp_path / "site")], cwd=ROOT,
                            capture_output=True, text=True, timeout=300, env={"NO_MKDOCS_2_WARNING": "1",
                                                                              "PATH": "/usr/bin:/bin"})
    assert result.returncode == 0, result.stderr[-3000:]
    assert (tmp_path / "site" / "scene" / "index.html").exists()
