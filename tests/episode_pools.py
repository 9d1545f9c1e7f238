"""The tests' own account of a training metric over the latest episodes (angora_jax.ppo.episode_pool), from a run's
records, to check the best checkpoint and `ppo.stop_at` against."""

import math


def pooled_means(history: list[dict], metric: str, need: int) -> dict[int, float]:
    """Per cycle of `history`, the mean of `metric` over the latest `need` episodes that had ended by then (that
    cycle's, then the earlier ones', the oldest in part); NaN while fewer had."""
    means, ended = {}, []
    for record in history:
        if record["episodes"] > 0:
            ended.append((record[metric], record["episodes"]))
        total = weighted = 0.0
        for value, count in reversed(ended):
            taken = min(count, need - total)
            total, weighted = total + taken, weighted + value * taken
            if total >= need:
                break
        means[record["cycle"]] = weighted / need if total >= need else math.nan
    return means
