"""Self-contained HTML reports from a few primitives: page, section, table, figure, warnings.

Everything a page needs is inside the file: the style sheet is inline and figures are inline
``<svg>`` elements or PNG data URIs, so a report opens offline, can be mailed or attached to a lab notebook, and loads nothing
from the network. Every primitive returns an HTML string; text is escaped, HTML passed in as
:class:`Html` is not.

    >>> from mbus_framework.pipeline import html
    >>> body = html.section("Estimates", html.table([["E_sigma", 2.42e10, "Pa"]], header=["name", "value", "unit"]))
    >>> page = html.page("potato", [body, html.warnings([])])
    >>> page.startswith("<!DOCTYPE html>") and "<table" in page
    True
"""
from __future__ import annotations

import base64
import html as _html
import math
from typing import TYPE_CHECKING, Any, Iterable, Sequence

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

STYLE = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0 auto;max-width:1100px;
padding:1.5rem;color:#1d2430;line-height:1.45}
h1{font-size:1.6rem;margin:.2rem 0}h2{font-size:1.2rem;border-bottom:1px solid #d0d7de;padding-bottom:.2rem;
margin-top:2rem}.subtitle{color:#57606a;margin:0 0 1rem}
table{border-collapse:collapse;margin:.6rem 0;font-size:.92rem}caption{text-align:left;color:#57606a;
padding:.2rem 0}th,td{border:1px solid #d0d7de;padding:.25rem .6rem;text-align:left}
th{background:#f6f8fa}td.num{text-align:right;font-variant-numeric:tabular-nums}
figure{margin:1rem 0}figure img,figure svg{max-width:100%;height:auto;border:1px solid #eaeef2}
figcaption{color:#57606a;font-size:.9rem}
.warnings{border-left:4px solid #d4a72c;background:#fff8c5;padding:.5rem 1rem;margin:.6rem 0}
.warnings.ok{border-color:#2da44e;background:#dafbe1}.warnings li{margin:.3rem 0}
pre{background:#f6f8fa;padding:.8rem;overflow:auto;font-size:.85rem}
nav a{margin-right:.8rem}
"""


class Html(str):
    """A string that is already HTML: primitives insert it as it is, without escaping."""


def escape(value: Any) -> Html:
    """``value`` as HTML text (``&``, ``<``, ``>`` and quotes escaped); Html passes through."""
    return value if isinstance(value, Html) else Html(_html.escape(str(value), quote=True))


def number(value: Any, digits: int = 5) -> str:
    """A table cell's text: floats to ``digits`` significant digits, inf/nan spelt out."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return f"{value:.{digits}g}"
    return str(value)


def table(rows: Iterable[Sequence[Any]], header: Sequence[str] | None = None, caption: str | None = None,
          digits: int = 5) -> Html:
    """A ``<table>``; numbers are right-aligned and shown to ``digits`` significant digits."""
    parts = ["<table>"]
    if caption:
        parts.append(f"<caption>{escape(caption)}</caption>")
    if header:
        parts.append("<thead><tr>" + "".join(f"<th>{escape(h)}</th>" for h in header) + "</tr></thead>")
    parts.append("<tbody>")
    for row in rows:
        cells = []
        for v in row:
            numeric = isinstance(v, (int, float)) and not isinstance(v, bool)
            cls = ' class="num"' if numeric else ""
            cells.append(f"<td{cls}>{escape(number(v, digits))}</td>")
        parts.append("<tr>" + "".join(cells) + "</tr>")
    parts.append("</tbody></table>")
    return Html("".join(parts))


def key_values(mapping: dict[str, Any], caption: str | None = None, digits: int = 5) -> Html:
    """A two-column table of a mapping."""
    return table(list(mapping.items()), header=["", "value"], caption=caption, digits=digits)


def png_bytes(fig: "Figure", dpi: int = 100) -> bytes:
    """Render a matplotlib figure to PNG bytes (Agg, no pyplot state)."""
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg

    if not isinstance(fig.canvas, FigureCanvasAgg):
        FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def image(content: bytes, alt: str, caption: str | None = None) -> Html:
    """A ``<figure>`` holding an image: SVG bytes (``<svg ...``) inline, with ``alt`` as its
    accessible label; PNG bytes as a base64 data URI."""
    cap = f"<figcaption>{escape(caption)}</figcaption>" if caption else ""
    if content.lstrip()[:4] == b"<svg":
        svg = content.decode("utf-8").replace("<svg ", f'<svg role="img" aria-label="{escape(alt)}" ', 1)
        return Html(f"<figure>{svg}{cap}</figure>")
    data = base64.b64encode(content).decode("ascii")
    return Html(f'<figure><img alt="{escape(alt)}" src="data:image/png;base64,{data}">{cap}</figure>')


def figure(fig: "Figure", alt: str, caption: str | None = None, dpi: int = 100) -> Html:
    """A matplotlib figure embedded as a PNG data URI."""
    return image(png_bytes(fig, dpi), alt, caption)


def warnings(items: Sequence[str], none: str = "No warnings: the fit and the data raised no concern.") -> Html:
    """The warnings as a highlighted list, or a short all-clear line."""
    if not items:
        return Html(f'<div class="warnings ok">{escape(none)}</div>')
    lis = "".join(f"<li>{escape(w)}</li>" for w in items)
    return Html(f'<div class="warnings"><strong>Warnings</strong><ul>{lis}</ul></div>')


def paragraph(text: Any) -> Html:
    return Html(f"<p>{escape(text)}</p>")


def code(text: str) -> Html:
    """Preformatted text (a config, a log)."""
    return Html(f"<pre>{escape(text)}</pre>")


def section(title: str, *parts: str, anchor: str | None = None) -> Html:
    """A titled section (``<h2>``); ``anchor`` gives it an id for the page's navigation."""
    ident = f' id="{escape(anchor)}"' if anchor else ""
    return Html(f"<section{ident}><h2>{escape(title)}</h2>{''.join(escape(p) for p in parts)}</section>")


def fragment(*parts: str) -> Html:
    """Parts joined into one block (for a notebook's rich display)."""
    return Html(f'<div class="mbus">{"".join(escape(p) for p in parts)}</div>')


def page(title: str, parts: Sequence[str], subtitle: str | None = None,
         nav: Sequence[tuple[str, str]] = ()) -> str:
    """A complete, self-contained HTML document; ``nav`` is (anchor, label) links to sections."""
    links = "".join(f'<a href="#{escape(a)}">{escape(label)}</a>' for a, label in nav)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        f"<title>{escape(title)}</title><style>{STYLE}</style></head><body>"
        f"<h1>{escape(title)}</h1>"
        + (f'<p class="subtitle">{escape(subtitle)}</p>' if subtitle else "")
        + (f"<nav>{links}</nav>" if links else "")
        + "".join(escape(p) for p in parts)
        + "</body></html>\n"
    )
