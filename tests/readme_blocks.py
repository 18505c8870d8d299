"""The code blocks of a README section, for tests that run the README as written."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def section(title: str) -> str:
    """The text of the README section headed ``## title`` (up to the next ``## `` heading)."""
    text = README.read_text()
    start = text.index(f"## {title}")
    end = text.find("\n## ", start + 1)
    return text[start:] if end < 0 else text[start:end]


def blocks(title: str, language: str | None = None) -> list[str]:
    """The fenced code blocks of section ``title`` (only ``language`` ones when given), in order."""
    found = re.findall(r"```(\w*)\n(.*?)```", section(title), flags=re.S)
    return [body for lang, body in found if language is None or lang == language]


def block(title: str, first_line: str) -> str:
    """The code block of section ``title`` whose first line is ``first_line``."""
    for body in blocks(title):
        if body.startswith(first_line):
            return str(body)
    raise AssertionError(f"README section {title!r} has no block starting with {first_line!r}")
