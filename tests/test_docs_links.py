"""The documentation holds together: every relative link and image of README.md, docs/*.md
and the asset cards resolves, the pages are the documented set and stay short, the README
links every page, and CI runs the README's test command."""

import re

import pytest
import yaml
from conftest import load_script


@pytest.fixture(scope="module")
def check_links(repo_root):
    return load_script(repo_root / "scripts" / "check_links.py")


def test_every_relative_link_resolves(check_links):
    files = check_links.markdown_files()
    assert any(f.name == "README.md" for f in files) and len(files) > 1
    problems = [p for f in files for p in check_links.broken_links(f)]
    assert not problems, "\n".join(problems)


def test_the_checker_finds_a_missing_file_and_a_missing_heading(check_links, tmp_path):
    (tmp_path / "other.md").write_text("# A heading\n\n## `Code` and more, too\n")
    page = tmp_path / "page.md"
    page.write_text(
        "[ok](other.md) [ok](other.md#a-heading) [ok](other.md#code-and-more-too) [ok](#top)\n"
        "# Top\n"
        "![gone](missing.png) [gone](other.md#no-such-heading) `[code](ignored.md)`\n"
        "```\n[fenced](ignored.md)\n```\n"
    )
    problems = check_links.broken_links(page)
    assert len(problems) == 2, problems
    assert "missing.png" in problems[0] and "no-such-heading" in problems[1]


DOCS_PAGES = {
    "install",
    "environment",
    "model",
    "anatomy",
    "observations",
    "training",
    "imitation",
    "benchmarks",
    "cli",
    "architecture",
    "paper",
    "limitations",
    "glossary",
}
USER_DOCS_MAX_LINES = 2000  # README plus docs/*.md: about 2,000 with the README's common tasks


def test_the_docs_are_the_documented_pages_and_stay_short(repo_root):
    pages = sorted((repo_root / "docs").glob("*.md"))
    assert {page.stem for page in pages} == DOCS_PAGES
    lines = sum(len(page.read_text().splitlines()) for page in [repo_root / "README.md", *pages])
    assert lines <= USER_DOCS_MAX_LINES, f"{lines} lines of user docs"


def test_readme_is_short_and_links_every_docs_page(repo_root):
    readme = (repo_root / "README.md").read_text()
    assert len(readme.splitlines()) <= 150
    for page in sorted((repo_root / "docs").glob("*.md")):
        assert f"docs/{page.name}" in readme, f"README does not link {page.name}"


def test_every_page_and_figure_of_docs_is_reachable_from_the_readme(check_links, repo_root):
    reached = check_links.reachable(repo_root / "README.md")
    unreached = [
        path.name
        for path in sorted((repo_root / "docs").iterdir())
        if path.suffix in (".md", ".png") and path.resolve() not in reached
    ]
    assert not unreached, f"not reachable from README.md by links: {unreached}"


def test_reachability_follows_links_through_pages_and_misses_an_orphan(check_links, tmp_path):
    (tmp_path / "a.md").write_text("[b](b.md)\n")
    (tmp_path / "b.md").write_text("![figure](fig.png) [back](a.md)\n")
    for name in ("fig.png", "orphan.png"):
        (tmp_path / name).write_bytes(b"")
    (tmp_path / "orphan.md").write_text("![figure](orphan.png)\n")
    names = {path.name for path in check_links.reachable(tmp_path / "a.md")}
    assert names == {"a.md", "b.md", "fig.png"}


def test_ci_runs_the_readmes_test_command(repo_root):
    readme = (repo_root / "README.md").read_text()
    commands = re.findall(r"^(bash scripts/\S+)", readme, flags=re.M)
    assert "bash scripts/test.sh" in commands
    assert "bash scripts/test.sh" in (repo_root / ".ci" / "run").read_text()


def test_the_citation_files_name_this_version_and_the_cathsim_paper(repo_root):
    citation = yaml.safe_load((repo_root / "CITATION.cff").read_text())
    version = re.search(r'^version = "([^"]+)"', (repo_root / "pyproject.toml").read_text(), flags=re.M)[1]
    assert citation["cff-version"] == "1.2.0" and citation["version"] == version
    (paper,) = citation["references"]
    arxiv = paper["identifiers"][0]["value"].removeprefix("arXiv:")
    bibtex = (repo_root / "CITATION.bib").read_text()
    assert f"version = {{{version}}}" in bibtex and f"eprint        = {{{arxiv}}}" in bibtex
    assert paper["title"] in (repo_root / "docs" / "paper.md").read_text().replace("\n", " ")
