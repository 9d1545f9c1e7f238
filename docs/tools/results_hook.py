"""MkDocs hook: the site shows `benchmarks/results/` as `results/`, and a page cites a result with a marker.

Pages link to results by their place in the repository (`../benchmarks/results/<study>/<file>` from docs/), so the
links also work where the Markdown is read as files (on GitHub, in an editor); the hook points each such link at the
published copy under `results/`.

Results sit in one folder per study (`benchmarks/results/<study>/`, each with a README.md that says which files are
current). `<!-- result: <study>/<name> -->` (a file in benchmarks/results) becomes, for a picture, the picture and a
caption; for any other file, a source line. Both say where the numbers were measured, read from the result itself
(device, package versions, date) or from `<!-- result: <study>/<name>.png from <study>/<other>.json -->`: the caption is
never typed by hand, so it cannot drift from the file, and a result that does not record its device, versions or
date says so. A marker naming a missing file stops the build.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

RESULTS = Path(__file__).resolve().parents[2] / "benchmarks" / "results"
SITE_FOLDER = "results"
MARKER = re.compile(r"<!--\s*result:\s*(?P<name>[\w.\-/]+)(?:\s+from\s+(?P<meta>[\w.\-/]+))?\s*-->")
# An inline Markdown link's relative target, and its anchor.
LINK = re.compile(r"\]\((?P<target>(?:\.\./)+benchmarks/results/[^)\s#]*)(?P<anchor>#[^)\s]*)?\)")
# The packages whose versions decide the numbers; others a result records are on its file.
KEY_PACKAGES = ("jax", "mujoco", "mujoco-mjx", "warp-lang", "brax")


def on_files(files: Files, config: Any) -> Files:
    """Publish every file of benchmarks/results under results/ (study folders kept), so pages link to the evidence
    itself; a study's README.md becomes that folder's page."""
    for path in sorted(RESULTS.rglob("*")):
        if path.is_file():
            site_path = f"{SITE_FOLDER}/{path.relative_to(RESULTS).as_posix()}"
            files.append(File.generated(config, site_path, abs_src_path=str(path)))
    return files


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files) -> str:
    depth = page.file.src_uri.count("/")
    prefix = "../" * depth + SITE_FOLDER
    markdown = LINK.sub(lambda match: published(match, page.file.abs_src_path, prefix), markdown)
    return MARKER.sub(lambda match: cite(match["name"], match["meta"], prefix), markdown)


def published(link: re.Match, source: str | None, prefix: str) -> str:
    """A link from a page to a file of benchmarks/results, pointed at its copy under results/; a link that does not
    land in benchmarks/results from the page's own file is left as written (the strict build then reports it)."""
    if source is None:
        return link[0]
    target = (Path(source).parent / link["target"]).resolve()
    if not target.is_relative_to(RESULTS):
        return link[0]
    return f"]({prefix}/{target.relative_to(RESULTS).as_posix()}{link['anchor'] or ''})"


def cite(name: str, meta: str | None, prefix: str) -> str:
    """The Markdown for one marker: picture and caption, or a source line."""
    if not (RESULTS / name).is_file():
        raise FileNotFoundError(f"<!-- result: {name} --> names no file in {RESULTS}")
    meta = meta or (Path(name).with_suffix(".json").as_posix() if Path(name).suffix != ".json" else name)
    facts = provenance(RESULTS / meta) if (RESULTS / meta).is_file() else "no device, versions or date recorded"
    source = f"[`{meta}`]({prefix}/{meta})" if (RESULTS / meta).is_file() else f"[`{name}`]({prefix}/{name})"
    line = f"<small>Measured: {facts}. Source: {source}.</small>"
    if Path(name).suffix.lower() in (".png", ".jpg", ".gif"):
        return f"![{Path(name).stem}]({prefix}/{name})\n\n{line}\n"
    return line


def provenance(path: Path) -> str:
    """Device, key package versions and date that a result file records, each or that it does not."""
    if path.suffix != ".json":
        return "device, versions and date not recorded apart from what the file itself says"
    data = json.loads(path.read_text())
    if not isinstance(data, dict):
        return "no device, versions or date recorded"
    # Evaluations record where they ran only in their `physics` line ("... on NVIDIA H100 80GB HBM3").
    device = describe_device(data.get("device") or data.get("training_device") or data.get("physics"))
    versions = data.get("versions")
    if isinstance(versions, dict):
        named = [f"{package} {versions[package]}" for package in KEY_PACKAGES if versions.get(package)]
        versions = ", ".join(named) or "versions not recorded"
    else:
        versions = f"jax {data['jax']} (other versions not recorded)" if data.get("jax") else "versions not recorded"
    date = str(data["date"])[:10] if data.get("date") else "date not recorded"
    return f"{device}; {versions}; {date}"


def describe_device(device: Any) -> str:
    """A result's device in words, whichever of the shapes the scripts have written it in."""
    if not device:
        return "device not recorded"
    if isinstance(device, str):
        return device
    if isinstance(device, list):
        kinds = sorted({entry.get("kind", "?") for entry in device if isinstance(entry, dict)})
        return f"{len(device)} x {', '.join(kinds)}" if len(device) > 1 else ", ".join(kinds)
    kind, count = device.get("kind", "?"), device.get("count", 1)
    if isinstance(kind, list):
        return " and ".join(str(k) for k in kind)
    if device.get("platform") == "cpu":
        return f"CPU, {device.get('host_cpus', '?')} cores"
    # `count` is every device the process saw, not how many a one-device benchmark used.
    return f"{kind} ({count} on the machine)" if count and count > 1 else str(kind)
