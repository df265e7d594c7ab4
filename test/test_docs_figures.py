"""Every figure of the README and docs/ comes with the command that makes it, and that command makes it.

The command is the first code span of the italic caption right below the image. Each is run here as written,
with its output in a temporary directory and, where the figure's work is large, fewer trajectories (options
the command has); the figure it writes must be the one shown: a PNG of the same size in pixels, with the same
titles and axis labels (numbers aside, which the tiny run changes: "surviving 3 strides").

Truth used: the image files of docs/ (their size) and what the figures show, as read off them (the texts
below); the commands' figures are read back from matplotlib as they are saved.
"""

from __future__ import annotations

import re
import shlex
import struct
from collections.abc import Iterator
from pathlib import Path

import pytest
from matplotlib.figure import Figure
from test_docs import PAGES, REPO_ROOT, relative

from tdslip_ros.commands import cli

IMAGE = re.compile(r"!\[[^\]]*\]\(([^)\s]+\.png)\)")
CAPTION = re.compile(r"^\*`(tdslip [^`]+)`")

SHOWN = {
    "docs/rough_terrain.png": [
        "suptitle: ",
        "title: TD-SLIP over random blocks: centre-of-mass paths",
        "xlabel: x [m]",
        "ylabel: y [m]",
        "title: ",
        "xlabel: stride",
        "ylabel: apex energy above the ground, Ebar",
    ],
    "docs/robustness.png": [
        "suptitle: survival",
        "title: terrain",
        "xlabel: block height sigma [m]",
        "ylabel: fraction surviving 50 strides",
        "title: noise",
        "xlabel: sensor noise s (height s r0, speed s sqrt(g r0))",
        "ylabel: fraction surviving 50 strides",
        "title: mismatch",
        "xlabel: controller's model: factor on the plant's value",
        "ylabel: fraction surviving 50 strides",
        "title: step",
        "xlabel: step down [m]",
        "ylabel: fraction surviving 50 strides",
    ],
    **{
        image: [
            "suptitle: ",
            "title: the viable pairs",
            "xlabel: touchdown angle [deg]",
            "ylabel: height fraction of the energy",
        ]
        for image in (
            "docs/viability/kernel.png",
            "docs/viability/e3/kernel.png",
            "docs/viability/e6/kernel.png",
        )
    },
    "docs/viability/torque/measure.png": [
        "suptitle: ",
        "title: fraction of viable actions",
        "xlabel: apex speed [m/s]",
        "ylabel: apex height y [m]",
        "title: ",
        "xlabel: ",
        "ylabel: fraction of viable actions",
    ],
}
"""The titles and axis labels each figure of docs/ shows, read off the image, axes by axes."""
TINY = {
    "robustness": ["--samples", "1", "--strides", "3"],
    "viability": ["--fractions", "0.1", "0.995", "12", "--angles-deg", "-10", "70", "9"],
    "viability apex": [
        "--heights",
        "0.9",
        "1.6",
        "3",
        "--speeds",
        "1",
        "6",
        "3",
        "--angles-deg",
        "5",
        "45",
        "3",
    ],
}
"""Options that make a command's work tiny (the figure's kind stays), by command, or by command and space."""


def figures() -> Iterator[tuple[str, str, str]]:
    """(page, image, command) for every image of the README and docs/: the image's path from the repository
    root, and the caption's command ("" where the caption gives none)."""
    for page in PAGES:
        lines = page.read_text().splitlines()
        for number, line in enumerate(lines):
            for image in IMAGE.findall(line):
                following = next((text for text in lines[number + 1 :] if text.strip()), "")
                caption = CAPTION.match(following)
                path = relative((page.parent / image).resolve())
                yield relative(page), path, caption.group(1) if caption else ""


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", path
    width, height = struct.unpack(">II", data[16:24])
    return width, height


def shown(figure: Figure) -> list[str]:
    """The suptitle, then per axes its title and labels, as SHOWN lists them."""
    texts = [f"suptitle: {figure.get_suptitle()}"]
    for axes in figure.axes:
        if axes.get_visible():
            texts += [
                f"title: {axes.get_title()}",
                f"xlabel: {axes.get_xlabel()}",
                f"ylabel: {axes.get_ylabel()}",
            ]
    return texts


def without_numbers(texts: list[str]) -> list[str]:
    return [re.sub(r"\d+", "N", text) for text in texts]


def test_every_figure_has_its_command_in_its_caption() -> None:
    found = list(figures())
    assert {image for _, image, _ in found} == set(SHOWN)  # a new figure needs its entry here
    for page, image, command in found:
        assert command, f"{page}: {image} has no caption *`tdslip ...`* naming the command that draws it"
        assert (REPO_ROOT / image).exists(), (page, image)


def test_the_check_reads_a_caption_and_refuses_a_missing_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    page = tmp_path / "page.md"
    page.write_text("![a](a.png)\n\n*`tdslip terrain --seed 2`: blocks.*\n\n![b](b.png)\nThe text.\n")
    monkeypatch.setattr(f"{__name__}.PAGES", [page])
    monkeypatch.setattr(f"{__name__}.relative", lambda path: path.name)
    assert list(figures()) == [("page.md", "a.png", "tdslip terrain --seed 2"), ("page.md", "b.png", "")]


def commands() -> dict[str, str]:
    """Each figure's command (one per figure: the pages that show it agree)."""
    found: dict[str, set[str]] = {}
    for _, image, command in figures():
        found.setdefault(image, set()).add(command)
    assert all(len(each) == 1 for each in found.values()), found
    return {image: each.pop() for image, each in found.items()}


@pytest.mark.parametrize("image", sorted(SHOWN))
def test_the_command_of_a_figure_draws_it(
    image: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    request: pytest.FixtureRequest,
) -> None:
    words = shlex.split(commands()[image])
    name, rest = words[1], words[2:]
    if "--out" in rest:  # the output goes here, not into the source tree
        del rest[rest.index("--out") : rest.index("--out") + 2]
    target = tmp_path / Path(image).name
    out = target if name == "terrain" else tmp_path  # terrain's --out is the PNG, a study's its directory
    rest += ["--out", str(out), *TINY.get(" ".join(words[1:3]), TINY.get(name, []))]
    if name in ("robustness", "viability"):
        rest += ["--scheduler", request.getfixturevalue("dask_scheduler")]
    saved: dict[Path, list[str]] = {}
    savefig = Figure.savefig

    def recorded(figure: Figure, path: Path, *args: object, **kwargs: object) -> None:
        saved[Path(path)] = shown(figure)
        savefig(figure, path, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", recorded)
    assert cli.main([name, *rest]) == 0
    assert png_size(target) == png_size(REPO_ROOT / image)
    assert without_numbers(saved[target]) == without_numbers(SHOWN[image])
    if name == "terrain":  # the headline: both policies hop every stride over the blocks
        assert capsys.readouterr().out.count("all strides;") == 2
