"""Reports from real short runs: PNG learning curves and an HTML page that lists and filters runs (checked in
headless Chromium when installed)."""

import re
import shutil
import subprocess
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import yaml
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.cli import main
from angora_jax.experiment import read_metrics
from angora_jax.experiment.live_report import LiveReport
from angora_jax.experiment.report import RunRecord, group_band, load_run, seed_groups

# Every run here is a few cycles of a tiny CartPole, module fixtures included (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")

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


def test_a_file_where_the_report_goes_is_a_warning_after_training_and_a_named_refusal_of_report(runs, tmp_path, capsys):
    """The run trained and saved, then ended in exit 2 saying "choose another path (logging.run_root, --out)"."""
    run = tmp_path / "run"
    shutil.copytree(runs[0].run_dir, run)
    shutil.rmtree(run / "report")
    (run / "report").write_text("notes")
    assert aj.resume(run, num_cycles=4).finished
    err = capsys.readouterr().err
    assert f"Warning: the run's report was not written ({run / 'report'} is a file, where the report's folder goes" \
        in err and f"`angora-jax report {run}` draws it" in err, err
    assert main(["report", str(run)]) == 2 and (run / "report").read_text() == "notes"
    assert "is a file, where the report's folder goes: move it away, or give another --out" in capsys.readouterr().err


