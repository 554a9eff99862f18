"""The README and the docs site hold together: every relative link of README.md resolves
(the site's home page is README.md: mkdocs.yml), the numbers it shows are the model's, and
the API reference covers ``testbed``."""

from __future__ import annotations

import re
from pathlib import Path

import testbed

ROOT = Path(__file__).resolve().parents[2]
# [text](target) and ![alt](target), outside code; a target may end in #anchor.
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def _prose(markdown: str) -> str:
    """The markdown without its fenced code blocks and inline code."""
    return re.sub(r"`[^`\n]*`", "", re.sub(r"^```.*?^```", "", markdown, flags=re.S | re.M))


def _anchors(markdown: str) -> set[str]:
    """The ids a heading gets (Python-Markdown's toc slugs, as mkdocs makes them)."""
    headings = re.findall(r"^#{1,6} (.+)$", _prose(markdown), re.M)
    return {re.sub(r"[\s]+", "-", re.sub(r"[^\w\s-]", "", h).strip().lower()) for h in headings}


def broken_links(markdown: str, base: Path) -> list[str]:
    """Every relative link or image of ``markdown`` (a file in ``base``) that names no file
    or no heading."""
    broken = []
    for target in LINK.findall(_prose(markdown)):
        if re.match(r"[a-z]+:", target):
            continue  # an absolute URL
        path, _, anchor = target.partition("#")
        page = (base / path) if path else None
        if page is not None and not page.exists():
            broken.append(f"{target}: no file {page.relative_to(ROOT)}")
        elif anchor and (page is None or page.suffix == ".md"):
            text = page.read_text() if page is not None else markdown
            if anchor not in _anchors(text):
                broken.append(f"{target}: no heading #{anchor}")
    return broken


def test_every_relative_link_of_the_readme_resolves() -> None:
    readme = (ROOT / "README.md").read_text()
    assert len(LINK.findall(_prose(readme))) > 10  # the check sees the links
    assert broken_links(readme, ROOT) == []


def test_a_broken_link_is_found() -> None:
    markdown = "# Top\n[a](docs/model.md) [b](docs/nope.md) [c](#top) [d](#gone) `[e](x.md)`\n"
    assert broken_links(markdown, ROOT) == [
        "docs/nope.md: no file docs/nope.md",
        "#gone: no heading #gone",
    ]


def test_the_readme_shows_its_headline_figure() -> None:
    readme = (ROOT / "README.md").read_text()
    images = re.findall(r"!\[[^\]]+\]\(([^)]+)\)", readme)
    assert images and (ROOT / images[0]).stat().st_size > 10_000


def test_the_api_reference_documents_every_name_of_testbed() -> None:
    reference = (ROOT / "docs" / "reference.md").read_text()
    headings = re.findall(r"^## `testbed\.(\w+)`\n\n::: [\w.]+$", reference, re.M)
    assert sorted(headings) == sorted(testbed.__all__)


def test_the_readme_shows_the_numbers_the_model_gives() -> None:
    """The expected output of `formation simulate paper --strategy all` in README.md: each
    strategy's final formation error, as the table prints it (3 significant digits)."""
    readme = (ROOT / "README.md").read_text()
    rows = dict(re.findall(r"^│ (\w+) +│ +1 │ +50 │ +([\d.e-]+) │", readme, re.M))
    assert sorted(rows) == sorted(["zero", "hold", "estimate", "blend", "drop"])
    scenario = testbed.load_scenario(ROOT / "scenarios" / "paper.toml")
    for strategy, shown in rows.items():
        final = testbed.simulate(scenario, strategy=strategy, seed=1).summary()
        assert f"{final['final_formation_error_m']:.3g}" == shown, strategy
