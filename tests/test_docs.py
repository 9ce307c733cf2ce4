"""The README and the guides in docs/ say only what is true of the code and the tables of record.

- the README fits on a front page (at most 150 lines);
- every relative link and ``#anchor`` resolves (GitHub's heading anchors);
- the README's headline table equals the report's figures (``docs/results/report.json`` and ``docs/results.md``);
- every ``aril <command>``, ``run_graph.py`` and ``python -m <module>`` shown, and every ``key:=`` it is given,
  is a real command and argument; a ``key:=`` shown alone is an argument of some command;
- every ``from aril_ros… import …`` / ``import aril_ros…`` shown resolves.

Nothing here runs the graph: commands are checked against their argument dataclasses in this process.
"""
from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import json
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
GUIDES = sorted((ROOT / "docs").glob("*.md"))
# pages whose links and anchors must resolve: the front page, the guides and the pages they send readers to first
LINKED_PAGES = [README, *GUIDES, ROOT / "benchmarks" / "README.md", ROOT / "results" / "aril_a_tuning.md"]
# pages whose commands must run today. docs/results.md is left out: it is the generated record of the command
# that made it at its revision (its header says which), and changes only when `aril report` runs again.
COMMAND_PAGES = [README, *(g for g in GUIDES if g.name != "results.md")]
README_MAX_LINES = 150

FENCE = re.compile(r"^```.*?^```", re.S | re.M)
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(([^)\s]+)\)")
INLINE_CODE = re.compile(r"`([^`\n]+)`")
KEY = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*):=")
PYTHON = re.compile(r"(^|/)python(\d(\.\d+)?)?$")
"""An interpreter as a shown command names it (python, python3, .venv/bin/python): what ``-m <module>`` follows."""


