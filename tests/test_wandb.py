"""`logging.wandb`: a tiny CartPole run in W&B's offline mode, read back from the run's `.wandb` file (the run's config
and every cycle's scalars must be there), and the config's refusals: an unknown mode, and wandb not installed."""

import importlib.util
import json
import struct

import numpy as np
import pytest
import wandb
from tiny import TINY_PPO
from wandb.proto import wandb_internal_pb2

import angora_jax as aj
from angora_jax.experiment.config import ConfigError, load_config, validate

# Every run here is a few cycles of a tiny CartPole, module fixtures included (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")

# W&B's transaction log (`run-ID.wandb`) is LevelDB's log format after a 7-byte header: 32 KiB blocks of chunks, each
# with a 7-byte header (CRC, length, type: 1 whole record, 2 first part, 3 middle, 4 last), of protobuf `Record`s.
BLOCK, CHUNK_HEADER, FILE_HEADER = 32768, 7, b":W&B\xe1\xbe\x00"


def wandb_records(path) -> list:
    data = path.read_bytes()
    assert data.startswith(FILE_HEADER)
    records, pending, offset = [], b"", len(FILE_HEADER)
    while offset + CHUNK_HEADER <= len(data):
        room = BLOCK - offset % BLOCK
        if room < CHUNK_HEADER:  # a block's tail too short for a chunk header is padding
            offset += room
            continue
        _, length, kind = struct.unpack("<IHB", data[offset:offset + CHUNK_HEADER])
        offset += CHUNK_HEADER
        pending += data[offset:offset + length]
        offset += length
        if kind in (1, 4):
            records.append(wandb_internal_pb2.Record.FromString(pending))
            pending = b""
    return records


def key(item) -> str:
    return item.key or ".".join(item.nested_key)  # W&B's writer fills one or the other


def offline_run(run_dir) -> tuple[dict, list[dict]]:
    """The config and the logged rows (key -> value) of the run's one offline W&B run."""
    (log,) = (run_dir / "wandb").glob("offline-run-*/run-*.wandb")
    config, rows = {}, []
    for record in wandb_records(log):
        kind = record.WhichOneof("record_type")
        if kind == "run":
            config |= {key(item): json.loads(item.value_json) for item in record.run.config.update}
        elif kind == "config":
            config |= {key(item): json.loads(item.value_json) for item in record.config.update}
        elif kind == "history":
            rows.append({key(item): json.loads(item.value_json) for item in record.history.item})
    return config, rows


def test_offline_run_holds_the_config_and_every_cycles_metrics(tmp_path):
    run = aj.train("cartpole", [*TINY_PPO, "ppo.num_cycles=2", "logging.wandb.mode=offline",
                                "logging.wandb.project=tests", "logging.progress=none", "logging.report=false",
                                f"logging.run_root={tmp_path}", "logging.run_name=r"])
    # W&B's service may still be writing the offline file when run.finish() returns (seen: an empty file read right
    # after it, a whole one a second later); teardown waits for the service to end.
    wandb.teardown()
    config, rows = offline_run(run.run_dir)
    assert config["env"]["task"] == "CartPole" and config["ppo"]["num_envs"] == 4
    assert config["logging"]["wandb"] == {"project": "tests", "entity": None, "mode": "offline"}
    assert [row["env_steps"] for row in rows] == [record["env_steps"] for record in run.history] == [64, 128]
    for row, record in zip(rows, run.history, strict=True):
        for key in ("episode_return", "loss", "entropy", "norm/reward_std"):
            np.testing.assert_allclose(row[key], record[key], rtol=1e-6, err_msg=key)
    (offline,) = (run.run_dir / "wandb").glob("offline-run-*")
    assert offline.name.endswith("-" + (run.run_dir / "wandb" / "run_id").read_text().strip()), "kept for resume"


def test_wandb_settings_are_checked_before_training(monkeypatch):
    with pytest.raises(ConfigError, match="Unknown value 'ofline' for logging.wandb.mode.*Did you mean 'offline'"):
        validate(load_config("cartpole", ["logging.wandb.mode=ofline"]))
    assert load_config("cartpole").logging.wandb is None, "off unless asked for"
    found = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "wandb" else found(name, *a))
    needs = r"needs the wandb package: pip install -c constraints.txt -e '\.\[wandb\]' in a clone"
    with pytest.raises(ConfigError, match=needs):
        validate(load_config("cartpole", ["logging.wandb={}"]))
