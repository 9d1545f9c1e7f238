"""Reports: PNG learning curves comparing runs and one static HTML page that lists the runs with their configs.

The page needs no server: open `index.html` from disk. It filters runs by any text of their name or config
(the filter box, or `index.html#filter=lstm` in the address). Each run's status (training, finished, stopped) is
read from its files; `angora-jax monitor` regenerates the page on a timer while runs train (`live_report`).
"""

from __future__ import annotations

import html
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
import scipy.stats

matplotlib.use("Agg")  # files only: no display needed
import matplotlib.pyplot as plt  # noqa: E402
import yaml  # noqa: E402

from angora_jax.experiment.monitor import read_metrics  # noqa: E402
from angora_jax.experiment.run_dir import (  # noqa: E402
    CONFIG_FILE,
    RunDirError,
    latest_video,
    not_a_run_dir,
    read_sessions,
    unwritable_out,
)
from angora_jax.whole_files import written_whole  # noqa: E402
from angora_jax.wording import counted

# Curves drawn when at least one run has them, in this order; task metrics (metric/*) follow the return.
CURVES = (
    "episode_return",
    "episode_length",
    "policy_loss",
    "value_loss",
    "entropy",
    "approx_kl",
    "clip_fraction",
    "explained_variance",
    "norm/reward_std",
    "steps_per_second",
)


@dataclass(frozen=True)
class RunRecord:
    """A run as the report sees it: its name (directory name), directory, resolved config and metric rows."""

    name: str
    path: Path
    config: dict[str, Any]
    rows: list[dict[str, Any]]

    def status(self, now: float | None = None) -> str:
        """"finished", "training" (a cycle or a session started recently: within three cycles' time, at least two
        minutes, so that a compile counts), or "stopped" (resume it to go on)."""
        total = self.config.get("ppo", {}).get("num_cycles")
        if self.rows and self.rows[-1]["cycle"] == total:
            return "finished"
        now = time.time() if now is None else now
        sessions = read_sessions(self.path)
        last = max([self.rows[-1].get("time", 0.0) if self.rows else 0.0, *(s["time"] for s in sessions)])
        seconds = [r["seconds"] for r in self.rows[-5:] if not math.isnan(r.get("seconds", math.nan))]
        patience = max(120.0, 3 * max(seconds, default=0.0))
        return "training" if now - last < patience else "stopped"


