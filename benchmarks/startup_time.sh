#!/bin/bash
# Start-up time of a run on a fresh host and on a warm one (issue 60, item 5): the same config trained for 2 cycles
# twice on one machine, "cold" (empty JAX compilation cache and Warp kernel cache) then "warm" (both filled by the
# first). For each it writes OUT/startup_<config>_<cold|warm>.json and .log with the seconds from launch to the
# session record (imports, config, building the task), from there to the first cycle's start (making the programs,
# Warp's kernel build, the reset's compile and run), the first cycle (its compile) and the second (the steady rate).
#
#   OUT=/tmp/startup benchmarks/startup_time.sh shadow_ihom     # on a GPU host; results/cube_one_gpu/startup_*
#
# Run from the repository root with angora_jax importable (an installed angora-jax or PYTHONPATH=.). The cold numbers
# are cold only on a host whose caches are empty (a fresh machine, or ANGORA_JAX_CACHE and ~/.cache/warp cleared).
set -u
CONFIG=${1:-shadow_ihom}
OUT=${OUT:?set OUT to the folder for the results}
ROOT=${RUN_ROOT:-$(mktemp -d)}
mkdir -p "$OUT"
for name in cold warm; do
  start=$(date +%s.%N)
  python -m angora_jax.cli train "$CONFIG" ppo.num_cycles=2 "logging.run_root=$ROOT" "logging.run_name=$name" \
      logging.progress=lines checkpoint.every=100 > "$OUT/startup_${CONFIG}_$name.log" 2>&1
  end=$(date +%s.%N)
  python - "$ROOT/$name" "$CONFIG" "$name" "$start" "$end" "$OUT" <<'PY'
import datetime, json, sys
run, config, name, start, end, out = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), float(sys.argv[5]), sys.argv[6]
session = json.loads(open(f"{run}/sessions.jsonl").readline())
rows = [json.loads(line) for line in open(f"{run}/metrics.jsonl")]
first = rows[0]
result = {"benchmark": "startup_time", "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
          "config": config, "run": name, "launch_to_session_s": session["time"] - start,
          "session_to_first_cycle_start_s": first["time"] - first["seconds"] - session["time"],
          "first_cycle_s": first["seconds"], "launch_to_first_cycle_end_s": first["time"] - start,
          "second_cycle_s": rows[1]["seconds"] if len(rows) > 1 else None, "launch_to_exit_s": end - start,
          "device": session["devices"][0]["kind"], "versions": session["versions"], "physics": session["physics"],
          "first_row": first}
print(json.dumps({k: v for k, v in result.items() if k not in ("versions", "physics", "first_row")}))
with open(f"{out}/startup_{config}_{name}.json", "w") as file:
    json.dump(result, file, indent=1)
PY
done
