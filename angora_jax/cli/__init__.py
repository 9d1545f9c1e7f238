"""The `angora-jax` command: train, resume, evaluate and compare runs.

angora-jax train cartpole                       train configs/cartpole.yaml into runs/<name>/
angora-jax train cartpole ppo.network.name=lstm logging.run_name=lstm
angora-jax resume runs/lstm                     continue from the latest checkpoint, exactly
angora-jax check runs/lstm                      is the run intact (checkpoints, metrics), what would resume do
angora-jax evaluate runs/lstm                   episode statistics of the best checkpoint (CPU path), JSON + PNG
angora-jax render runs/lstm --out lstm.mp4      a video of an episode (MuJoCo tasks)
angora-jax export runs/lstm --out lstm.msgpack  the policy in one file, for aj.load_policy without the run
angora-jax report runs/lstm runs/other          PNG curves + index.html comparing runs
angora-jax monitor runs/lstm runs/other         the same page while runs train, served on http://127.0.0.1:8000
angora-jax list-configs                         the shipped configs (train one by name from any directory)
angora-jax doctor                               versions, devices, physics choice, rendering: what to install
angora-jax record runs/lstm --out act.nc        every layer's activity with the task variables (xarray, NetCDF)
angora-jax analyze decode act.nc                ridge R^2 of each variable from each layer, against noise
angora-jax analyze similarity act.nc --condition metric_goal_distance    RDMs per layer (RSA), compared
angora-jax analyze dynamics act.nc --run runs/cortical --recurrent network.PMC
                                                PCA per layer; fixed points of a recurrent area (--inputs
                                                network.PMC_in: the layer feeding a cell outside a graph)
angora-jax analyze timescales act.nc             activity autocorrelation and timescale per layer
angora-jax analyze crosscorrelation act.nc       which layer's leading component leads which, over lags
angora-jax analyze decode act.nc --lags 0 4 8    decode each variable k steps after the activity
angora-jax analyze tuning act.nc --layer network.SSC_2 --variable metric_goal_distance
angora-jax analyze sindy act.nc --layer network.PMC.1 --inputs network.PMC_in
                                                equations of a layer's dynamics in its leading components
angora-jax analyze ablate runs/lstm --lesion network.SSC_2 --silence goal    task outcomes under lesions
angora-jax analyze visual act.nc --run runs/pixels   a pixel agent's visual area: filters, saliency, preferred stimuli
angora-jax pretrain-vision --out encoder.msgpack    a visual encoder that sees the cube's pose, from renders
"""

from __future__ import annotations

import argparse
import errno
import os
import signal
import sys

from angora_jax.cli import analysis, configs, evaluation, reports, training, vision
from angora_jax.cli.arguments import EXIT_FAILED, EXIT_USAGE, add_import_option
from angora_jax.cli.errors import device_memory_message, os_error_message, platform_message
from angora_jax.experiment.terminal import discard, terminal_descriptors
from angora_jax.registry.plugins import UserCodeError, import_modules

# The verbs in the order `angora-jax --help` lists them, each added by the module of its group.
VERBS = (training.add_train, training.add_resume, training.add_check, evaluation.add_evaluate, evaluation.add_render,
         evaluation.add_export, reports.add_report, evaluation.add_record, analysis.add_analyze, reports.add_monitor,
         vision.add_pretrain_vision, configs.add_config, configs.add_list_configs, configs.add_doctor,
         configs.add_list_tasks, configs.add_list_models, configs.add_run)