def load_run(run_dir: str | Path) -> RunRecord:
    """Read a run directory's config and metrics; RunDirError when it is not a run directory."""
    path = Path(run_dir)
    if not (path / CONFIG_FILE).is_file():
        raise RunDirError(not_a_run_dir(run_dir))
    try:
        config = yaml.safe_load((path / CONFIG_FILE).read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        raise RunDirError(f"{path / CONFIG_FILE} is damaged ({type(error).__name__}): `angora-jax check {run_dir} "
                          "--restore-config` writes it again from its checkpoints' copy, or leave the run out of the "
                          "report.") from None
    if not isinstance(config, dict):
        raise RunDirError(f"{path / CONFIG_FILE} holds no config (a {type(config).__name__}): `angora-jax check "
                          f"{run_dir} --restore-config` writes it again from its checkpoints' copy.")
    if (misshapen := _not_a_mapping(config)) is not None:
        raise RunDirError(f"{path / CONFIG_FILE} is damaged: {misshapen}, not a mapping of settings. `angora-jax "
                          f"check {run_dir} --restore-config` writes it again from its checkpoints' copy, or leave the "
                          "run out of the report.")
    return RunRecord(path.resolve().name, path, config, read_metrics(path))


def _not_a_mapping(config: dict[str, Any]) -> str | None:
    """The first section the report reads (env, ppo, ppo.network) that is not a mapping, as "ppo is 'oops'"; None
    when each is one or absent. A config.yaml edited into `ppo: 3` ended `report` and `monitor` in AttributeError."""
    for dotted in ("env", "ppo", "ppo.network"):
        value: Any = config
        for key in dotted.split("."):
            value = value.get(key, {})
        if not isinstance(value, dict):
            return f"{dotted} is {repr(value)[:60]}"
    return None


def curve_names(runs: list[RunRecord]) -> list[str]:
    """The metrics to plot: those of CURVES, every task metric and every held-out evaluation's (eval/...) that
    some run recorded."""
    present = {key for run in runs for row in run.rows for key in row}
    task = sorted(k for k in present if k.startswith(("metric/", "eval/")))
    ordered = [CURVES[0], *task, *CURVES[1:]]
    return [name for name in ordered if name in present]


def seed_groups(runs: list[RunRecord]) -> list[list[RunRecord]]:
    """The runs grouped by config, ignoring `ppo.seed` and `logging` (names, folders, display): runs that differ
    only in their seed share a group. Groups and their runs keep the order of `runs`."""
    groups: dict[str, list[RunRecord]] = {}
    for run in runs:
        config = {section: values for section, values in run.config.items() if section != "logging"}
        config["ppo"] = {key: value for key, value in config.get("ppo", {}).items() if key != "seed"}
        groups.setdefault(json.dumps(config, sort_keys=True), []).append(run)
    return list(groups.values())


def group_band(group: list[RunRecord], name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`(env_steps, mean, half_width)` of metric `name` over a group's seeds: at each env step that at least two
    runs recorded (NaN excluded), the mean and the half width of its 95% confidence interval (Student's t)."""
    values: dict[float, list[float]] = {}
    for run in group:
        for step, value in _points(run.rows, name):
            values.setdefault(step, []).append(value)
    steps = np.array(sorted(step for step, seen in values.items() if len(seen) >= 2))
    mean = np.array([np.mean(values[step]) for step in steps])
    half = np.array([scipy.stats.t.ppf(0.975, len(values[step]) - 1) * scipy.stats.sem(values[step])
                     for step in steps])
    return steps, mean, half


def _points(rows: list[dict[str, Any]], name: str) -> list[tuple[float, float]]:
    """(env steps, value) of metric `name` in each row that holds both, NaN left out. A row without env_steps (a line
    holding only its cycle, `{"cycle": 7}`) has no place on the curves' axis: it ended `report` in KeyError."""
    return [(r["env_steps"], r[name]) for r in rows if "env_steps" in r and name in r and not math.isnan(r[name])]


def plot_curve(runs: list[RunRecord], name: str, path: Path) -> None:
    """One PNG: metric `name` against env steps, one line per run; runs that differ only in `ppo.seed` are drawn as
    their mean with a 95% confidence band, labelled with the seed count."""
    fig, ax = plt.subplots(figsize=(6, 3.6))
    for group in seed_groups(runs):
        if len(group) > 1:
            steps, mean, half = group_band(group, name)
            if len(steps):
                line, = ax.plot(steps, mean, label=f"{group[0].name} and others: mean of {len(group)} seeds")
                ax.fill_between(steps, mean - half, mean + half, color=line.get_color(), alpha=0.25, linewidth=0)
            continue
        run = group[0]
        points = _points(run.rows, name)
        if points:
            ax.plot(*zip(*points, strict=True), marker="." if len(points) < 50 else None, label=run.name)
    ax.set_xlabel("env steps")
    ax.set_title(name)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:  # no line yet (NaN only): a legend of nothing is matplotlib's warning
        ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_report(run_dirs: list[str | Path], out_dir: str | Path, refresh_seconds: int | None = None) -> Path:
    """Write one PNG per metric (runs compared) and index.html into `out_dir`; return the HTML path.

    The report's own files in `out_dir` are regenerated; nothing else there is touched. An index.html that is not a
    report's (a site of your own given as `out_dir`), or without a report's index.html a file named as one of its
    PNGs, is refused (RunDirError) before anything is written.

    Args:
        run_dirs: the runs to compare; a run given twice (under any spelling of its path) is drawn once.
        out_dir: where the report is written.
        refresh_seconds: the page reloads itself this often (for a live view), None for a static page.
    """
    distinct: dict[Path, str | Path] = {}
    for run_dir in run_dirs:
        distinct.setdefault(Path(run_dir).resolve(), run_dir)
    runs = [load_run(d) for d in distinct.values()]
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise RunDirError(f"{out} is a file, where the report's folder goes: move it away, or give another --out")
    if (why := unwritable_out(out / "index.html")) is not None:
        raise RunDirError(f"--out {out}: {why}; give another --out.")
    if (out / CONFIG_FILE).is_file():  # its page and a PNG per curve would lie among the run's own files
        raise RunDirError(f"--out {out} is a run directory itself: a run's report goes in its report folder "
                          f"({out / 'report'}, where `angora-jax report {out}` writes it without --out); give that "
                          "or another folder.")
    page = out / "index.html"
    if page.is_file() and PAGE_TITLE not in page.read_text(errors="replace"):
        raise RunDirError(f"{page} is a page of your own, not a report of runs, and the report would write over it "
                          "(its index.html and one PNG per curve): give another --out, e.g. a new folder.")
    images = [(name, name.replace("/", "_") + ".png") for name in curve_names(runs)]
    if not page.is_file():  # no report's page: a file named like a curve here is the user's
        yours = [file for _, file in images if (out / file).exists()]
        if yours:
            raise RunDirError(f"{out / yours[0]} is a file of your own (the folder holds no report's index.html), and "
                              "the report would write over it (its index.html and one PNG per curve): give another "
                              "--out, e.g. a new folder; if it is left from a report cut short, delete it.")
    out.mkdir(parents=True, exist_ok=True)
    # Each run's latest video (evaluation.video), linked where it lies rather than copied: videos are large.
    videos = [(run.name, os.path.relpath(video, out)) for run in runs if (video := latest_video(run.path))]
    # The page first: a report cut short while drawing is then still known as a report's, and drawn again over.
    with written_whole(page) as draft:
        draft.write_text(render_html(runs, images, refresh_seconds, videos))
    for name, file in images:
        with written_whole(out / file) as draft:  # a browser reloading a live report sees the old image or the new one
            plot_curve(runs, name, draft)
    return page


def summary(run: RunRecord, seeds: int = 1) -> dict[str, Any]:
    """Table cells of a run: task, network, head, seeds (runs of its group, see `seed_groups`), cycles done, env
    steps, final and best return."""
    returns = [r["episode_return"] for r in run.rows if not math.isnan(r.get("episode_return", math.nan))]
    tail = returns[-max(1, len(returns) // 10) :]
    steps = [r["env_steps"] for r in run.rows if "env_steps" in r]  # the last cycle's row may hold nothing else
    ppo = run.config.get("ppo", {})
    return {
        "status": run.status(),
        "task": run.config.get("env", {}).get("task", "?"),
        "network": ppo.get("network", {}).get("name", "?"),
        "head": ppo.get("head", "?"),
        "seed": f"{ppo.get('seed', '?')} (group of {seeds})" if seeds > 1 else str(ppo.get("seed", "?")),
        "cycles": f"{run.rows[-1]['cycle'] if run.rows else 0}/{ppo.get('num_cycles', '?')}",
        "env steps": f"{steps[-1]:,}" if steps else "0",
        "final return": f"{sum(tail) / len(tail):.2f}" if tail else "-",
        "best return": f"{max(returns):.2f}" if returns else "-",
    }


def render_html(runs: list[RunRecord], images: list[tuple[str, str]], refresh_seconds: int | None = None,
                videos: list[tuple[str, str]] = ()) -> str:
    """The report page: a filterable table of runs (config in a fold-out), the learning-curve images and `videos`
    ((run name, path relative to the page) of each run's latest video); with `refresh_seconds`, a page that reloads
    itself (keeping the filter, which lives in the address)."""
    columns = ["run", *summary(runs[0])] if runs else ["run"]
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    rows = []
    group_size = {id(run): len(group) for group in seed_groups(runs) for run in group}
    for run in runs:
        config_text = yaml.safe_dump(run.config, sort_keys=False)
        cells = "".join(f"<td>{html.escape(str(v))}</td>" for v in summary(run, group_size[id(run)]).values())
        search = html.escape(f"{run.name} {json.dumps(run.config)}".lower(), quote=True)
        rows.append(
            f'<tr class="run" data-search="{search}"><td><details><summary>{html.escape(run.name)}</summary>'
            f"<pre>{html.escape(config_text)}</pre></details></td>{cells}</tr>"
        )
    figures = "".join(
        f'<figure><img src="{html.escape(file)}" alt="{html.escape(name)}"></figure>'
        for name, file in images
    )
    if videos:
        figures += "<h2>The policy, latest video</h2>" + "".join(
            f'<figure><img src="{html.escape(file)}" alt="{html.escape(name)}">'
            f"<figcaption>{html.escape(name)}: {html.escape(Path(file).stem)}</figcaption></figure>"
            for name, file in videos
        )
    refresh = "" if refresh_seconds is None else f'<meta http-equiv="refresh" content="{int(refresh_seconds)}">'
    updated = time.strftime("%Y-%m-%d %H:%M:%S")
    live = "" if refresh_seconds is None else f", reloads every {int(refresh_seconds)} s"
    return _PAGE.format(head=head, rows="\n".join(rows), figures=figures, count=len(runs),
                        total=counted(len(runs), "run"), refresh=refresh, updated=f"{updated}{live}")


# The page's title, also how `write_report` tells a report's index.html from a page of the user's.
PAGE_TITLE = "<title>angora_jax runs</title>"
_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">{refresh}""" + PAGE_TITLE + """
<style>
body {{ font-family: sans-serif; margin: 1.5em; }}
table {{ border-collapse: collapse; }}
th, td {{ border-bottom: 1px solid #ddd; padding: 0.3em 0.8em; text-align: left; vertical-align: top; }}
pre {{ font-size: 0.8em; max-height: 30em; overflow: auto; }}
figure {{ display: inline-block; margin: 0.5em; }}
#filter {{ width: 30em; padding: 0.3em; margin-bottom: 0.8em; }}
</style></head>
<body>
<h1>angora_jax runs</h1>
<p id="updated">Updated {updated}</p>
<input id="filter" placeholder="filter runs by name or any config value (e.g. lstm, CartPole)">
<p><span id="shown">{count}</span> of {total} shown</p>
<table><thead><tr>{head}</tr></thead><tbody>
{rows}
</tbody></table>
<h2>Learning curves</h2>
{figures}
<script>
const box = document.getElementById("filter");
function applyFilter() {{
  const words = box.value.toLowerCase().split(/\\s+/).filter(Boolean);
  let shown = 0;
  for (const row of document.querySelectorAll("tr.run")) {{
    const match = words.every(w => row.dataset.search.includes(w));
    row.hidden = !match;
    shown += match;
  }}
  document.getElementById("shown").textContent = shown;
}}
box.addEventListener("input", () => {{
  applyFilter();  // the filter goes into the address, so that a reloading live page keeps it
  history.replaceState(null, "", box.value ? "#filter=" + encodeURIComponent(box.value) : location.pathname);
}});
const fromAddress = new URLSearchParams(location.hash.slice(1)).get("filter");
if (fromAddress) {{ box.value = fromAddress; }}
applyFilter();
window.addEventListener("load", () => {{
  const images = [...document.images];
  document.body.dataset.imagesLoaded = images.filter(i => i.complete && i.naturalWidth > 0).length;
}});
</script>
</body></html>
"""
