"""A training metric over the latest episodes, pooled across cycles: what the best checkpoint and `ppo.stop_at`
compare. A cycle's training metric is a mean over the episodes that ended in it; with few environments that is one
episode or two, and a cycle whose one episode succeeded by chance would look solved."""

from __future__ import annotations

import math

# The cycles a pool still needs, oldest first: [metric value, episodes that ended in the cycle].
Pool = list[list[float]]


def pool_episodes(pool: Pool, value: float, episodes: float, need: int) -> tuple[float, Pool]:
    """Add a cycle's `value` (the mean over its `episodes` ending episodes; NaN and 0 add nothing) to `pool` and
    return the mean over the latest `need` episodes (this cycle's, then the cycles' before it, the oldest in part),
    NaN while fewer have ended, with the pool that the next cycle continues (only the cycles still needed)."""
    if math.isfinite(value) and math.isfinite(episodes) and episodes > 0:
        pool = [*pool, [value, episodes]]
    total = weighted = 0.0
    for start in range(len(pool) - 1, -1, -1):
        past, count = pool[start]
        taken = min(count, need - total)
        total, weighted = total + taken, weighted + past * taken
        if total >= need:
            return weighted / need, pool[start:]
    return math.nan, pool


def compared_value(pool: Pool, metrics: dict[str, float], name: str, need: int) -> tuple[float, Pool]:
    """The value of metric `name` in a cycle's `metrics` that a target or the best checkpoint compares, with the pool
    the next cycle continues: a held-out `eval/` value as it is (an evaluation of its own size), a training value over
    the latest `need` episodes (`pool_episodes`; a cycle's record counts its episodes, other callers give one value
    each)."""
    value = float(metrics.get(name, math.nan))
    if name.startswith("eval/"):
        return value, pool
    return pool_episodes(pool, value, float(metrics.get("episodes", 1.0)), need)
