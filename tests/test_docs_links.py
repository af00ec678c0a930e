"""The README and docs/ stay readable and true to the tree: the README's length, every relative link (and anchor)
resolves, and every repository path they name in backticks exists."""

from __future__ import annotations

import itertools
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
#: What a newcomer reads top-down (issue 41): the rest belongs in docs/.
README_MAX_CHARS = 10_000
#: ``[text](target)`` and ``![alt](target)``; the target ends at whitespace or ``)``.
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
#: A path in backticks that starts at the repository root or at a package of bop_cender.
PATH_ROOTS = ("bop_cender", "results", "scripts", "tests", "docs", ".ci", "bop_toolkit_adapters")
PACKAGES = ("cli", "data", "eval", "geometry", "net", "pose", "render", "report", "synth")
CODE_SPAN = re.compile(r"`([^`\s]+)`")


def prose(text: str) -> str:
    """``text`` without its fenced code blocks (commands and outputs, not links)."""
    return re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a markdown heading: lower case, punctuation dropped, spaces as hyphens."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    headings = re.findall(r"^#{1,6}\s+(.+?)\s*$", prose(path.read_text()), flags=re.M)
    return {github_anchor(h) for h in headings}


def expand_braces(pattern: str) -> list[str]:
    """``a{1,2}b`` -> ``[a1b, a2b]`` (shell brace expansion, as the docs write sets of files)."""
    parts = re.split(r"\{([^{}]*)\}", pattern)
    choices = [[p] if i % 2 == 0 else p.split(",") for i, p in enumerate(parts)]
    return ["".join(c) for c in itertools.product(*choices)]


def test_the_readme_is_short():
    size = len((ROOT / "README.md").read_text())
    assert size <= README_MAX_CHARS, (
        f"README.md is {size} characters (at most {README_MAX_CHARS}); move detail to docs/"
    )


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_resolves(doc: Path):
    broken = []
    for target in LINK.findall(prose(doc.read_text())):
        if re.match(r"^[a-z]+:", target):  # https:, mailto:
            continue
        file_part, _, anchor = target.partition("#")
        resolved = (doc.parent / file_part).resolve() if file_part else doc
        if not resolved.exists():
            broken.append(f"{target}: no such file")
        elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
            broken.append(f"{target}: no heading with anchor #{anchor} in {resolved.relative_to(ROOT)}")
    assert not broken, f"{doc.relative_to(ROOT)}:\n" + "\n".join(broken)


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_repository_path_named_exists(doc: Path):
    """A path in backticks (``bop_cender/meshes.py``, ``pose/...`` for a package of bop_cender, globs and ``{a,b}``
    allowed) names something in the tree: a module that moved must be renamed in the docs too."""
    missing = []
    for token in CODE_SPAN.findall(prose(doc.read_text())):
        token = token.split(":")[0].rstrip(".,;")
        first = token.split("/")[0]
        if "/" not in token or "<" in token or first not in PATH_ROOTS + PACKAGES:
            continue
        bases = [ROOT] if first in PATH_ROOTS else [ROOT / "bop_cender"]
        if first == "results":
            bases.append(ROOT / "bop_cender")  # results/ of the package or of the repository
        if not all(any(list(base.glob(p.rstrip("/"))) for base in bases) for p in expand_braces(token)):
            missing.append(token)
    assert not missing, f"{doc.relative_to(ROOT)} names paths that do not exist: {missing}"


def test_the_helpers_see_what_they_check():
    assert github_anchor("Synthetic datasets (`bop-cender synth`)") == "synthetic-datasets-bop-cender-synth"
    assert github_anchor("Stage 1: heatmaps") == "stage-1-heatmaps"
    assert expand_braces("v15/scores_{a,b}.json") == ["v15/scores_a.json", "v15/scores_b.json"]
    assert LINK.findall("see [x](docs/a.md#b) and ![i](img/f.png)") == ["docs/a.md#b", "img/f.png"]


#: A citation of a file outside the repository: the first design brief and the references beside the project's root.
OUTSIDE = re.compile(
    r"(?<![\w/])(?:design|rendering|datasets|bop_metrics)\.md|shared/(?!reference/bop_results_samples)"
)
#: Where citations live: code, tests, scripts, CI and the committed results.
CITING = ("bop_cender", "tests", "scripts", "bop_toolkit_adapters", ".ci", "results")


def test_code_tests_and_results_cite_only_files_in_the_repository():
    """What a reader cannot open is no reference: facts from outside live in docs/ (``shared/reference``'s sample
    results file is test data, read where it exists, not a citation)."""
    found = []
    for base in CITING:
        for path in sorted((ROOT / base).rglob("*")):
            if not path.is_file() or path.suffix not in ("", ".py", ".md", ".sh", ".txt") or path == Path(__file__):
                continue
            for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
                if OUTSIDE.search(line):
                    found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not found, "\n".join(found)
