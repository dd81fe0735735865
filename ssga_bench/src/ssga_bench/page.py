"""One page per run: ``index.html`` beside a run's outputs (and a bench's), to look at.

A static page that opens from disk, offline: no server, nothing fetched from elsewhere,
every picture a file beside it. Its tables are the report's own text (``report.md``,
``bench.md``), so its figures are those of ``results.csv``; around them, the pictures a
researcher compares runs by: the per-level plot, sample queries right and wrong, the
workspace map, a few scene graphs, and where the time went.

A small inline script marks the body with the pictures that failed to load
(``data-broken-images``), so a headless browser can check the page as a reader sees it.
"""

from __future__ import annotations

import html
import json
import re
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

from ssga_bench.io import atomic_write_bytes

STYLE = """
body { font: 14px/1.45 system-ui, sans-serif; margin: 2em auto; max-width: 1400px; padding: 0 1em; color: #222; }
table { border-collapse: collapse; margin: 0.6em 0 1.2em; font-size: 13px; }
th, td { border: 1px solid #ccc; padding: 2px 6px; }
td:not(:first-child) { text-align: right; white-space: nowrap; }
tr:nth-child(even) { background: #f6f6f6; }
img { max-width: 100%; border: 1px solid #ddd; }
.gallery { display: flex; flex-wrap: wrap; gap: 8px; }
.gallery figure { margin: 0; max-width: 460px; }
figcaption { font-size: 12px; color: #555; }
nav a { margin-right: 1em; }
"""

CHECK_IMAGES = """
addEventListener("load", () => {
  const broken = [...document.images].filter(i => !i.complete || i.naturalWidth === 0).map(i => i.getAttribute("src"));
  document.body.dataset.brokenImages = broken.join(" ") || "none";
});
"""


def markdown_html(text: str) -> str:
    """The Markdown ssga's reports use (headings, pipe tables, bullets, paragraphs, bold,
    italics, code) as HTML; anything else is shown as text."""
    out: list[str] = []
    table: list[list[str]] = []
    items: list[str] = []

    def flush(keep_list: bool = False) -> None:
        if table:
            head, *body = table
            out.append("<table><thead><tr>" + "".join(f"<th>{_inline(c)}</th>" for c in head) + "</tr></thead><tbody>")
            out.extend("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in row) + "</tr>" for row in body)
            out.append("</tbody></table>")
            table.clear()
        if items and not keep_list:
            out.append("<ul>" + "".join(f"<li>{_inline(i)}</li>" for i in items) + "</ul>")
            items.clear()

    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("|"):
            cells = [c.strip() for c in stripped.strip("|").split("|")]
            if not all(re.fullmatch(r":?-+:?", c) for c in cells):  # the header's underline
                table.append(cells)
            continue
        bullet = stripped.startswith("- ")
        flush(keep_list=bullet)
        heading = re.match(r"(#{1,6}) (.*)", stripped)
        if heading:
            level = min(len(heading.group(1)) + 1, 6)  # the page's own title is the h1
            out.append(f"<h{level}>{_inline(heading.group(2))}</h{level}>")
        elif bullet:
            items.append(stripped[2:])
        elif stripped:
            out.append(f"<p>{_inline(stripped)}</p>")
    flush()
    return "\n".join(out)


def _inline(text: str) -> str:
    text = html.escape(text, quote=False)
    text = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", text)
    text = re.sub(r"`(.+?)`", r"<code>\1</code>", text)
    return re.sub(r"(?<!\w)_(.+?)_(?!\w)", r"<em>\1</em>", text)


def _figures(paths: Iterable[str], caption: Callable[[str], str] = lambda p: Path(p).stem) -> str:
    figures = [f'<figure><a href="{html.escape(p)}"><img src="{html.escape(p)}" alt="{html.escape(caption(p))}" loading="lazy"></a>'
               f"<figcaption>{html.escape(caption(p))}</figcaption></figure>" for p in paths]  # fmt: skip
    return f'<div class="gallery">{"".join(figures)}</div>' if figures else "<p>none</p>"


def _timings_table(timings: dict[str, dict[str, float]]) -> str:
    wall, work, views = timings.get("wall", {}), timings.get("work", {}), timings.get("views", {})
    rows = [f"<tr><td>{html.escape(p)}</td><td>{s:.1f}</td></tr>" for p, s in wall.items()]
    out = "<h3>Wall time per phase (s)</h3><table><tbody>" + "".join(rows) + f"<tr><td><strong>all</strong></td><td>{sum(wall.values()):.1f}</td></tr></tbody></table>"
    rows = [
        f"<tr><td>{html.escape(p)}</td><td>{s:.1f}</td><td>{views.get(p, '')}</td><td>{f'{views[p] / s:.1f}' if views.get(p) and s > 0 else ''}</td></tr>"
        for p, s in work.items()
    ]
    return out + "<h3>Work per stage, summed over the workers</h3><table><thead><tr><th>stage</th><th>s</th><th>views</th><th>views/s</th></tr></thead><tbody>" + "".join(rows) + "</tbody></table>"


def _page(title: str, body: Sequence[str]) -> bytes:
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<title>{html.escape(title)}</title><style>{STYLE}</style><script>{CHECK_IMAGES}</script></head>"
        f"<body><h1>{html.escape(title)}</h1>\n" + "\n".join(body) + "\n</body></html>\n"
    ).encode()


