"""The front door and the manual hold together: the README stays short and links only to pages
that exist, and every page of docs/ is in the site's navigation (``mkdocs build --strict`` in CI
checks the links inside the site)."""

import re
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


def nav_pages():
    text = (ROOT / "mkdocs.yml").read_text()
    conf = yaml.safe_load(text)
    pages = []
    for entry in conf["nav"]:
        pages.extend(entry.values())
    return pages


def test_the_readme_is_at_most_300_lines_and_its_links_resolve():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 300
    links = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text)
    assert any(link.startswith("docs/") for link in links)
    missing = [link for link in links if not link.startswith("http")
               and not (ROOT / link).exists()]
    assert missing == []


def test_every_page_is_in_the_navigation_and_every_nav_entry_exists():
    pages = set(nav_pages())
    on_disk = {p.name for p in (ROOT / "docs").glob("*.md")}
    assert on_disk == pages, (on_disk - pages, pages - on_disk)


def test_the_readme_maps_every_page_of_the_manual():
    text = (ROOT / "README.md").read_text()
    assert [p for p in nav_pages() if p != "index.md" and f"(docs/{p}" not in text] == []
