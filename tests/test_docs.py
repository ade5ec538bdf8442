"""The documentation: every page is reachable (the site's navigation and the index list it), every
relative link and image resolves, user-facing text names no internal issue number, and the site builds
strictly with mkdocs (which also fails on broken links)."""

import re
import subprocess
import sys

import pytest
import yaml

from glimpse.config import REPO_ROOT

DOCS = REPO_ROOT / "docs"
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def nav_pages(nav) -> list[str]:
    pages = []
    for entry in nav:
        for value in entry.values():
            pages += nav_pages(value) if isinstance(value, list) else [value]
    return pages


def test_every_page_is_in_the_navigation_and_the_index():
    config = yaml.safe_load((REPO_ROOT / "mkdocs.yml").read_text())
    pages = {p.name for p in DOCS.glob("*.md")}
    assert sorted(nav_pages(config["nav"])) == sorted(pages)
    listed = set(LINK.findall((DOCS / "index.md").read_text()))
    assert listed == pages - {"index.md"}


@pytest.mark.parametrize("page", sorted(p.name for p in DOCS.glob("*.md")) + ["../README.md"])
def test_relative_links_resolve_and_no_issue_numbers(page):
    text = (DOCS / page).read_text()
    for target in LINK.findall(text):
        if "://" not in target:
            assert (DOCS / page).parent.joinpath(target).exists(), f"{page}: broken link {target}"
    assert not re.search(r"(?i)\bissues?\s*#?\d+|#\d{2,}\b", text), f"{page} names an issue number"


def test_the_site_builds_strictly(tmp_path):
    pytest.importorskip("mkdocs")
    result = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "-f",
                             str(REPO_ROOT / "mkdocs.yml"), "-d", str(tmp_path / "site")],
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "site" / "report.html").is_file() and (tmp_path / "site" / "index.html").is_file()