def parser() -> argparse.ArgumentParser:
    """The whole command line: `angora-jax` and each verb's parser, its handler set as `handler`."""
    top = argparse.ArgumentParser(prog="angora-jax", description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    top.add_argument("--version", action="version", version=f"angora-jax {installed_version()}",
                     help="print the installed angora-jax's version (`angora-jax doctor`: JAX's, MuJoCo's, devices)")
    commands = top.add_subparsers(dest="command", required=True)
    for add_verb in VERBS:
        add_verb(commands)
    for verb in leaf_parsers(top):
        add_import_option(verb)
    return top


def installed_version() -> str:
    """angora-jax's version as installed (its package metadata), read without importing JAX."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("angora-jax")
    except PackageNotFoundError:  # run from a checkout that was never installed
        return "(not installed: run from a source checkout)"


def leaf_parsers(command: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """The parsers that run a handler: `command`'s subcommands, and theirs (`analyze decode`, `config show`)."""
    groups = [action for action in command._actions if isinstance(action, argparse._SubParsersAction)]
    if not groups:
        return [command]
    return [leaf for group in groups for sub in group.choices.values() for leaf in leaf_parsers(sub)]


def main(argv: list[str] | None = None) -> int:
    """Run the command; exit codes: 0 done, 1 training diverged or another process of the run failed, 2 bad usage
    or config, a second writer, a damaged file, a full disk or a GPU out of memory (nothing saved before is changed),
    128 + signal number (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP: its terminal closed) when training was interrupted
    after saving a checkpoint, 141 (as for SIGPIPE) when the reader of its output left before it ended (`| head`),
    129 too when its terminal closed while it ran on with SIGHUP ignored (its work done; its last output lost)."""
    terminals = terminal_descriptors()  # now: a terminal that closed is no tty
    cli = parser()
    args, extra = cli.parse_known_args(argv)
    if extra:
        settings = all("=" in item and not item.startswith("-") for item in extra)
        if hasattr(args, "overrides") and settings:
            args.overrides = [*args.overrides, *extra]  # overrides after the options: `train CFG --distributed a=1`
        elif args.command == "resume" and settings:
            cli.error(f"resume continues a run with the settings it was trained with, so it takes no KEY=VALUE "
                      f"({' '.join(extra)}). To train it longer: --num-cycles N; past its ppo.stop_at: --no-stop-at; "
                      "with other settings, a new run from its policy: angora-jax train CONFIG "
                      "ppo.init_from=RUN_DIR:latest KEY=VALUE")
        else:
            cli.error(f"unrecognized arguments: {' '.join(extra)}")
    try:
        import_modules(args.imports, "--import")
        code = args.handler(args)
        sys.stdout.flush()  # here, where a reader gone is answered below, not at Python's exit (exit status 120)
        return code
    except UserCodeError as error:
        print(f"angora-jax {args.command}: {error}", file=sys.stderr)
        return EXIT_USAGE
    except (*raised("angora_jax.experiment.config:ConfigError", "angora_jax.experiment.run_dir:RunDirError"),
            FileNotFoundError) as error:
        # The system's own FileNotFoundError names a path and an errno; ours carry their whole message.
        system = isinstance(error, FileNotFoundError) and error.errno is not None
        print(f"angora-jax {args.command}: {os_error_message(error, args.command) if system else error}",
              file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # stdout's reader is gone (`| head`, a pager closed): nothing to tell it, the work is done
        discard([sys.stdout.fileno()])  # Python's flush at exit fails no more
        return 128 + signal.SIGPIPE  # as a shell reports a writer that SIGPIPE ended
    except OSError as error:  # a full disk, a read-only or lost mount, permissions: the machine's, not a bug
        if error.errno == errno.EIO and any(not os.isatty(descriptor) for descriptor in terminals):
            # Not the disk: the terminal it wrote to closed (`disown`, a SIGHUP ignored); nothing can be shown.
            discard(terminals)
            return 128 + signal.SIGHUP
        print(f"angora-jax {args.command}: {os_error_message(error, args.command)}", file=sys.stderr)
        return EXIT_USAGE
    except raised("angora_jax.experiment.runner:TrainingInterrupted") as stop:
        from angora_jax.experiment.distributed import is_main_process  # imported by the runner that raised it

        if is_main_process():  # every process of a job stopped after the same cycle: one says so, not one each
            print(f"angora-jax {args.command}: {stop}", file=sys.stderr)
        return 128 + stop.signum
    except KeyboardInterrupt:  # Ctrl-C in a verb other than train's loop, which stops after saving instead
        print(f"angora-jax {args.command}: interrupted (Ctrl-C); the files it wrote are whole, none was left "
              "half-written.", file=sys.stderr)
        return 128 + signal.SIGINT
    except raised("angora_jax.ppo.train:TrainingDivergedError",
                  "angora_jax.experiment.distributed:ProcessFailed") as error:
        print(f"angora-jax {args.command}: {error}", file=sys.stderr)
        return EXIT_FAILED
    except Exception as error:
        platform = platform_message(error)  # first: asking for the process count would fail again, with a traceback
        if platform is not None:
            print(f"angora-jax {args.command}: {platform}", file=sys.stderr)
            return EXIT_USAGE
        if "angora_jax.experiment.distributed" in sys.modules:  # no job of several processes without it
            from angora_jax.experiment.distributed import lost_process_cause, lost_process_exit

            lost = lost_process_cause(error)
            if lost is not None:  # a process of the job is gone (kill -9): no traceback, no wait at the shutdown
                lost_process_exit(lost)
        message = device_memory_message(error, args.command)
        if message is None:
            raise
        print(f"angora-jax {args.command}: {message}", file=sys.stderr)
        return EXIT_USAGE


def raised(*classes: str) -> tuple[type[BaseException], ...]:
    """The exception classes among `classes` ("module:Class") whose modules are imported: only those can have been
    raised, and importing the others on the way out (JAX, Orbax) would cost seconds for nothing."""
    found = []
    for name in classes:
        module, _, attribute = name.partition(":")
        if module in sys.modules:
            found.append(getattr(sys.modules[module], attribute))
    return tuple(found)