def rel(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def prose(text: str) -> str:
    """``text`` without its fenced code blocks."""
    return FENCE.sub("", text)


def code_blocks(text: str) -> list[str]:
    return [block.split("\n", 1)[1].rsplit("```", 1)[0] for block in FENCE.findall(text)]


def github_anchor(heading: str, seen: dict) -> str:
    """The anchor GitHub gives a heading: lowercased, punctuation dropped, spaces as hyphens; repeats get -1, -2."""
    slug = re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")
    count = seen.get(slug, 0)
    seen[slug] = count + 1
    return slug if count == 0 else f"{slug}-{count}"


def anchors(page: Path) -> set[str]:
    seen: dict = {}
    return {github_anchor(m.group(1), seen) for m in re.finditer(r"^#{1,6}\s+(.+?)\s*#*\s*$", prose(page.read_text()),
                                                               re.M)}


def broken_links(page: Path) -> list[str]:
    broken = []
    for target in LINK.findall(prose(page.read_text())):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
            continue
        path_part, _, anchor = target.partition("#")
        dest = (page.parent / path_part).resolve() if path_part else page
        if not dest.exists():
            broken.append(f"{rel(page)}: {target} (no such file)")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(f"{rel(page)}: {target} (no heading #{anchor} in {rel(dest)})")
    return broken


def test_readme_fits_a_front_page():
    lines = README.read_text().count("\n")
    assert lines <= README_MAX_LINES, f"README.md has {lines} lines; a front page has at most {README_MAX_LINES}"


def test_github_anchors():
    seen: dict = {}
    assert github_anchor("One command: `aril scorecard`", seen) == "one-command-aril-scorecard"
    assert github_anchor("ARIL's rounds", seen) == "arils-rounds"
    assert github_anchor("Defenses (learners)", seen) == "defenses-learners"
    assert github_anchor("Defenses (learners)", seen) == "defenses-learners-1"


@pytest.mark.parametrize("page", LINKED_PAGES, ids=rel)
def test_links_and_anchors_resolve(page):
    assert broken_links(page) == []


def test_a_broken_anchor_is_found(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# Title\n\n[ok](#title) [bad](#nothing) [gone](missing.md)\n```\n# not a heading\n```\n"
                    "[in code is prose too](#not-a-heading)\n")
    assert [b.split(": ", 1)[1] for b in broken_links(page)] == [
        f"#nothing (no heading #nothing in {page})", "missing.md (no such file)",
        f"#not-a-heading (no heading #not-a-heading in {page})"]


# --- the headline table -------------------------------------------------------------------------------------------

# each row of the README's table: the report's row key (report.json's overall_drop) and its label in docs/results.md
HEADLINE_ROWS = {
    "DAgger under FGSM": ("dagger fgsm", "FGSM (on DAgger)"),
    "DAgger under FGSM^k": ("dagger fgsm_k", "FGSM^k (on DAgger)"),
    "DAgger under ARIL-A": ("dagger aril_a", "ARIL-A (on DAgger)"),
    "DAgger under directed ARIL-A": ("dagger aril_a_directed", "ARIL-A, directed (on DAgger)"),
    "GAIL, worst attack": ("gail worst", "GAIL"),
    "DR, worst attack": ("dr worst", "DR"),
    "DART, worst attack": ("dart worst", "DART"),
    "ARIL, worst attack": ("aril worst", "ARIL"),
}


def markdown_table(text: str, first_header: str) -> list[dict]:
    """The rows (header -> cell) of the table whose first header cell is ``first_header``."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and cells[0] == first_header:
            rows = []
            for row in lines[i + 2:]:
                if not row.startswith("|"):
                    break
                rows.append(dict(zip(cells, (c.strip() for c in row.strip().strip("|").split("|")))))
            return rows
    raise AssertionError(f"no table headed {first_header!r}")


def percent(cell: str) -> float | None:
    """``-53.4%`` (or ``−53.4%``) as -53.4; ``—`` (no figure) as None."""
    return None if cell == "—" else float(cell.replace("−", "-").rstrip("%"))


def results_md_overall() -> dict:
    """docs/results.md's overall columns: {(mode, row label): (ours, paper)}."""
    text = (ROOT / "docs" / "results.md").read_text()
    figures = {}
    for mode, heading in (("sensory", "## Table 1"), ("physical", "## Table 2")):
        table = text[text.index(heading):]
        for row in markdown_table(table, ""):
            figures[mode, row[""]] = (percent(row["overall ours"]), percent(row["overall paper"]))
    return figures


def test_headline_figures_are_the_reports():
    report = json.loads((ROOT / "docs" / "results" / "report.json").read_text())["overall_drop"]
    tables = results_md_overall()
    rows = markdown_table(README.read_text(), "overall drop")
    assert rows, "the README's headline table has no rows"
    for row in rows:
        assert row["overall drop"] in HEADLINE_ROWS, f"README headline row {row['overall drop']!r} is not a report row"
        key, label = HEADLINE_ROWS[row["overall drop"]]
        for mode in ("sensory", "physical"):
            ours, paper = percent(row[f"{mode}, ours"]), percent(row[f"{mode}, paper"])
            assert ours == round(report[mode][key], 1), (row["overall drop"], mode, "ours", ours)
            assert (ours, paper) == tables[mode, label], (row["overall drop"], mode)


# --- commands, arguments, imports ---------------------------------------------------------------------------------

def shown_code(page: Path) -> list[str]:
    """Every line of code a page shows: the lines of its code blocks and its inline code spans."""
    text = page.read_text()
    lines = [line for block in code_blocks(text) for line in block.splitlines()]
    return lines + INLINE_CODE.findall(prose(text))


def words(line: str) -> list[str]:
    try:
        return shlex.split(line, comments=True)
    except ValueError:  # an unbalanced quote in a prose span: split on blanks
        return line.split()


def keys_after(tokens: list[str]) -> list[str]:
    """The ``key:=`` names given to a command: the run of ``key:=value`` words after it (flags skipped)."""
    keys = []
    for token in tokens:
        if token.startswith("--ros-args") or token in ("|", "&&", ";"):
            break
        if KEY.match(token):
            keys.append(KEY.match(token).group(1))
        elif not token.startswith("-"):
            break
    return keys


def fields(config) -> set[str]:
    return {f.name for f in dataclasses.fields(config)}


def module_config_fields(module_name: str) -> set[str]:
    """Every argument of the argument dataclasses a ``python -m`` module defines."""
    module = importlib.import_module(module_name)
    return {name for value in vars(module).values()
            if dataclasses.is_dataclass(value) and isinstance(value, type) and value.__module__ == module_name
            for name in fields(value)}


@pytest.fixture(scope="module")
def known():
    """What a shown command may be: the aril commands (the library's and the installed plugins'), run_graph.py's
    arguments, and the registered benchmarks' arguments."""
    from aril_ros import cli, plugins
    from aril_ros_nodes import run_graph

    commands = {name: fields(cli.command(name).config) for name in [*cli.COMMANDS, *plugins.names("aril_ros.commands")]}
    benchmarks = set().union(*(module_config_fields(plugins.value("aril_ros.benchmarks", name))
                               for name in plugins.names("aril_ros.benchmarks")))
    return {"aril": commands, "run_graph": fields(run_graph.GraphConfig), "benchmarks": benchmarks}


def wrong_commands(line: str, known: dict) -> list[str]:
    """What in one shown line names a command or argument that does not exist."""
    tokens = words(line)
    wrong, checked_keys = [], set()
    for i, token in enumerate(tokens):
        rest = tokens[i + 1:]
        if token == "-m" and not (i and PYTHON.search(tokens[i - 1])):
            continue  # another program's -m (run_tests.py -m "not slow": pytest's markers), not python's
        if token == "aril" or token.endswith("/aril") or (token == "-m" and rest and rest[0] == "aril_ros"):
            rest = rest[1:] if token == "-m" else rest
            if not rest or rest[0].startswith(("-", "<")):
                continue
            name, given = rest[0], keys_after(rest[1:])
            if name not in known["aril"]:
                wrong.append(f"aril {name}: no such command")
                continue
            wrong += [f"aril {name} {k}:= (no such argument)" for k in given if k not in known["aril"][name]]
            checked_keys.update(given)
        elif token.endswith("run_graph.py") or (token == "-m" and rest and rest[0] == "aril_ros_nodes.run_graph"):
            given = keys_after(rest[1:] if token == "-m" else rest)
            wrong += [f"run_graph.py {k}:= (no such argument)" for k in given if k not in known["run_graph"]]
            checked_keys.update(given)
        elif token == "-m" and rest and rest[0] not in ("aril_ros", "aril_ros_nodes.run_graph", "pytest") \
                and "<" not in rest[0]:  # python -m aril_ros.benchmarks.<name>: a placeholder
            module = rest[0]
            if importlib.util.find_spec(module) is None:
                wrong.append(f"python -m {module}: no such module")
                continue
            given = keys_after(rest[1:])
            if given:
                allowed = module_config_fields(module)
                wrong += [f"python -m {module} {k}:= (no such argument)" for k in given if k not in allowed]
            checked_keys.update(given)
    # a key:= shown without its command must still be an argument of some command
    every = set(known["run_graph"]).union(known["benchmarks"], *known["aril"].values())
    for token in tokens:
        match = KEY.match(token)
        if (match and match.group(1) not in checked_keys | every | {"key"}  # key:=value: the syntax itself
                and "--ros-args" not in tokens):
            wrong.append(f"{token}: no command takes {match.group(1)}:=")
    return wrong


@pytest.mark.parametrize("page", COMMAND_PAGES, ids=rel)
def test_shown_commands_and_arguments_exist(page, known):
    assert [w for line in shown_code(page) for w in wrong_commands(line, known)] == []


def test_a_wrong_command_or_argument_is_found(known):
    assert wrong_commands("aril eval env:=Ant-v5 episodes:=3  # fine", known) == []
    assert wrong_commands("aril evaluate env:=Ant-v5", known) == ["aril evaluate: no such command"]
    assert wrong_commands("python run_graph.py mode:=sensory blocks:=64", known) == [
        "run_graph.py blocks:= (no such argument)"]
    assert wrong_commands("warm_start:=true blocks:=64", known) == ["blocks:=64: no command takes blocks:="]
    assert wrong_commands("python -m aril_ros.benchmarks.nothing", known) == [
        "python -m aril_ros.benchmarks.nothing: no such module"]
    assert wrong_commands("python run_tests.py -m 'not slow'", known) == []  # pytest's -m, not python's
    assert wrong_commands(".venv/bin/python -m aril_ros evaluate", known) == ["aril evaluate: no such command"]


IMPORT = re.compile(r"^\s*(?:from\s+(aril_ros[\w.]*)\s+import\s+([\w\s,()]+)|import\s+(aril_ros[\w.]*))", re.M)


def wrong_imports(text: str) -> list[str]:
    wrong = []
    for line in [*code_blocks(text), *INLINE_CODE.findall(prose(text))]:
        for line_text in re.split(r"[;\n]|\"|'", line):
            for match in IMPORT.finditer(line_text):
                module = match.group(1) or match.group(3)
                try:
                    imported = importlib.import_module(module)
                except ImportError:
                    wrong.append(f"import {module}: no such module")
                    continue
                names = [n.strip() for n in (match.group(2) or "").strip("() ").split(",") if n.strip()]
                wrong += [f"from {module} import {n}: no such name" for n in names if not hasattr(imported, n)]
    return wrong


@pytest.mark.parametrize("page", [README, *GUIDES], ids=rel)
def test_shown_imports_resolve(page):
    assert wrong_imports(page.read_text()) == []


def test_a_wrong_import_is_found():
    assert wrong_imports("```python\nfrom aril_ros.policy import resolve_policy, nothing_here\n"
                         "import aril_ros.no_such_room\n```\n") == [
        "from aril_ros.policy import nothing_here: no such name", "import aril_ros.no_such_room: no such module"]


def test_the_block_size_stated_is_the_codes():
    """The guides once said 64-row blocks after the code moved to 16: the figure stated is the one in force."""
    from aril_ros.policy import BLOCK_ROWS

    stated = [int(n) for page in [README, *GUIDES] for n in re.findall(r"blocks of (\d+) rows", page.read_text())]
    assert stated and set(stated) == {BLOCK_ROWS}, (stated, BLOCK_ROWS)
