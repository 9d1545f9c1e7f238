"""CITATION.cff: valid Citation File Format 1.2.0 keys, the package's version and license as pyproject.toml states
them, and AngoraPy's paper among its references, as its message asks users to cite it too."""

import tomllib
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


def test_the_citation_file_names_this_version_and_angorapys_paper():
    citation = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert citation["cff-version"] == "1.2.0" and {"message", "title", "authors"} <= set(citation)
    assert (citation["version"], citation["license"]) == (project["version"], project["license"])
    (angorapy,) = [ref for ref in citation["references"] if ref["title"].startswith("AngoraPy")]
    assert angorapy["doi"] == "10.3389/fninf.2023.1223687" and angorapy["year"] == 2023
    assert [author["family-names"] for author in angorapy["authors"]] == ["Weidler", "Goebel", "Senden"]
    assert "AngoraPy" in citation["message"]
