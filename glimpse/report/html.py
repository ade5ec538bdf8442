"""Small HTML builders for the report: escaped text, tables, figures, videos, and the subset of Markdown that
Glimpse's own .md outputs use (headings, tables, lists, paragraphs)."""

from __future__ import annotations

import html
from collections.abc import Sequence

STYLE = """
body { font-family: system-ui, sans-serif; margin: 0 auto; max-width: 1180px; padding: 0 1.2em 3em;
       color: #1d1d1f; line-height: 1.45; }
h1 { margin-bottom: 0.1em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: 0.2em; margin-top: 1.8em; }
nav a { margin-right: 1em; } .muted { color: #666; } .warn { color: #9a4a00; }
table { border-collapse: collapse; margin: 0.6em 0 1em; font-size: 0.92em; }
th, td { border: 1px solid #ddd; padding: 0.25em 0.6em; text-align: left; vertical-align: top; }
td.num { text-align: right; font-variant-numeric: tabular-nums; } th { background: #f4f4f6; }
figure { display: inline-block; margin: 0.4em 0.8em 0.8em 0; vertical-align: top; }
figure img, figure video { display: block; max-width: 100%; image-rendering: auto; }
figcaption { font-size: 0.85em; color: #555; max-width: 560px; }
.headline { font-size: 1.05em; background: #f4f7fb; padding: 0.6em 0.9em; border-radius: 6px; }
details { margin: 0.3em 0 1em; } pre { background: #f6f6f6; padding: 0.6em; overflow-x: auto; font-size: 0.85em; }
"""


def esc(value: object) -> str:
    return html.escape(str(value), quote=True)


def number(value: object, decimals: int = 3) -> str:
    """A float rounded for a table; ints, text and None (as a dash) as they are."""
    if value is None:
        return "–"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return esc(value)
    if isinstance(value, int):
        return f"{value:,}"
    return f"{value:,.{decimals}f}"


def table(headers: Sequence[str] | None, rows: Sequence[Sequence[object]], decimals: int = 3) -> str:
    """An HTML table (no header row when ``headers`` is None); numbers right-aligned and rounded to
    ``decimals``."""
    head = "<thead><tr>" + "".join(f"<th>{esc(h)}</th>" for h in headers) + "</tr></thead>" if headers else ""
    body = []
    for row in rows:
        cells = []
        for cell in row:
            numeric = isinstance(cell, (int, float)) and not isinstance(cell, bool)
            cells.append(f'<td class="num">{number(cell, decimals)}</td>' if numeric else f"<td>{number(cell)}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table>{head}<tbody>{''.join(body)}</tbody></table>"


def image(src: str, caption: str) -> str:
    return f'<figure><img src="{esc(src)}" alt="{esc(caption)}"><figcaption>{esc(caption)}</figcaption></figure>'


def video(src: str, caption: str, height: int) -> str:
    """A video element ``height`` pixels high (small renders enlarged)."""
    return (f'<figure><video src="{esc(src)}" height="{height}" controls loop muted preload="metadata"></video>'
            f"<figcaption>{esc(caption)}</figcaption></figure>")


def section(anchor: str, title: str, body: str) -> str:
    return f'<section id="{esc(anchor)}"><h2>{esc(title)}</h2>\n{body}\n</section>'


def _inline(text: str) -> str:
    """Markdown inline code (`x`) as <code>; everything else escaped."""
    parts = text.split("`")
    return "".join(f"<code>{esc(p)}</code>" if i % 2 else esc(p) for i, p in enumerate(parts))


def markdown(text: str) -> str:
    """HTML of Markdown as Glimpse writes it: '#' headings (shown two levels down), pipe tables (the row of
    dashes skipped; cells aligned right when the dashes end with ':'), '- ' lists (folded under the line before
    them when it ends with ':', as the protocols under Glimpse's tables), other lines as paragraphs."""
    out: list[str] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i].strip()
        if line.startswith("#"):
            level = min(6, len(line) - len(line.lstrip("#")) + 2)
            out.append(f"<h{level}>{_inline(line.lstrip('#').strip())}</h{level}>")
        elif line.startswith("|"):
            block = []
            while i < len(lines) and lines[i].strip().startswith("|"):
                block.append([c.strip() for c in lines[i].strip().strip("|").split("|")])
                i += 1
            right = [c.endswith(":") for c in block[1]] if len(block) > 1 else []
            rows = [block[0]] + block[2:]
            html_rows = []
            for r, cells in enumerate(rows):
                tag = "th" if r == 0 else "td"
                html_rows.append("<tr>" + "".join(
                    f'<{tag}{" class=num" if r and c < len(right) and right[c] else ""}>{_inline(cell)}</{tag}>'
                    for c, cell in enumerate(cells)) + "</tr>")
            out.append("<table>" + "".join(html_rows) + "</table>")
            continue
        elif line.startswith("- "):
            items = []
            while i < len(lines) and lines[i].strip().startswith("- "):
                items.append(f"<li>{_inline(lines[i].strip()[2:])}</li>")
                i += 1
            listed = "<ul>" + "".join(items) + "</ul>"
            if out and out[-1].startswith("<p>") and out[-1].endswith(":</p>"):
                listed = f"<details><summary>{out.pop()[3:-5]}</summary>{listed}</details>"
            out.append(listed)
            continue
        elif line:
            out.append(f"<p>{_inline(line)}</p>")
        i += 1
    return "\n".join(out)
