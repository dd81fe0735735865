"""One page per run and per bench: index.html, static, offline, its figures those of results.csv."""

from __future__ import annotations

import csv
import html.parser
import math
import shutil
import subprocess
from pathlib import Path

import pytest

from ssga_bench.config import validate_experiment
from ssga_bench.dataset_build import build_dataset
from ssga_bench.experiment import run_experiment
from ssga_bench.page import markdown_html, write_bench_page
from ssga_bench.protocol import ProtocolConfig
from ssga_bench.testing import WallWorkspaceSource


class Page(html.parser.HTMLParser):
    """The page's references (src, href) and its tables as rows of cell texts."""

    def __init__(self) -> None:
        super().__init__()
        self.references: list[str] = []
        self.tables: list[list[list[str]]] = []
        self._cell: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        self.references += [attrs[a] for a in ("src", "href") if a in attrs]
        if tag == "table":
            self.tables.append([])
        elif tag == "tr":
            self.tables[-1].append([])
        elif tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self.tables[-1][-1].append("".join(self._cell).strip())
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


@pytest.fixture(scope="module")
def run(tmp_path_factory, ssga_plugin_set_module):
    root = tmp_path_factory.mktemp("page")
    dataset = build_dataset(WallWorkspaceSource().open(), root / "ds", source={"name": "test-wall"}, protocol=ProtocolConfig(cells=2, test_per_class=2, seed=4))
    exp = validate_experiment(
        {
            "workspace": {"name": "test-wall"},
            "stages": {"parser": {"name": "test-stripes"}, "descriptor": {"name": "test-patch-colour"}, "synthesizer": {"name": "test-shift"}},
            "variants": ["PDS", "SD"],
            "training": {"classifier": "graph-match"},
        },
        ssga_plugin_set_module,
    )
    run_experiment(exp, dataset, root / "out")
    return root / "out"


@pytest.fixture(scope="module")
def ssga_plugin_set_module():
    from ssga_bench import testing
    from ssga_core.testing import get_plugin_manager, stages

    manager = get_plugin_manager()  # the installed plugins, and the stand-ins beside them
    manager.register(stages, "stand-ins")
    manager.register(testing, "stand-in-workspaces")
    return manager.registry()


def test_a_run_writes_one_page_whose_every_reference_is_beside_it(run):
    page = Page()
    page.feed((run / "index.html").read_text())
    local = [r for r in page.references if "://" not in r]
    assert local == page.references  # nothing from elsewhere: it opens offline
    missing = [r for r in local if not (run / r).is_file()]
    assert not missing
    pictures = {Path(r).parent.as_posix() for r in local if r.endswith(".png")}
    assert {"queries", "scene-graphs", "."} <= pictures  # queries, scene graphs, the plot and the workspace map
    assert {"results.png", "workspace.png"} <= set(local)


def test_the_pages_table_1_is_results_csv(run):
    page = Page()
    page.feed((run / "index.html").read_text())
    head, *rows = page.tables[0]
    assert head[1].startswith("Top-1[%]")
    with (run / "results.csv").open() as f:
        mrr = {(r["row"], r["group"]): float(r["mrr"]) for r in csv.DictReader(f) if r["mrr"]}
    columns = {title: i for i, title in enumerate(head)}
    checked = 0
    for row in rows:
        label = row[0].removesuffix(" ⚠")
        for group in ("L1", "L2", "L3"):
            column = columns.get(f"MRR[%] {group}")
            if column is None or (label, group) not in mrr:
                continue
            expected = "–" if math.isnan(mrr[label, group]) else f"{mrr[label, group]:.1f}"  # a group without test views
            assert row[column].split(" ±")[0] == expected, (label, group)
            checked += 1
    assert checked >= 5


def test_markdown_tables_headings_lists_and_escaping():
    text = "### A <b> title\n\n| | x |\n|---|---:|\n| **E** | 1.0 ±0.5 |\n\n- one\n- two\n\n_note_\n"
    made = markdown_html(text)
    assert "<h4>A &lt;b&gt; title</h4>" in made
    assert "<thead><tr><th></th><th>x</th></tr></thead>" in made and "<td><strong>E</strong></td><td>1.0 ±0.5</td>" in made
    assert "<ul><li>one</li><li>two</li></ul>" in made and "<p><em>note</em></p>" in made


def test_a_bench_page_links_each_seeds_page(tmp_path):
    for seed in (3, 4):
        (tmp_path / f"seed-{seed}").mkdir()
        (tmp_path / f"seed-{seed}" / "index.html").write_text("<html></html>")
    write_bench_page(tmp_path, "## Mean over seeds 3, 4\n\n| | MRR |\n|---|---:|\n| E | 1.0 |\n", [3, 4])
    page = Page()
    page.feed((tmp_path / "index.html").read_text())
    assert {"seed-3/index.html", "seed-4/index.html", "bench.md"} <= set(page.references)
    assert page.tables[0] == [["", "MRR"], ["E", "1.0"]]


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium here (make test installs Debian's where it can)")
def test_the_page_loads_in_a_real_browser_without_errors_or_broken_pictures(run):
    done = subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=10000", "--enable-logging=stderr", "--v=0",
         "--dump-dom", (run / "index.html").as_uri()],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert 'data-broken-images="none"' in done.stdout, "pictures that did not load: " + done.stdout.split("data-broken-images=")[-1][:300]
    console = [line for line in done.stderr.splitlines() if ":CONSOLE" in line]
    assert not console, console
