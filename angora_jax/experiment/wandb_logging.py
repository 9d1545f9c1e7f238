"""Weights & Biases logging (`logging.wandb`): the run's resolved config once, then every cycle's scalars.

Optional: the `wandb` package comes with the `wandb` extra (in a clone: `pip install -c constraints.txt -e
'.[wandb]'`), and `config.validate` refuses `logging.wandb` without it before anything compiles. W&B keeps its own
files in `RUN_DIR/wandb/` (in `offline` mode everything stays there, for `wandb sync` later). A resumed run continues
the same W&B run: its id is kept in `RUN_DIR/wandb/run_id`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from angora_jax.frozen_settings import settings

WANDB_MODES = ("online", "offline", "disabled")
# angora-jax is not on PyPI: its extras install from a clone; plain `pip install wandb` works anywhere.
WANDB_INSTALL = "pip install -c constraints.txt -e '.[wandb]' in a clone of angora_jax (or pip install wandb)"
RUN_ID_FILE = "run_id"


@settings
class WandbConfig:
    """Logging to Weights & Biases; the section is off (null) unless one of its keys is given.

    Attributes:
        project: the W&B project the run goes to.
        entity: the W&B user or team that owns the project; null for the logged-in user's default.
        mode: "online" (sent as it trains), "offline" (written to `RUN_DIR/wandb/` only, to `wandb sync` later) or
            "disabled" (nothing written: W&B's own switch, e.g. for a debugging run).
    """

    project: str = "angora-jax"
    entity: str | None = None
    mode: str = "online"


class WandbLog:
    """One W&B run for one training session: started with the config, given each cycle's record, finished at the
    end. Charts use env_steps as their x axis, so a resumed run (whose first cycles may repeat cycles the killed
    session logged after its last checkpoint) draws its curve on from the checkpoint's env steps."""

    def __init__(self, run_dir: Path, settings: WandbConfig, config: dict[str, Any]):
        import wandb  # optional dependency, checked by config.validate

        folder = Path(run_dir) / "wandb"
        folder.mkdir(parents=True, exist_ok=True)
        id_file = folder / RUN_ID_FILE
        run_id = id_file.read_text().strip() if id_file.exists() else None  # None: W&B makes a new one
        self._run = wandb.init(project=settings.project, entity=settings.entity, mode=settings.mode,
                               dir=str(run_dir), name=Path(run_dir).name, id=run_id, resume="allow", config=config)
        id_file.write_text(self._run.id + "\n")
        self._run.define_metric("env_steps")
        self._run.define_metric("*", step_metric="env_steps")

    def log(self, record: dict[str, Any]) -> None:
        """The record's finite numbers (W&B draws no NaN; `time` is W&B's own timestamp already)."""
        self._run.log({key: value for key, value in record.items()
                       if isinstance(value, int | float) and math.isfinite(value) and key != "time"})

    def close(self) -> None:
        self._run.finish()
