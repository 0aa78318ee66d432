"""Every relative link in the README and under docs/ points at a file or folder of the repository."""
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").rglob("*.md"))]
#: [text](target) and ![alt](target); the target ends at whitespace or the closing parenthesis
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def relative_links(page: Path) -> list[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)  # code blocks hold commands, not links
    return [t for t in LINK.findall(text) if not re.match(r"[a-z][a-z0-9+.-]*:", t) and not t.startswith("#")]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page):
    missing = [t for t in relative_links(page) if not (page.parent / t.split("#")[0]).exists()]
    assert not missing, f"{page.relative_to(ROOT)} links to missing files: {missing}"


def test_the_link_pattern_finds_links_and_skips_urls_and_anchors(tmp_path):
    page = tmp_path / "p.md"
    page.write_text("[a](x.md) ![b](img/y.png) [c](https://e.org) [d](#part) [e](z.json#k)\n```\n[f](no.md)\n```\n")
    assert relative_links(page) == ["x.md", "img/y.png", "z.json#k"]


def _linked_files() -> set[Path]:
    return {(page.parent / t.split("#")[0]).resolve() for page in PAGES for t in relative_links(page)}


def test_every_result_file_is_named_by_a_page():
    """A result nobody links is a result nobody reads: link it from its page, or delete it (git keeps it)."""
    linked = _linked_files()
    results = ROOT / "docs" / "results"
    unnamed = sorted(str(f.relative_to(ROOT)) for f in results.rglob("*")
                     if f.is_file() and f.name != "README.md" and f.resolve() not in linked)
    assert not unnamed, f"result files no page links: {unnamed}"


def test_results_pages_hold_no_machine_paths():
    machine = re.compile(r"(?<![\w.])/(?:work|tmp|home|root|Users)/")
    found = [f"{f.relative_to(ROOT)}:{i}" for f in sorted((ROOT / "docs").rglob("*")) if f.suffix in (".md", ".json")
             for i, line in enumerate(f.read_text().splitlines(), 1) if machine.search(line)]
    assert not found, f"absolute machine paths in {found[:20]}"


#: ``python -m benchmarks.speed.NAME`` / ``python -m benchmarks.learning.NAME`` and the diagnostics' commands
BENCHMARK = re.compile(r"python3? -m benchmarks\.([a-z]\w*)\.([a-z]\w*)")  # NAME: a placeholder
DIAGNOSTIC = re.compile(r"python3? -m torchrl_mpail2\.diagnostics ([a-z]\w*)")
OLD_SCRIPT = re.compile(r"python3? benchmarks/\w+\.py")


def test_documented_benchmark_and_diagnostic_commands_exist():
    """A command the docs give runs a module that exists (the CHANGELOG's older entries name the paths of their day)."""
    from torchrl_mpail2.diagnostics.__main__ import COMMANDS

    pages = [p for p in PAGES if p.name != "CHANGELOG.md"] + sorted((ROOT / "benchmarks").rglob("*.py")) + sorted(
        (ROOT / "torchrl_mpail2").rglob("*.py"))
    missing, old = [], []
    for page in pages:
        text = page.read_text()
        missing += [f"{page.relative_to(ROOT)}: benchmarks.{group}.{name}" for group, name in BENCHMARK.findall(text)
                    if not (ROOT / "benchmarks" / group / f"{name}.py").is_file()]
        missing += [f"{page.relative_to(ROOT)}: diagnostics {name}" for name in DIAGNOSTIC.findall(text)
                    if name not in COMMANDS]
        old += [f"{page.relative_to(ROOT)}: {m}" for m in OLD_SCRIPT.findall(text)]
    old = [o for o in old if "diary/" not in o]  # the frozen diary names scripts removed at a commit it names
    assert not missing, f"documented commands of modules that do not exist: {missing}"
    assert not old, f"scripts run by path (use python -m benchmarks.speed.NAME / benchmarks.learning.NAME): {old}"
