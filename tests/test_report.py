"""Reports from real short runs: PNG learning curves and an HTML page that lists and filters runs (checked in
headless Chromium when installed)."""

import re
import shutil
import subprocess
from pathlib import Path

import pytest
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.cli import main

TINY = [
    *TINY_PPO,
    "ppo.num_cycles=3",
    "logging.progress=none",
]
BROWSER = next((shutil.which(b) for b in ("chromium", "chromium-browser", "google-chrome") if shutil.which(b)), None)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two runs that differ in seed; each writes its own report when it ends (logging.report=true)."""
    root = tmp_path_factory.mktemp("runs")
    return [
        aj.train("cartpole", [*TINY, f"ppo.seed={seed}", f"logging.run_root={root}", f"logging.run_name=seed{seed}"])
        for seed in (0, 1)
    ]


def test_each_run_writes_its_report(runs):
    report = runs[0].run_dir / "report"
    assert (report / "index.html").exists()
    assert (report / "episode_return.png").read_bytes().startswith(b"\x89PNG\r\n\x1a\n")


@pytest.fixture(scope="module")
def comparison(runs, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    assert main(["report", *(str(r.run_dir) for r in runs), "--out", str(out)]) == 0
    return out


def test_report_compares_runs_in_pngs_and_html(runs, comparison):
    pngs = sorted(p.name for p in comparison.glob("*.png"))
    for name in ("episode_return.png", "episode_length.png", "entropy.png", "approx_kl.png", "value_loss.png"):
        assert name in pngs
    for png in pngs:
        assert (comparison / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and (comparison / png).stat().st_size > 5000
    page = (comparison / "index.html").read_text()
    assert page.count('<tr class="run"') == 2 and "seed0" in page and "seed1" in page
    assert page.count("<img ") == len(pngs)
    assert "minibatch_size: 32" in page  # each run's resolved config is on the page


def rendered(page: Path, fragment: str) -> str:
    result = subprocess.run(
        [BROWSER, "--headless", "--no-sandbox", "--disable-gpu", "--dump-dom", page.as_uri() + fragment],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    return result.stdout


@pytest.mark.skipif(BROWSER is None, reason="no headless browser: install Debian's chromium (.ci/run does)")
def test_html_report_filters_runs_in_a_browser(comparison):
    page = comparison / "index.html"
    dom = rendered(page, "#filter=seed1")
    rows = {
        name: attributes for attributes, name in re.findall(r'<tr class="run"([^>]*)>.*?<summary>([^<]+)<', dom, re.S)
    }
    assert "hidden" in rows["seed0"] and "hidden" not in rows["seed1"]
    assert '<span id="shown">1</span>' in dom
    images = len(re.findall(r"<img ", dom))
    assert f'data-images-loaded="{images}"' in dom  # every learning curve PNG loaded and decoded
    assert '<span id="shown">2</span>' in rendered(page, "")
