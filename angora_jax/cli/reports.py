"""Verbs that show runs' learning curves: `report` writes the page once, `monitor` keeps it current while runs
train."""

from __future__ import annotations

import argparse
import errno
import socket
import sys
from pathlib import Path

from angora_jax.cli.arguments import EXIT_OK, EXIT_USAGE, port, update_interval
from angora_jax.wording import counted


def add_report(commands: argparse._SubParsersAction) -> None:
    """The `report` verb: its arguments and its handler."""
    report = commands.add_parser("report", help="PNG learning curves and an HTML page comparing runs")
    report.add_argument("run_dirs", nargs="+", metavar="RUN_DIR", help="one or more runs, drawn together")
    report.add_argument(
        "--out", default=None, help="default: RUN_DIR/report for one run, else report/ beside the first run"
    )
    report.set_defaults(handler=command_report)


def add_monitor(commands: argparse._SubParsersAction) -> None:
    """The `monitor` verb: its arguments and its handler."""
    monitor = commands.add_parser("monitor", help="the HTML report of runs while they train, regenerated and served")
    monitor.add_argument("run_dirs", nargs="+", metavar="RUN_DIR", help="one or more runs, training or done")
    monitor.add_argument("--out", default=None, help="where the page is written (default: as for report)")
    monitor.add_argument("--every", type=update_interval, default=30.0,
                         help="seconds between updates, at most 86,400 (default: 30)")
    monitor.add_argument("--port", type=port, default=8000, help="HTTP port (default: 8000; 0: any free port)")
    monitor.add_argument("--host", default="127.0.0.1",
                         help="address to serve on (default: this machine only; 0.0.0.0 for the network)")
    monitor.add_argument("--no-serve", action="store_true", help="only rewrite the page on disk (open it yourself)")
    monitor.set_defaults(handler=command_monitor)


def report_dir(run_dirs: list[str], out: str | None) -> Path:
    """Where a report of `run_dirs` goes: `out`, else RUN_DIR/report for one run, else report/ beside the first."""
    first = Path(run_dirs[0])
    return Path(out) if out else (first / "report" if len(run_dirs) == 1 else first.parent / "report")


def command_report(args: argparse.Namespace) -> int:
    from angora_jax.experiment.report import write_report  # matplotlib only when a report is made

    print(f"Report: {write_report(args.run_dirs, report_dir(args.run_dirs, args.out))}")
    return EXIT_OK


def command_monitor(args: argparse.Namespace) -> int:
    from angora_jax.experiment.live_report import LiveReport

    out = report_dir(args.run_dirs, args.out)
    try:
        live = LiveReport(args.run_dirs, out, args.every, None if args.no_serve else args.port, args.host)
    except OSError as error:
        # A name that does not resolve, or an address of another machine, is the host's fault: another port fails too.
        elsewhere = isinstance(error, socket.gaierror) or error.errno == errno.EADDRNOTAVAIL
        fix = ("give --host an address of this machine (127.0.0.1: this machine only; 0.0.0.0: the network)"
               if elsewhere else "pick another --port (0: any free one)")
        print(f"angora-jax monitor: cannot serve on {args.host}:{args.port} ({error}); {fix} or use --no-serve.",
              file=sys.stderr)
        return EXIT_USAGE
    with live:
        where = live.url or (out / "index.html").resolve().as_uri()
        print(f"Monitoring {counted(len(args.run_dirs), 'run')}: {where} (updated every {args.every:g} s; Ctrl-C "
              "stops the monitor, never the runs)", flush=True)
        try:
            live.wait()
        except KeyboardInterrupt:
            print("Monitor stopped.")
    return EXIT_OK

