"""benchmarks/results/ is one folder per study, each with a README.md that names every file in it, and every result
that a page, script, test or module cites exists. Reads files only: well under a second."""

import fnmatch
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
# Where results are cited: the READMEs, the docs' pages and hooks, the benchmark scripts, tests, the package's code
# and configs, examples and the site's nav. The results' own notes name their siblings by bare name and are not here.
CITING = ("README.md", "mkdocs.yml", "docs/**/*.md", "docs/**/*.py", "benchmarks/*.py", "benchmarks/README.md",
          "tests/*.py", "tests/README.md", "angora_jax/**/*.py", "angora_jax/**/*.yaml", "examples/*")
# `results/STUDY/NAME` (NAME may hold * and {a,b}) or `results/STUDY/`, after a path separator or not inside a word;
# a name followed by `<` is a pattern a script fills in (`<task>_<platform>.json`), not a file.
CITATION = re.compile(r"(?<![\w])results/(?P<path>[\w.\-*{},/]*)(?![\w<])")
MARKER = re.compile(r"<!--\s*result:\s*(?P<name>[\w.\-/]+)(?:\s+from\s+(?P<meta>[\w.\-/]+))?\s*-->")


def expand(pattern: str) -> list[str]:
    """`a_{b,c}_*.json` as the shell patterns `a_b_*.json` and `a_c_*.json`."""
    match = re.search(r"\{([^{}]*)\}", pattern)
    if not match:
        return [pattern]
    return [p for alt in match[1].split(",") for p in expand(pattern[:match.start()] + alt + pattern[match.end():])]


def resolves(cited: str, results: Path, files: list[str]) -> bool:
    """Whether a cited results path (a folder, a file or a pattern of files) names something under `results`, whose
    files are `files` (paths relative to it)."""
    cited = cited.rstrip(".,;:")
    if not cited or cited.endswith("/") or "." not in cited and "*" not in cited:
        return (results / cited).is_dir()
    return any(fnmatch.filter(files, pattern) for pattern in expand(cited))


def citations(text: str) -> list[str]:
    """The results paths a text cites, markers included."""
    found = [m["path"] for m in CITATION.finditer(text)]
    for marker in MARKER.finditer(text):
        found += [name for name in (marker["name"], marker["meta"]) if name]
    return found


def unresolved(root: Path, results: Path) -> list[str]:
    """`file: cited path` for every citation under `root` that names nothing under `results`."""
    missing = []
    files = [p.relative_to(results).as_posix() for p in results.rglob("*") if p.is_file()]
    for pattern in CITING:
        for path in sorted(root.glob(pattern)):
            if path.is_file() and path.resolve() != Path(__file__).resolve():
                missing += [f"{path.relative_to(root)}: {cited}"
                            for cited in citations(path.read_text(errors="replace"))
                            if not resolves(cited, results, files)]
    return missing


def misplaced(results: Path) -> list[str]:
    """Files that are not in a study folder whose README.md names them: a file directly in the folder by its name, a
    file of a run directory kept whole inside it (`<study>/<run folder>/...`, as `angora-jax report` and
    benchmarks/seed_statistics.py read runs) by a folder above it, `<run folder>/`."""
    problems = []
    for path in sorted(results.rglob("*")):
        if not path.is_file():
            continue
        parts = path.relative_to(results).parts
        readme = results / parts[0] / "README.md"
        names = [parts[-1]] if len(parts) == 2 else [f"{'/'.join(parts[1:k])}/" for k in range(2, len(parts))]
        if len(parts) < 2:
            problems.append(f"{path.relative_to(results)}: not in a study folder (benchmarks/results/<study>/<file>)")
        elif not readme.is_file():
            if f"{parts[0]}/: no README.md" not in problems:
                problems.append(f"{parts[0]}/: no README.md")
        elif path != readme and not any(name in readme.read_text() for name in names):
            problems.append(f"{path.relative_to(results)}: not named in {parts[0]}/README.md")
    return problems


def test_every_cited_result_exists():
    assert not unresolved(ROOT, RESULTS), "cited results that do not exist:\n" + "\n".join(unresolved(ROOT, RESULTS))


def test_every_result_is_in_a_study_folder_whose_readme_names_it():
    assert not misplaced(RESULTS), "\n".join(misplaced(RESULTS))


@pytest.fixture
def tree(tmp_path):
    """A copy in miniature: one study with its README, one page citing it."""
    (tmp_path / "results" / "study").mkdir(parents=True)
    (tmp_path / "results" / "study" / "a_gpu.json").write_text("{}")
    (tmp_path / "results" / "study" / "README.md").write_text("# study\n\n`a_gpu.json`: current\n")
    (tmp_path / "README.md").write_text("see `benchmarks/results/study/a_gpu.json` and results/study/a_{gpu,cpu}.*\n")
    return tmp_path


def test_the_checks_fail_on_a_missing_citation_and_a_loose_file(tree):
    assert not unresolved(tree, tree / "results") and not misplaced(tree / "results")
    (tree / "README.md").write_text("gone: benchmarks/results/study/b_gpu.json; no file: results/study/c_*.png.\n")
    assert unresolved(tree, tree / "results") == ["README.md: study/b_gpu.json", "README.md: study/c_*.png."]
    (tree / "results" / "loose.json").write_text("{}")
    (tree / "results" / "study" / "unnamed.png").write_bytes(b"")
    for run in ("run_a", "run_b"):
        (tree / "results" / "study" / run / "evaluation").mkdir(parents=True)
        (tree / "results" / "study" / run / "evaluation" / "best.json").write_text("{}")
    (tree / "results" / "study" / "README.md").write_text("# study\n\n`a_gpu.json`, `run_a/`: current\n")
    assert misplaced(tree / "results") == ["loose.json: not in a study folder (benchmarks/results/<study>/<file>)",
                                           "study/run_b/evaluation/best.json: not named in study/README.md",
                                           "study/unnamed.png: not named in study/README.md"]
