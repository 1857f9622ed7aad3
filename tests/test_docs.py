"""The reference in docs/ names what the tool has: every subcommand and option of the command
line appears in docs/cli.md (the studio's options in docs/studio.md, which cli.md links)."""

from __future__ import annotations

import argparse
from pathlib import Path

from drawstring.app.parser import build_parser

DOCS = Path(__file__).resolve().parents[1] / "docs"
#: Subcommands whose options are documented on a page of their own, which docs/cli.md links.
OWN_PAGE = {"studio": "studio.md"}


def subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    found: dict[str, argparse.ArgumentParser] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            found.update(action.choices)
    return found


def test_every_subcommand_and_option_is_in_cli_md() -> None:
    text = (DOCS / "cli.md").read_text()
    commands = subcommands()
    assert {"design", "simulate", "profiles"} <= set(commands)
    missing = [f"drawstring {name}" for name in commands if f"`drawstring {name}" not in text]
    for name, sub in commands.items():
        page = text + ((DOCS / OWN_PAGE[name]).read_text() if name in OWN_PAGE else "")
        assert name not in OWN_PAGE or f"({OWN_PAGE[name]})" in text
        for action in sub._actions:
            missing += [
                f"{name} {flag}"
                for flag in action.option_strings
                if flag.startswith("--") and flag != "--help" and f"`{flag}" not in page
            ]
    assert not missing, f"not in docs/cli.md: {missing}"