def test_a_folder_with_a_page_of_its_own_is_refused_not_written_over(runs, tmp_path, capsys):
    """`report RUN --out site` into a folder holding the user's own index.html (a lab's site, the Desktop) wrote the
    report's page over it, and its PNGs beside it, with exit 0; refused now, nothing written. A report's own folder is
    regenerated as before."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "index.html").write_text("<html><title>My lab</title></html>")
    assert main(["report", str(runs[0].run_dir), "--out", str(site)]) == 2
    err = capsys.readouterr().err
    assert f"{site / 'index.html'} is a page of your own, not a report of runs" in err and "give another --out" in err
    assert list(site.iterdir()) == [site / "index.html"] and "My lab" in (site / "index.html").read_text()
    for _ in range(2):
        assert main(["report", str(runs[0].run_dir), "--out", str(tmp_path / "report")]) == 0


def test_a_report_into_a_run_directory_itself_is_refused_naming_its_report_folder(runs, tmp_path, capsys):
    """`report RUN --out RUN` wrote index.html and a dozen PNGs among the run's config.yaml, metrics.jsonl and
    checkpoints, with exit 0."""
    run = tmp_path / "run"
    shutil.copytree(runs[0].run_dir, run)
    before = sorted(path.name for path in run.iterdir())
    assert main(["report", str(run), "--out", str(run)]) == 2
    err = capsys.readouterr().err
    assert f"--out {run} is a run directory itself" in err and f"({run / 'report'}, where" in err, err
    assert sorted(path.name for path in run.iterdir()) == before


def test_a_report_into_a_runs_checkpoint_folder_is_refused_naming_it(runs, tmp_path, capsys):
    """`report RUN --out RUN/checkpoints/latest/3` (and monitor's) wrote its page and PNGs into the checkpoint, which
    training deletes with them when a later one replaces it; refused now, as every other --out there, before anything
    is written."""
    run = tmp_path / "run"
    shutil.copytree(runs[0].run_dir, run)
    before = sorted(run.rglob("*"))
    for argv in (["report", str(run), "--out", str(run / "checkpoints" / "latest" / "3")],
                 ["report", str(runs[1].run_dir), "--out", str(run / "checkpoints" / "report")],
                 ["monitor", str(run), "--no-serve", "--out", str(run / "checkpoints")]):
        assert main(argv) == 2, argv
        assert f"the checkpoint folder of the run {run}, which only training writes" in capsys.readouterr().err
    assert sorted(run.rglob("*")) == before


def test_a_folder_holding_a_file_named_like_a_curve_is_refused_and_a_report_cut_short_is_drawn_again(
        runs, tmp_path, capsys, monkeypatch):
    """`report RUN --out figures` into a folder of the user's holding an episode_return.png (and no index.html) wrote
    the curve over it with exit 0; refused now, nothing written. A report cut short while drawing its curves keeps its
    page, so the next report into that folder draws them again."""
    import angora_jax.experiment.report as report

    figures = tmp_path / "figures"
    figures.mkdir()
    (figures / "episode_return.png").write_bytes(b"mine")
    assert main(["report", str(runs[0].run_dir), "--out", str(figures)]) == 2
    err = capsys.readouterr().err
    assert f"{figures / 'episode_return.png'} is a file of your own" in err and "give another --out" in err, err
    assert list(figures.iterdir()) == [figures / "episode_return.png"]
    assert (figures / "episode_return.png").read_bytes() == b"mine"

    def cut_short(*args):
        raise OSError(28, "No space left on device")

    out = tmp_path / "report"
    monkeypatch.setattr(report, "plot_curve", cut_short)
    assert main(["report", str(runs[0].run_dir), "--out", str(out)]) == 2
    assert (out / "index.html").is_file() and not list(out.glob("*.png"))
    monkeypatch.undo()
    assert main(["report", str(runs[0].run_dir), "--out", str(out)]) == 0
    assert (out / "episode_return.png").read_bytes().startswith(b"\x89PNG")


@pytest.mark.parametrize("section, value, said", [("ppo", "oops", "ppo is 'oops'"), ("env", [1], "env is [1]"),
                                                  ("ppo.network", 3, "ppo.network is 3")])
def test_a_config_whose_section_is_no_mapping_is_named_as_damaged(section, value, said, runs, tmp_path, capsys):
    """A run's config.yaml edited into `ppo: oops` (or `env: [1]`) ended `report` in AttributeError: 'str' object has
    no attribute 'items' and exit 1; it is named as damaged now, with the fix (`check --restore-config`)."""
    run = tmp_path / "run"
    shutil.copytree(runs[0].run_dir, run)
    config = yaml.safe_load((run / "config.yaml").read_text())
    *sections, key = section.split(".")
    target = config
    for name in sections:
        target = target[name]
    target[key] = value
    (run / "config.yaml").write_text(yaml.safe_dump(config))
    assert main(["report", str(run), "--out", str(tmp_path / "report")]) == 2
    err = capsys.readouterr().err
    assert f"{run / 'config.yaml'} is damaged: {said}, not a mapping of settings" in err, err
    assert f"`angora-jax check {run} --restore-config`" in err and "Traceback" not in err


def test_a_metrics_line_edited_to_hold_text_is_skipped_as_damaged_not_a_traceback(runs, tmp_path, capsys):
    """A line of metrics.jsonl edited to hold text where a number goes (`"episode_return": "high"`) ended `report`
    in TypeError: must be real number, not str (exit 1), while `check` called the run intact. It is a damaged line
    now: the report skips it with a warning naming it, and `check` lists it."""
    from angora_jax.experiment.run_check import check_run

    run = tmp_path / "run"
    shutil.copytree(runs[0].run_dir, run)
    lines = len((run / "metrics.jsonl").read_text().splitlines())
    with (run / "metrics.jsonl").open("a") as log:
        log.write('{"cycle": 4, "env_steps": 999, "episode_return": "high"}\n')
    assert main(["report", str(run), "--out", str(tmp_path / "report")]) == 0
    assert f"line {lines + 1} is not a record of a cycle and is skipped" in capsys.readouterr().err
    assert any(f"metrics.jsonl line {lines + 1} holds no cycle's record" in problem
               for problem in check_run(run).problems)


@pytest.mark.parametrize("line", ['{"cycle": 4}', '{"cycle": 4, "episode_return": 9.0}'])
def test_a_metrics_line_without_its_env_steps_is_reported_without_a_traceback(line, runs, tmp_path, capsys):
    """A last line of metrics.jsonl cut down to `{"cycle": 4}` (or holding a curve's value but not env_steps) ended
    `report` (and `monitor`) in `KeyError: 'env_steps'`, alone and beside its seed's twin. The row has no place on the
    curves' env-steps axis and is left off them; the table counts its cycle and shows the env steps of the last row
    that has them."""
    copies = [tmp_path / run.run_dir.name for run in runs]
    for run, copy in zip(runs, copies, strict=True):
        shutil.copytree(run.run_dir, copy)
    steps = read_metrics(copies[0])[-1]["env_steps"]
    with (copies[0] / "metrics.jsonl").open("a") as log:
        log.write(line + "\n")
    for given in ([copies[0]], copies):  # one run's own curves; the two seeds' mean and band
        out = tmp_path / f"report{len(given)}"
        assert main(["report", *map(str, given), "--out", str(out)]) == 0
        assert "Traceback" not in capsys.readouterr().err
        cells = re.findall(r"<td>([^<]*)</td>", (out / "index.html").read_text())
        assert "4/3" in cells and f"{steps:,}" in cells, cells
        assert (out / "episode_return.png").is_file()


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
    assert "<td>0 (group of 2)</td>" in page and "<td>1 (group of 2)</td>" in page, "two seeds of one config"


def test_a_run_given_twice_is_drawn_once(runs, tmp_path, monkeypatch):
    """`report runs/a runs/a` (or `./runs/a`) listed the run twice and counted it as two seeds of one group."""
    monkeypatch.chdir(runs[0].run_dir.parent)
    assert main(["report", "seed0", "./seed0", str(runs[0].run_dir), "seed1", "--out", str(tmp_path)]) == 0
    page = (tmp_path / "index.html").read_text()
    assert page.count('<tr class="run"') == 2 and "<td>0 (group of 2)</td>" in page


def test_runs_that_differ_only_in_seed_are_one_group_drawn_as_mean_and_95_percent_band(tmp_path):
    def run(name, seed, learning_rate, returns):
        config = {"ppo": {"seed": seed, "learning_rate": learning_rate}, "logging": {"run_name": name}}
        rows = [{"env_steps": 10 * (i + 1), "episode_return": r} for i, r in enumerate(returns)]
        return RunRecord(name, tmp_path / name, config, rows)

    a, b = run("a", 0, 1e-3, [1.0, 3.0, 7.0]), run("b", 1, 1e-3, [3.0, 5.0, float("nan")])
    c, d = run("c", 0, 3e-4, [0.0]), run("d", 2, 1e-3, [2.0, 4.0])
    assert seed_groups([a, c, b, d]) == [[a, b, d], [c]]
    steps, mean, half = group_band([a, b], "episode_return")
    assert steps.tolist() == [10, 20], "a step that only one run recorded (NaN at 30 in b) has no band"
    assert mean.tolist() == [2.0, 4.0]
    np.testing.assert_allclose(half, [12.7062, 12.7062], rtol=1e-5)  # t(0.975, 1 dof) x sem([1, 3]) = 12.7062 x 1


def rendered(page: Path, fragment: str) -> str:
    return rendered_url(page.as_uri() + fragment)


def rendered_url(url: str) -> str:
    result = subprocess.run(
        [BROWSER, "--headless", "--no-sandbox", "--disable-gpu", "--dump-dom", url],
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


def test_a_finished_run_is_finished_and_an_idle_unfinished_one_stopped(runs):
    run = load_run(runs[0].run_dir)
    assert run.status() == "finished"
    unfinished = run.__class__(run.name, run.path, {**run.config, "ppo": {**run.config["ppo"], "num_cycles": 9}},
                               run.rows)
    assert unfinished.status(now=run.rows[-1]["time"] + 10) == "training"
    assert unfinished.status(now=run.rows[-1]["time"] + 3600) == "stopped"


def fetch(url: str) -> bytes:
    with urllib.request.urlopen(url, timeout=30) as response:
        return response.read()


@pytest.mark.slow
def test_monitor_serves_the_report_as_a_run_trains(runs, tmp_path):
    """A copy of a run that has done 1 of its 3 cycles, then the other two arrive while the page is served."""
    live_run = tmp_path / "live"
    shutil.copytree(runs[0].run_dir, live_run, ignore=shutil.ignore_patterns("report", "checkpoints"))
    lines = (live_run / "metrics.jsonl").read_text().splitlines(keepends=True)
    (live_run / "metrics.jsonl").write_text(lines[0])
    with LiveReport([live_run], tmp_path / "page", every=0.2, port=0) as live:
        page = fetch(live.url).decode()
        assert '<meta http-equiv="refresh" content="1">' in page and "<td>training</td>" in page and "1/3" in page
        (live_run / "metrics.jsonl").write_text("".join(lines))
        seen = live.updates
        deadline = time.monotonic() + 30
        while live.updates < seen + 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        page = fetch(live.url).decode()
        assert "<td>finished</td>" in page and "3/3" in page
        assert fetch(live.url.replace("index.html", "episode_return.png")).startswith(b"\x89PNG")  # curves beside it
        if BROWSER is not None:
            dom = rendered_url(live.url)
            assert '<span id="shown">1</span>' in dom and "<td>finished</td>" in dom
    with pytest.raises(OSError):  # stopped: the server no longer answers
        fetch(live.url)


def test_a_curve_with_no_value_to_draw_is_drawn_empty_without_a_matplotlib_warning(tmp_path):
    """A run whose curve has no finite value yet (a first cycle in which no episode ended, NaN) printed matplotlib's
    'No artists with labels found to put in legend' at the end of training: a legend is drawn only for lines."""
    import warnings

    from angora_jax.experiment.report import plot_curve
    run = RunRecord("a", tmp_path / "a", {}, [{"cycle": 1, "env_steps": 32, "episode_return": float("nan")}])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plot_curve([run], "episode_return", tmp_path / "episode_return.png")
    assert (tmp_path / "episode_return.png").stat().st_size > 0
