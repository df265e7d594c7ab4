"""The README and docs/ as a newcomer reads them: links that resolve, `tdslip` options and node parameters
that exist, one colcon command, short tables, a short README.

No node starts here: the options come from each subcommand's ``--help``, the parameters from config/*.yaml.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import re
from pathlib import Path

import pytest
import yaml

from tdslip_ros.commands.cli import SUBCOMMANDS

REPO_ROOT = Path(__file__).resolve().parents[1]
PAGES = [REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").glob("*.md"))]
NODES = ("plant_node", "controller_node", "recorder_node")
ROS_PARAMETERS = {"use_sim_time"}
"""Parameters every ROS node has, beside the ones of its config file."""
README_MAX_LINES = 150
TABLE_CELL_MAX = 150
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
CODE_SPAN = re.compile(r"`([^`]+)`")
TDSLIP = re.compile(r"(?:\btdslip|\./run\.sh demo)(?: (\w+))?")
OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")
NODE_PARAMETER = re.compile(r"-p ([a-z_]+):=")


def relative(page: Path) -> str:
    return str(page.relative_to(REPO_ROOT))


def snippets(page: Path) -> list[str]:
    """The page's code: every line of its fenced blocks and every inline code span (which may wrap), comments
    cut off."""
    found: list[str] = []
    prose: list[str] = []
    fenced = False
    for line in page.read_text().splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
        elif fenced:
            found.append(line)
        else:
            prose.append(line)
    found += [span.replace("\n", " ") for span in CODE_SPAN.findall("\n".join(prose))]
    return [snippet.split(" # ")[0] for snippet in found]


def slug(heading: str) -> str:
    """GitHub's anchor of a heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower().replace("`", ""))
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    return {slug(line.lstrip("#")) for line in page.read_text().splitlines() if line.startswith("#")}


@pytest.mark.parametrize("page", PAGES, ids=relative)
def test_links_resolve(page: Path) -> None:
    """Every relative link names a file of the repository, and a #heading that page has."""
    for target in LINK.findall(page.read_text()):
        if re.match(r"[a-z]+:", target):
            continue
        path, _, anchor = target.partition("#")
        linked = (page.parent / path).resolve() if path else page
        assert linked.exists(), f"{relative(page)}: {target} does not exist"
        if anchor and linked.suffix == ".md":
            assert anchor in anchors(linked), (
                f"{relative(page)}: {target} names no heading of {relative(linked)}"
            )


@pytest.fixture(scope="module")
def help_texts() -> dict[str, str]:
    """``tdslip SUB --help`` of every subcommand."""
    texts = {}
    for name in SUBCOMMANDS:
        out = io.StringIO()
        with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
            importlib.import_module(f"tdslip_ros.commands.{name}").main(["--help"])
        texts[name] = out.getvalue()
    return texts


@pytest.mark.parametrize("page", PAGES, ids=relative)
def test_cited_tdslip_options_exist(page: Path, help_texts: dict[str, str]) -> None:
    """Every ``tdslip SUB --option`` (and ``./run.sh demo --option``, which goes to ``tdslip run``) the page
    cites is an option of that subcommand."""
    for snippet in snippets(page):
        matches = list(TDSLIP.finditer(snippet))
        ends = [match.start() for match in matches[1:]] + [len(snippet)]
        for match, end in zip(matches, ends[: len(matches)], strict=True):
            name = "run" if match.group(0).startswith("./run.sh") else match.group(1)
            if name not in SUBCOMMANDS:
                continue  # tdslip --help, tdslip_ros, or the command's name in prose
            rest = snippet[match.end() : end]
            for option in OPTION.findall(rest):
                assert re.search(rf"(?<![\w-]){option}\b", help_texts[name]), (
                    f"{relative(page)}: tdslip {name} has no option {option} ({snippet})"
                )


@pytest.mark.parametrize("page", PAGES, ids=relative)
def test_cited_node_parameters_exist(page: Path) -> None:
    """Every ``-p name:=value`` given to a node executable is a parameter of that node (config/*.yaml)."""
    parameters = {}
    for node in NODES:
        config = yaml.safe_load((REPO_ROOT / "config" / f"{node.removesuffix('_node')}.yaml").read_text())
        parameters[node] = set(config["/**"]["ros__parameters"]) | ROS_PARAMETERS
    for snippet in snippets(page):
        named = [node for node in NODES if re.search(rf"\b{node}\b", snippet)]
        if len(named) != 1:
            continue
        for name in NODE_PARAMETER.findall(snippet):
            assert name in parameters[named[0]], f"{relative(page)}: {named[0]} has no parameter {name}"


def test_the_colcon_page_builds_as_the_readme_does() -> None:
    """docs/colcon.md repeats the README's ``colcon build`` line (test_package_layout.py builds that one)."""

    def colcon_lines(page: Path) -> list[str]:
        return [
            line.strip() for line in page.read_text().splitlines() if line.strip().startswith("colcon build")
        ]

    readme = colcon_lines(REPO_ROOT / "README.md")
    assert len(readme) == 1
    assert colcon_lines(REPO_ROOT / "docs" / "colcon.md") == readme


def test_the_readme_is_short() -> None:
    assert len((REPO_ROOT / "README.md").read_text().splitlines()) < README_MAX_LINES


@pytest.mark.parametrize("page", PAGES, ids=relative)
def test_table_cells_are_short(page: Path) -> None:
    for line in page.read_text().splitlines():
        if line.startswith("|"):
            cells = re.split(r"(?<!\\)\|", line.strip().strip("|"))
            longest = max(cells, key=len).strip()
            assert len(longest) <= TABLE_CELL_MAX, f"{relative(page)}: a cell of {len(longest)} characters"


def test_the_architecture_page_draws_every_module_of_the_model(repo_root: Path) -> None:
    """docs/ARCHITECTURE.md's tree of model/ names every module there is, in its sub-package's branch."""
    page = (repo_root / "docs" / "ARCHITECTURE.md").read_text()
    tree = page[page.index("```\nmodel/") : page.index("```", page.index("```\nmodel/") + 3)]
    branches = {
        line.split("/")[0].split()[-1]: index for index, line in enumerate(tree.splitlines()) if "/ " in line
    }
    model = repo_root / "tdslip_ros" / "model"
    lines = tree.splitlines()
    for path in sorted(model.rglob("*.py")):
        if path.name == "__init__.py":
            continue
        package = path.parent.name if path.parent != model else None
        name = re.compile(rf"(?<![\w/]){re.escape(path.name)}(?!\w)")
        named = [index for index, line in enumerate(lines) if name.search(line)]
        assert named, f"docs/ARCHITECTURE.md's tree of model/ leaves out {path.relative_to(model)}"
        if package is not None:
            start = branches[package]
            ends = [index for index in branches.values() if index > start]
            assert start < named[0] < min(ends, default=len(lines)), (
                f"{path.relative_to(model)} is drawn elsewhere"
            )
