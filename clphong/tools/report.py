"""Report formatting shared by the tools (bench tables, hard cases, the bad-input catalogue)."""

from __future__ import annotations

__all__ = ["markdown_table"]


def markdown_table(header, rows) -> str:
    """A Markdown table of column titles and rows of cells (anything str() takes)."""
    lines = [header, ["---"] * len(header), *rows]
    return "\n".join("| " + " | ".join(str(c) for c in line) + " |" for line in lines)