def _present(out: Path, names: Iterable[str]) -> list[str]:
    return [n for n in names if (out / n).is_file()]


def write_run_page(out: Path) -> Path:
    """``out/index.html`` from the run's files in ``out`` (report, plot, queries, workspace map,
    scene graphs, timings); whatever is missing is left out. Returns its path."""
    report = (out / "report.md").read_text()
    title = report.splitlines()[0].lstrip("# ").strip() if report else out.name
    files = _present(out, ["report.md", "results.csv", "results.png", "predictions.jsonl", "timings.json", "fusion.json", "heading.json", "protocol-fitted.json"])
    body = ["<nav>" + "".join(f'<a href="{f}">{f}</a>' for f in files) + "</nav>"]
    if (out / "protocol-fitted.json").is_file():
        fitted = json.loads((out / "protocol-fitted.json").read_text())
        chose = ", ".join(f"{k} = {v:g} (configured {fitted['configured'][k]:g})" for k, v in fitted["fitted"].items())
        body.append(f"<p><strong>The protocol was fitted to this workspace:</strong> {html.escape(chose)}, because as configured: {html.escape(fitted['because'])}</p>")
    body.append("<h2>Table 1: Top-1, Top-5 and MRR per difficulty level</h2>" + markdown_html("\n".join(report.splitlines()[1:])))
    if "results.png" in files:
        body.append('<h2>Per level, with 95% intervals</h2><img src="results.png" alt="results per level">')
    queries = sorted(p.relative_to(out).as_posix() for p in (out / "queries").glob("*.png")) if (out / "queries").is_dir() else []
    body.append("<h2>Sample queries, right and wrong</h2>" + _figures(queries, lambda p: Path(p).stem.split("-", 1)[-1]))
    if (out / "workspace.png").is_file():
        body.append('<h2>The workspace</h2><p>Cells, training views, test cameras by level and the pseudo-views training synthesized (purple).</p><img src="workspace.png" alt="workspace map">')
    graphs = sorted(p.relative_to(out).as_posix() for p in (out / "scene-graphs").glob("*.png")) if (out / "scene-graphs").is_dir() else []
    if graphs:
        body.append("<h2>Scene graphs of a few test views</h2>" + _figures(graphs))
    if (out / "timings.json").is_file():
        body.append("<h2>Where the time went</h2>" + _timings_table(json.loads((out / "timings.json").read_text())))
    path = out / "index.html"
    atomic_write_bytes(path, _page(title, body))
    return path


def write_bench_page(out: Path, summary: str, seeds: Sequence[int]) -> Path:
    """``out/index.html`` of a bench: the summary over seeds (``bench.md``) and a link to each seed's page."""
    links = "".join(f'<a href="seed-{s}/index.html">seed {s}</a>' for s in seeds if (out / f"seed-{s}" / "index.html").is_file())
    body = [f"<nav><a href=\"bench.md\">bench.md</a><a href=\"bench.json\">bench.json</a>{links}</nav>", markdown_html(summary)]
    path = out / "index.html"
    atomic_write_bytes(path, _page(f"Bench: seeds {', '.join(map(str, seeds))}", body))
    return path
