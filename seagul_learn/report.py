"""A report a person can open: Markdown with embedded figures, plus a self-contained HTML copy.

The report is assembled from plain data (sections of text, tables as lists of rows, figure paths), so every stage of
an experiment can add to it without knowing how it is rendered.
"""

from __future__ import annotations

import base64
import html
import importlib.metadata
import os
import platform
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: Libraries whose versions every report records.
REPORTED_PACKAGES = ("seagul", "numpy", "scipy", "casadi", "torch", "gymnasium", "mujoco", "stable-baselines3")


@dataclass
class Table:
    """A table: a header row and data rows (cells are rendered with ``str`` unless floats)."""

    header: Sequence[str]
    """Column names."""
    rows: Sequence[Sequence[Any]]
    """Data rows, one sequence of cells each."""


@dataclass
class Section:
    """A titled part of the report: paragraphs, tables and figures in that order."""

    title: str
    """Heading text."""
    paragraphs: list[str] = field(default_factory=list)
    """Markdown paragraphs."""
    tables: list[Table] = field(default_factory=list)
    """Tables."""
    figures: list[tuple[str, str]] = field(default_factory=list)
    """``(path relative to the report, caption)`` pairs."""


def library_versions() -> dict[str, str]:
    """Installed versions of the libraries that shape the results."""
    versions = {"python": platform.python_version()}
    for name in REPORTED_PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def machine_description() -> str:
    """One line naming the machine (CPU model, cores, OS)."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}"


def _cell(value: Any) -> str:
    if isinstance(value, float):
        if value != value:  # NaN
            return "n/a"
        return f"{value:.4g}"
    return str(value)


def render_markdown(title: str, sections: Sequence[Section]) -> str:
    """Markdown text of the report (figures referenced by relative path)."""
    lines = [f"# {title}", ""]
    for section in sections:
        lines += [f"## {section.title}", ""]
        for paragraph in section.paragraphs:
            lines += [paragraph, ""]
        for table in section.tables:
            lines.append("| " + " | ".join(table.header) + " |")
            lines.append("|" + "---|" * len(table.header))
            for row in table.rows:
                lines.append("| " + " | ".join(_cell(c) for c in row) + " |")
            lines.append("")
        for path, caption in section.figures:
            lines += [f"![{caption}]({path})", "", f"*{caption}*", ""]
    return "\n".join(lines).rstrip() + "\n"


def _inline_markdown(text: str) -> str:
    """The little inline Markdown the report uses (code, bold) as HTML."""
    text = html.escape(text)
    text = re.sub(r"`([^`]+)`", r"<code>\1</code>", text)
    return re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", text)


def render_html(title: str, sections: Sequence[Section], base_dir: Path) -> str:
    """Self-contained HTML (figures embedded as base64 PNG) that opens in any browser."""
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.45}"
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}"
        "th{background:#eee}img{max-width:100%}figcaption{font-style:italic;color:#444}"
        "code{background:#f4f4f4;padding:0 3px}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
    ]
    for section in sections:
        parts.append(f"<h2>{html.escape(section.title)}</h2>")
        parts += [f"<p>{_inline_markdown(p)}</p>" for p in section.paragraphs]
        for table in section.tables:
            parts.append("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in table.header) + "</tr>")
            for row in table.rows:
                parts.append("<tr>" + "".join(f"<td>{html.escape(_cell(c))}</td>" for c in row) + "</tr>")
            parts.append("</table>")
        for path, caption in section.figures:
            figure = base_dir / path
            if figure.exists():
                data = base64.b64encode(figure.read_bytes()).decode("ascii")
                src = f"data:image/png;base64,{data}"
            else:
                src = html.escape(path)
            parts.append(f"<figure><img src='{src}' alt='{html.escape(caption)}'>")
            parts.append(f"<figcaption>{html.escape(caption)}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(out_dir: Path, title: str, sections: Sequence[Section]) -> Path:
    """Write ``report.md`` and ``report.html`` into ``out_dir`` atomically; return the Markdown path."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    md_path = out_dir / "report.md"
    for path, text in ((md_path, render_markdown(title, sections)), (out_dir / "report.html", None)):
        if text is None:
            text = render_html(title, sections, out_dir)
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    return md_path
