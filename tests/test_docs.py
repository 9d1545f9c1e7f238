"""The documentation site builds without a warning, its executed pages run, and the README stays a front door.

A fenced code block right after a `<!-- docs-test -->` line is executed: a page's marked blocks run in order as one
script (Python or bash), in an empty folder, with this checkout's code. So the quickstart and the tutorials cannot
drift from the code. mkdocs is the `docs` extra, which `make test` installs: without it these tests fail, not skip.
"""

from __future__ import annotations

import html
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from quick_compile import QUICK_SUBPROCESS

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
MARKED = re.compile(r"<!-- docs-test -->\n```(?P<language>\w+)\n(?P<code>.*?)\n```", re.DOTALL)
# Text of a page's executed blocks replaced for the test only, to keep it quick: a quickstart that trains CartPole
# to 500 takes a minute, two cycles check the same commands. Each original must be on its page (asserted).
SHRINK = {
    "quickstart.md": [("angora-jax train cartpole logging.run_name=quickstart",
                       "angora-jax train cartpole logging.run_name=quickstart ppo.num_cycles=2")],
    "training.md": [('aj.load_config("cartpole", ["ppo.num_cycles=30"])',
                     'aj.load_config("cartpole", ["ppo.num_cycles=2"])')],
}
EXECUTED_PAGES = ["quickstart.md", "training.md", "tutorials/custom-task.md", "tutorials/custom-model.md"]
# The site's pages: docs/, the changelog it includes, and the study notes that docs/tools/results_hook.py publishes
# from benchmarks/results.
PAGE_SOURCES = [*sorted(DOCS.rglob("*.md")), ROOT / "CHANGELOG.md",
                *sorted((ROOT / "benchmarks" / "results").rglob("*.md"))]
LIST_ITEM = re.compile(r"^\s*(?:[-*+]|\d+\.)\s")
FENCE = re.compile(r"^\s*(?:```|~~~)")
# A page's text in the built site, and within it the paragraphs.
ARTICLE = re.compile(r"<article\b[^>]*>(?P<body>.*?)</article>", re.DOTALL)
PARAGRAPH = re.compile(r"<p\b[^>]*>(?P<text>.*?)</p>", re.DOTALL)
TAG = re.compile(r"<[^>]+>")
MIN_PAGE_LINES = 20


def marked_blocks(page: str) -> tuple[str, str]:
    """(language, script): the page's marked blocks joined, with the test's SHRINK replacements made."""
    text = (DOCS / page).read_text()
    blocks = [(m["language"], m["code"]) for m in MARKED.finditer(text)]
    assert blocks, f"{page} has no <!-- docs-test --> block"
    languages = {language for language, _ in blocks}
    assert len(languages) == 1 and languages <= {"python", "bash"}, f"{page} mixes or misnames languages: {languages}"
    script = "\n\n".join(code for _, code in blocks)
    for original, shrunk in SHRINK.get(page, []):
        assert original in script, f"{page} no longer has {original!r}: update SHRINK in tests/test_docs.py"
        script = script.replace(original, shrunk)
    return languages.pop(), script


def code_env() -> dict[str, str]:
    """This checkout's code first, and the interpreter's scripts (`angora-jax`) on the PATH. The pages train a cycle
    or two, so XLA compiles quickly (`QUICK_SUBPROCESS`)."""
    env = dict(os.environ) | QUICK_SUBPROCESS
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env["PATH"]])
    return env


@pytest.mark.parametrize("page", EXECUTED_PAGES)
def test_executed_pages_parse(page):
    """The fast tier's check of the executed pages (`make test-fast` leaves out running them): their blocks parse."""
    language, script = marked_blocks(page)
    if language == "python":
        compile(script, page, "exec")
    else:
        done = subprocess.run(["bash", "-n", "-c", script], capture_output=True, text=True)
        assert done.returncode == 0, f"{page}'s blocks are not valid bash: {done.stderr}"


