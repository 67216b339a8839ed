"""``report.html`` for output folders other than a single fit: studies, model comparisons,
excitation designs and transducer calibrations.

The page holds what the command printed (the summary as text), every figure the folder holds
(its PNG files, embedded as data URIs) and the validated config, so every folder ``mbus-run``
writes has one self-contained page to open, whatever the mode. A fit's own report is
:mod:`mbus_framework.pipeline.run_report`.
"""
from __future__ import annotations

from pathlib import Path

from mbus_framework.pipeline import html
from mbus_framework.pipeline.run_report import REPORT_FILE
from mbus_framework.pipeline.storage import atomic_write_text



def folder_report_html(folder: Path, title: str, summary_text: str, subtitle: str | None = None) -> str:
    """The page: the printed summary, the folder's PNG figures (sorted by name), config.yaml."""
    folder = Path(folder)
    parts = [html.section("Summary", html.code(summary_text.strip("\n")), anchor="summary")]
    nav = [("summary", "Summary")]
    figures = [html.image(p.read_bytes(), p.stem.replace("_", " "), p.name) for p in sorted(folder.glob("*.png"))]
    if figures:
        parts.append(html.section("Figures", *figures, anchor="figures"))
        nav.append(("figures", "Figures"))
    config = folder / "config.yaml"
    if config.is_file():
        parts.append(html.section("Config", html.code(config.read_text(encoding="utf-8", errors="replace")),
                                  anchor="config"))
        nav.append(("config", "Config"))
    return html.page(title, parts, subtitle=subtitle or str(folder), nav=nav)


def write_folder_report(folder: Path, title: str, summary_text: str, subtitle: str | None = None) -> Path:
    """Write ``report.html`` into ``folder`` (see :func:`folder_report_html`); returns its path."""
    return atomic_write_text(Path(folder) / REPORT_FILE, folder_report_html(folder, title, summary_text, subtitle))
