"""The documentation's images: every ``![alt](path)`` of a docs page names a file that exists, and the
user guide shows the pictures of ``hd view``'s page and of ``hd eval``'s landing figure that
``docs/figures/guide_images.py`` regenerates (the script itself is too slow to run here)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parents[2] / "docs"
IMAGE = re.compile(r"!\[([^\]]*)\]\(([^)\s]+)\)")
GUIDE_IMAGES = ("figures/guide_detect_page.png", "figures/guide_landing.png")
MAX_BYTES = 300_000  # docs/figures/guide_images.py: MAX_BYTES


def image_links(text: str) -> list[tuple[str, str]]:
    """The (alt text, target) of every Markdown image in ``text``."""
    return [(m.group(1), m.group(2)) for m in IMAGE.finditer(text)]


def test_image_links_are_read_as_written() -> None:
    text = "a ![one](figures/a.png) b ![](b.png#x) and [a link](c.md), not an image"
    assert image_links(text) == [("one", "figures/a.png"), ("", "b.png#x")]


@pytest.mark.parametrize("page", sorted(p.name for p in DOCS.glob("*.md")))
def test_every_image_a_page_shows_exists(page: str) -> None:
    links = image_links((DOCS / page).read_text())
    missing = [target for _, target in links if not (DOCS / target.split("#")[0]).is_file()]
    assert not missing, f"docs/{page} shows images that do not exist: {missing}"


@pytest.mark.parametrize("target", GUIDE_IMAGES)
def test_the_user_guide_shows_the_regenerated_images(target: str) -> None:
    text = (DOCS / "user-guide.md").read_text()
    assert target in [t for _, t in image_links(text)], f"docs/user-guide.md does not show {target}"
    caption = text[text.index(f"]({target})") :].split("\n\n")[1]
    assert "python docs/figures/guide_images.py" in caption.replace("\n", " "), caption
    assert 0 < (DOCS / target).stat().st_size <= MAX_BYTES
    assert (DOCS / "figures" / "guide_images.py").is_file()
