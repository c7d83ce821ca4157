"""Relative links in the Markdown docs point at files that exist and at headings that exist there.

Headings become anchors as GitHub makes them: lower case, punctuation other than ``-`` and ``_``
dropped, spaces turned into ``-``, and ``-1``, ``-2`` … appended to repeated ones. Code blocks
are not headings.
"""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", ROOT / "CHANGELOG.md", ROOT / "data" / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def anchors(markdown: str) -> set[str]:
    """GitHub's anchors of the headings of ``markdown``."""
    text = re.sub(r"```.*?```", "", markdown, flags=re.S)
    seen: dict[str, int] = {}
    out = set()
    for m in re.finditer(r"^#{1,6}\s+(.*?)\s*$", text, flags=re.M):
        title = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", m.group(1).replace("`", ""))
        slug = re.sub(r"[^\w\- ]", "", title.lower()).replace(" ", "-")
        n = seen.get(slug)
        seen[slug] = 0 if n is None else n + 1
        out.add(slug if n is None else f"{slug}-{n + 1}")
    return out


def test_anchor_rules_on_known_headings():
    md = "# A day at a 2 % median\n```\n# not a heading\n```\n## Peer: LESS 3\n## Peer: LESS 3\n"
    assert anchors(md) == {"a-day-at-a-2--median", "peer-less-3", "peer-less-3-1"}


@pytest.mark.parametrize("doc", [d for d in DOCS if d.exists()], ids=lambda d: str(d.relative_to(ROOT)))
def test_relative_links_resolve(doc):
    text = doc.read_text()
    broken = []
    for m in LINK.finditer(re.sub(r"```.*?```", "", text, flags=re.S)):
        link = m.group(1)
        if re.match(r"[a-z]+:", link):  # https:, mailto: …
            continue
        path, _, anchor = link.partition("#")
        target = (doc.parent / path).resolve() if path else doc
        if not target.exists():
            broken.append(f"{link}: no file {target}")
        elif anchor and target.suffix == ".md" and anchor not in anchors(target.read_text()):
            broken.append(f"{link}: no heading with anchor #{anchor}")
    assert not broken, broken
