"""The msgpack files that the commands write, told apart by what they hold, so that one given where another belongs is
named as what it is and the right place for it is said: an exported policy (`angora-jax export`), a pose estimator and
a network component (`angora-jax pretrain-vision` writes both, OUT.pose.msgpack and OUT)."""

from __future__ import annotations

from pathlib import Path

from flax import serialization

EXPORTED_POLICY = "an exported policy (`angora-jax export`)"
POSE_ESTIMATOR = "a pose estimator (`angora-jax pretrain-vision --out OUT` writes it as OUT.pose.msgpack)"
COMPONENT = ("a network component (`angora-jax pretrain-vision --out OUT` writes its encoder as OUT; "
             "nets.components.save_component writes any module)")

# Where each kind is given instead.
USE = {
    EXPORTED_POLICY: "act with it in Python, `aj.load_policy(file)`, whose `.agent` evaluates and is probed "
                     "(docs/evaluation.md, Export a policy)",
    POSE_ESTIMATOR: "give it as env.options.pose_estimator=FILE (evaluate and record: --env-option "
                    "pose_estimator=FILE)",
    COMPONENT: "give it as a network's pretrained component, e.g. ppo.network.pretrained='{visual: FILE}'",
}


def msgpack_kind(file: str | Path) -> str | None:
    """Which of the kinds above `file` holds (EXPORTED_POLICY, POSE_ESTIMATOR or COMPONENT), or None when it holds
    none (not msgpack, damaged, cut short or empty)."""
    try:
        content = serialization.msgpack_restore(Path(file).read_bytes())
    except (OSError, ValueError, TypeError):  # msgpack and flax raise these on bytes that are no msgpack
        return None
    return content_kind(content)


def content_kind(content: object) -> str | None:
    """`msgpack_kind` of a file's contents already read (`flax.serialization.msgpack_restore`)."""
    if not isinstance(content, dict) or not content:
        return None
    if {"format", "state"} <= content.keys():
        return EXPORTED_POLICY
    return POSE_ESTIMATOR if "encoder_options" in content else COMPONENT
