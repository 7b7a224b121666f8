"""The README and docs/ link only what the repository holds, and name no private folders."""

import os
import re

import pytest

from helpers import ROOT

DOCS = ["README.md"] + [
    os.path.join("docs", name)
    for name in sorted(os.listdir(os.path.join(ROOT, "docs")))
    if name.endswith(".md")
]
LINK = re.compile(r"\]\(([^)\s]+)\)")


@pytest.mark.parametrize("name", DOCS)
def test_links_resolve_inside_the_repository(name):
    path = os.path.join(ROOT, name)
    with open(path, encoding="utf-8") as f:
        text = f.read()
    assert "../shared" not in text, f"{name} names a folder outside the repository"
    for target in LINK.findall(text):
        if re.match(r"[a-z]+://", target):
            continue  # a web page, not a file
        file_part = target.split("#", 1)[0]
        if not file_part:
            continue
        resolved = os.path.normpath(os.path.join(os.path.dirname(path), file_part))
        assert resolved.startswith(ROOT + os.sep), f"{name}: {target} leaves the repository"
        assert os.path.exists(resolved), f"{name}: {target} does not exist"
        if "#" in target and resolved.endswith(".md"):
            anchor = target.split("#", 1)[1]
            assert anchor in anchors(resolved), f"{name}: {target}: no such heading"


def anchors(path):
    """GitHub's anchors of a Markdown file's headings (lower case, punctuation dropped)."""
    with open(path, encoding="utf-8") as f:
        headings = re.findall(r"^#+ (.+)$", f.read(), flags=re.M)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in headings}


def test_readme_is_short_and_points_to_the_docs():
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as f:
        text = f.read()
    assert len(text.splitlines()) <= 220
    for name in DOCS[1:]:
        assert f"({name})" in text, f"the README does not link {name}"


def test_the_material_point_snippet_runs():
    """docs/laws.md's MaterialPoint snippet, as printed: confined, then sheared under p."""
    with open(os.path.join(ROOT, "docs", "laws.md"), encoding="utf-8") as f:
        section = f.read().split("## One material point", 1)[1].split("\n## ", 1)[0]
    (code,) = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    namespace = {}
    exec(compile(code, "docs/laws.md", "exec"), namespace)
    point = namespace["point"]
    assert point.F[0, 1] == 0.01 and point.F[1, 1] < 1.0  # sheared, compressed
    assert abs(point.last.sigma[1, 1] + 1e5) <= 1e-10 * 1e5
