"""MkDocs hook: `<!-- cli-help -->` on a page becomes the `--help` of `angora-jax` and of each of its commands, read
from the command's own argparse parser at build time, so the command-line reference cannot drift from the code."""

from __future__ import annotations

import argparse
from typing import Any

MARKER = "<!-- cli-help -->"


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    if MARKER not in markdown:
        return markdown
    from angora_jax.cli import parser  # imported only for the page that shows it: it imports JAX

    return markdown.replace(MARKER, "\n".join(help_sections(parser())))


def help_sections(top: argparse.ArgumentParser) -> list[str]:
    """A section per command (subcommands of a command, such as `analyze decode`, nested), each its `--help`."""
    sections = [f"```text\n{top.format_help()}```\n"]
    sections += command_sections(top, "angora-jax", level=2)
    return sections


def command_sections(command: argparse.ArgumentParser, prog: str, level: int) -> list[str]:
    sections = []
    for action in command._actions:  # argparse keeps its subcommands only here
        if not isinstance(action, argparse._SubParsersAction):
            continue
        for name, sub in action.choices.items():
            sections.append(f"{'#' * level} `{prog} {name}`\n\n```text\n{sub.format_help()}```\n")
            sections += command_sections(sub, f"{prog} {name}", level + 1)
    return sections