@pytest.mark.slow
@pytest.mark.parametrize("page", EXECUTED_PAGES)
def test_executed_pages_run(page, tmp_path):
    language, script = marked_blocks(page)
    command = [sys.executable, "-c", script] if language == "python" else ["bash", "-euo", "pipefail", "-c", script]
    done = subprocess.run(command, cwd=tmp_path, env=code_env(), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"{page}'s blocks failed:\n{done.stdout[-3000:]}\n{done.stderr[-5000:]}"


@pytest.mark.slow
def test_site_builds_strictly(tmp_path):
    """`mkdocs build --strict`: every page in the nav, every link and anchor resolves, the API reference renders from
    the docstrings, every result a page cites exists."""
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, env=code_env(), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"mkdocs build --strict failed:\n{done.stdout[-3000:]}\n{done.stderr[-5000:]}"
    assert built_site_problems(tmp_path / "site") == []


def built_site_problems(site: Path) -> list[str]:
    """What renders wrong on the built site's pages, one line each: a literal `\\|` (a table cell's escaped bar
    shown as typed), a list whose items run on inside a paragraph, a page with fewer than MIN_PAGE_LINES lines of
    text (a stub)."""
    problems = []
    for page in sorted(site.rglob("index.html")):
        found = ARTICLE.search(page.read_text())
        if found is None:  # the theme's own pages (search) have no article
            continue
        name, body = page.parent.relative_to(site).as_posix() or "home", found["body"]
        text = html.unescape(TAG.sub("", body))
        if "\\|" in text:
            problems.append(f"{name}: a literal \\| {text.count(chr(92) + '|')} times")
        paragraphs = [html.unescape(TAG.sub("", p["text"])) for p in PARAGRAPH.finditer(body)]
        run_on = [text for text in paragraphs if run_on_list(text.splitlines()) is not None]
        if run_on:
            problems.append(f"{name}: list items run on in {len(run_on)} paragraphs, e.g. {run_on[0][:120]!r}")
        lines = [line for line in text.splitlines() if line.strip()]
        if len(lines) < MIN_PAGE_LINES:
            problems.append(f"{name}: {len(lines)} lines of text")
    return problems


def run_on_list(lines: list[str]) -> int | None:
    """The index of the line of one paragraph's `lines` where a list runs on as the paragraph's text (Markdown needs
    a blank line before a list): a line that starts like a list item after a line ending with a colon, or the first
    of two or more such lines. One such line alone is a wrapped formula's minus (`a\\n- b`), which reads right."""
    items = [i for i, line in enumerate(lines) if i and LIST_ITEM.match(line)]
    after_colon = [i for i in items if lines[i - 1].rstrip().endswith(":")]
    return after_colon[0] if after_colon else items[0] if len(items) > 1 else None


def unseparated_lists(markdown: str) -> list[int]:
    """Line numbers (from 1) where a list runs on inside a paragraph of `markdown` (`run_on_list`). Code blocks,
    headings, tables, HTML, admonitions, lists and indented blocks are not paragraphs."""
    found, paragraphs, fenced = [], [[]], False
    for number, line in enumerate(markdown.splitlines(), 1):
        if FENCE.match(line):
            fenced = not fenced
            paragraphs.append([])
        elif fenced or not line.strip() or line.startswith("#"):
            paragraphs.append([])
        else:
            paragraphs[-1].append((number, line))
    for paragraph in paragraphs:
        lines = [line for _, line in paragraph]
        if lines and not lines[0].startswith(("|", "<", "!!!", "???", " ", "\t")) and not LIST_ITEM.match(lines[0]):
            index = run_on_list(lines)
            found += [paragraph[index][0]] if index is not None else []
    return found


def test_lists_follow_a_blank_line():
    """The fast tier's counterpart of the built-site check for lists: no list item directly after a paragraph's
    line in the site's Markdown (pages, and study notes published from benchmarks/results)."""
    assert unseparated_lists("Text:\n- a\n- b\n\nText:\n\n- a\n\n```\nx\n- y\n```\n- a\n  b\n- c\n") == [2]
    assert unseparated_lists("Text.\n- a\n- b\n\nr = a\n- b\n\n- a\n- b\n") == [2]
    found = {path.relative_to(ROOT).as_posix(): unseparated_lists(path.read_text()) for path in PAGE_SOURCES}
    assert {path: lines for path, lines in found.items() if lines} == {}


def test_page_links_resolve_as_files():
    """Every relative link of the site's Markdown names a file or folder of the checkout from where the page is, so
    the pages also read right as files (on GitHub, in an editor), not only on the built site: a page links a result
    as `../benchmarks/results/...`, which docs/tools/results_hook.py points at the site's `results/` copy."""
    link = re.compile(r"\]\((?P<target>[^)\s#]+)(?:#[^)\s]*)?\)")
    code = re.compile(r"```.*?```|`[^`\n]*`", re.DOTALL)
    broken = [f"{path.relative_to(ROOT).as_posix()}: {match['target']}"
              for path in PAGE_SOURCES for match in link.finditer(code.sub("", path.read_text()))
              if not re.match(r"[a-z]+:|/", match["target"]) and not (path.parent / match["target"]).exists()]
    assert broken == []


def test_model_diagrams_draw_their_graphs():
    """The Models page's diagrams are SVGs drawn once from the shipped graphs (docs/tools/model_diagrams.py) and
    committed: each still draws its graph's edges, all and only those, so a changed graph fails here until they are
    drawn again."""
    spec = importlib.util.spec_from_file_location("model_diagrams", DOCS / "tools" / "model_diagrams.py")
    diagrams = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(diagrams)
    for name, graph in diagrams.GRAPHS.items():
        svg = (diagrams.OUTPUT / f"{name}.svg").read_text()
        titles = re.findall(r'class="edge">\s*<title>(.*?)</title>', svg)  # Graphviz titles an edge "A->B"
        drawn = {tuple(html.unescape(title).split("->")) for title in titles}
        assert drawn == diagrams.edges(graph()), f"docs/assets/models/{name}.svg: run docs/tools/model_diagrams.py"


def test_home_page_shows_the_readmes_headline_results():
    """The site's home page and the README show the same headline table (each links benchmarks/results from where it
    is; docs/tools/results_hook.py points the site's links at its copy under results/), and the same animation."""

    def headline(text: str) -> str:
        return text.split("## Headline results", 1)[1].split("\n\n", 2)[1]

    readme, home = (ROOT / "README.md").read_text(), (DOCS / "index.md").read_text()
    assert headline(home) == headline(readme).replace("](benchmarks/results/", "](../benchmarks/results/")
    assert "](docs/assets/cube.gif)" in readme and "](assets/cube.gif)" in home


def test_readme_is_a_front_door_whose_links_resolve():
    """At most 150 lines, opening with the two set-up commands, and every page and result it links to exists (the
    cube animation it shows is rendered from a trained GPU run and committed apart, so pictures are not checked)."""
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 150
    assert readme.splitlines()[3].startswith("make run") and readme.splitlines()[4].startswith("make test")
    links = re.findall(r"\]\(((?:docs|benchmarks)/[^)#]+\.(?:md|json))[)#]", readme)
    assert len(links) > 10, links
    assert [link for link in links if not (ROOT / link).is_file()] == []
