"""The README is for a newcomer: short, every command line in it (and in docs/commands.md) one the
parser takes, every link live."""

import argparse
import re
import shlex
from pathlib import Path

import pytest

from faceanim.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))


def subparsers(parser: argparse.ArgumentParser) -> dict:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices
    return {}


def command_lines(text: str) -> list[str]:
    """The `faceanim ...` lines of the indented code blocks, comments cut off."""
    out = []
    for line in text.splitlines():
        if line.startswith("    faceanim ") or line.startswith("    .venv/bin/faceanim "):
            out.append(line.split("  #")[0].strip().removeprefix(".venv/bin/"))
    return out


def resolve(line: str):
    """(the subcommand's parser, the words after it) of a README line."""
    words = shlex.split(line)[1:]
    parser = build_parser()
    while words and words[0] in subparsers(parser):
        parser = subparsers(parser)[words.pop(0)]
    return parser, words


def test_readme_is_short():
    assert len(README.read_text().splitlines()) <= 250


@pytest.mark.parametrize("line", command_lines(README.read_text()) + command_lines((ROOT / "docs" / "commands.md").read_text()))
def test_every_readme_command_line_names_real_commands_options_and_suffixes(line):
    parser, words = resolve(line)
    assert parser is not build_parser(), line
    options = {s for a in parser._actions for s in a.option_strings}
    for word in words:
        for flag in re.findall(r"(?:^|\[|\|)(--?[a-z][a-z-]*)", word):
            assert flag in options, f"{line}: {flag} is not an option of {parser.prog}"
    output = next((a for a in parser._actions if "-o" in a.option_strings), None)
    for k, word in enumerate(words):
        if word == "-o" and output is not None and output.type is not None and k + 1 < len(words):
            name = words[k + 1]
            stem, _, tail = name.partition(".")
            for suffix in tail.split("|"):  # OUT.glb|mp4|csv or rigged.glb|avatar.vrm
                suffix = suffix.rpartition(".")[2] if "." in suffix else suffix
                if re.fullmatch(r"[a-z0-9]+", suffix):
                    output.type(f"x.{suffix}")  # raises ArgumentTypeError for a suffix it refuses


def test_every_relative_link_in_the_docs_is_a_file():
    for page in [README, *DOCS]:
        for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", page.read_text()):
            if "://" in target:
                continue
            assert (page.parent / target).exists(), f"{page.name} links to {target}, which is not there"


def test_every_docs_page_is_reachable_from_the_docs_index():
    index = (ROOT / "docs" / "README.md").read_text()
    for page in DOCS:
        if page.name != "README.md":
            assert f"({page.name})" in index, f"docs/README.md does not link {page.name}"
