#!/bin/bash
# MyoHandPose by the start-distance curriculum that the pose oracle study recommends (benchmarks/results/myohand/
# README.md; docs/tasks.md, MyoHandPose), as one command: stage 1 trains from starts nearer the target
# (env.options.start_spread=SPREAD; 0.4 starts about 1 rad off), stage 2 trains on MyoSuite's own starts
# (start_spread 1) from stage 1's network and observation statistics (ppo.init_from); then stage 2's policy is
# evaluated on EPISODES episodes of MyoSuite's task (its mode actions; evaluate's own episode keys, not training's),
# recorded, and its muscle synergies and muscles-or-movements analyses (against the random-weights control) are
# computed. Everything lands in ROOT, and the script prints where:
#   ROOT/stage1, ROOT/stage2                 the two runs (each an ordinary run: resume, evaluate, render it)
#   ROOT/stage2/evaluation/*.json, *.png     the evaluation, at start_spread 1
#   ROOT/recording.nc                        stage 2's layers, muscles and joints over RECORD_EPISODES episodes
#   ROOT/recording.synergies.{png,nc}, ROOT/recording.muscles-or-movements.{png,nc}
#
#   examples/myohand_pose_curriculum.sh runs/pose_curriculum                    # 5 + 5 minutes on one GPU
#   SPREAD=0.3 STAGE1_MINUTES=3 STAGE2_MINUTES=7 CONFIG=myohand_pose_cortical examples/myohand_pose_curriculum.sh \
#       runs/pose_cortical ppo.seed=1                                           # KEY=VALUE goes to both stages
#   examples/myohand_pose_curriculum.sh runs/pose_cpu ppo.num_envs=8 ppo.minibatch_size=32   # on a CPU
#
# Arguments: ROOT, a folder for the two runs and the results, then config overrides for both stages' `angora-jax
# train`. Environment:
#   CONFIG            the config (myohand_pose; or myohand_pose_cortical)
#   SPREAD            stage 1's start_spread, in (0, 1] (0.4)
#   STAGE1_MINUTES    stage 1's training time, compile included (5); ppo.num_cycles is set to 5,000, more than a stage
#   STAGE2_MINUTES    of 45 minutes reaches on one H200, so the minutes end each stage (5); a ppo.num_cycles override
#                     caps both
#   CHECKPOINT        the checkpoint of a stage carried on: stage 2 starts from stage 1's, and stage 2's is evaluated
#                     and recorded (latest; best is by checkpoint.best_metric, metric/success for myohand_pose, so
#                     while no episode has succeeded it stays at the first cycle that ended episodes: on a GPU a
#                     stage 1 that never succeeded handed its cycle 1 of 227 to stage 2 that way)
#   EPISODES          evaluation episodes (480); EVALUATE_OPTIONS: more `angora-jax evaluate` options, e.g.
#                     "--workers 8" or "--path batched"
#   RECORD_EPISODES   episodes recorded for the analyses (64; at least 5, the analyses' folds)
# A ROOT that holds a stage1 already is refused (exit 2, as `angora-jax train` refuses an existing run): nothing is
# overwritten. Ctrl-C stops the stage's training after its cycle with a checkpoint, and the script stops there.
set -euo pipefail

usage() {
    echo "examples/myohand_pose_curriculum.sh: $1" >&2
    echo "usage: [SPREAD=0.4 STAGE1_MINUTES=5 STAGE2_MINUTES=5 ...] examples/myohand_pose_curriculum.sh ROOT" \
        "[KEY=VALUE ...]  (the header lists every variable)" >&2
    exit 2
}

[ $# -ge 1 ] && [[ $1 != *=* ]] || usage "give ROOT, the folder for the two runs and the results, first."
ROOT=$1
shift
CONFIG=${CONFIG:-myohand_pose}
SPREAD=${SPREAD:-0.4}
STAGE1_MINUTES=${STAGE1_MINUTES:-5}
STAGE2_MINUTES=${STAGE2_MINUTES:-5}
CHECKPOINT=${CHECKPOINT:-latest}
EPISODES=${EPISODES:-480}
RECORD_EPISODES=${RECORD_EPISODES:-64}
read -r -a evaluate_options <<< "${EVALUATE_OPTIONS:-}"

# Checked before stage 1 trains, so that a typo does not end the script after minutes of training; SPREAD and the
# overrides `angora-jax train` checks itself when stage 1 starts.
for name in STAGE1_MINUTES STAGE2_MINUTES; do
    [[ ${!name} =~ ^[0-9]*\.?[0-9]+$ && ${!name} =~ [1-9] ]] ||
        usage "$name=${!name} is not a positive number of minutes, e.g. $name=5."
done
for name in EPISODES RECORD_EPISODES; do
    [[ ${!name} =~ ^[1-9][0-9]*$ ]] || usage "$name=${!name} is not a positive whole number of episodes."
done
[ "$RECORD_EPISODES" -ge 5 ] ||
    usage "RECORD_EPISODES=$RECORD_EPISODES: muscles-or-movements splits the episodes into 5 folds; give at least 5."
[[ $CHECKPOINT =~ ^(best|latest|[0-9]+)$ ]] || usage "CHECKPOINT=$CHECKPOINT: give best, latest or a cycle number."
for override in "$@"; do
    case $override in
        env.options.start_spread=* | ppo.init_from=* | logging.run_root=* | logging.run_name=*)
            usage "$override is the script's to set: give stage 1's start_spread as SPREAD=..., the place as ROOT." ;;
    esac
done

# Each stage's minutes end it: the config's cycles (myohand_pose: 300, about 3.5 minutes on one H200) would end it
# first. Not far more than needed: snapshots, the disk check and the progress's ETA count on ppo.num_cycles. Before
# the overrides, which win.
common=("logging.run_root=$ROOT" ppo.num_cycles=5000 "$@")
angora-jax train "$CONFIG" "${common[@]}" logging.run_name=stage1 "env.options.start_spread=$SPREAD" \
    --minutes "$STAGE1_MINUTES" || {
    status=$?
    # train's refusal of an existing run suggests another logging.run_name, which is the script's to set.
    [ "$status" -ne 2 ] || echo "examples/myohand_pose_curriculum.sh: stage 1 was refused (above); if ROOT holds a" \
        "curriculum already, give another ROOT." >&2
    exit "$status"
}
angora-jax train "$CONFIG" "${common[@]}" logging.run_name=stage2 env.options.start_spread=1.0 \
    "ppo.init_from=$ROOT/stage1:$CHECKPOINT" --minutes "$STAGE2_MINUTES"
# Stage 2's own config holds start_spread 1: the evaluation is of MyoSuite's task.
angora-jax evaluate "$ROOT/stage2" --checkpoint "$CHECKPOINT" --episodes "$EPISODES" "${evaluate_options[@]}"
angora-jax record "$ROOT/stage2" --checkpoint "$CHECKPOINT" --episodes "$RECORD_EPISODES" --out "$ROOT/recording.nc"
angora-jax analyze synergies "$ROOT/recording.nc"
angora-jax analyze muscles-or-movements "$ROOT/recording.nc" --run "$ROOT/stage2" --checkpoint "$CHECKPOINT"

echo "MyoHandPose curriculum done, in $ROOT:"
echo "  stage 1 (start_spread $SPREAD, $STAGE1_MINUTES min): $ROOT/stage1"
echo "  stage 2 (start_spread 1, $STAGE2_MINUTES min, from stage 1's $CHECKPOINT): $ROOT/stage2"
for file in "$ROOT"/stage2/evaluation/*.json; do echo "  evaluation ($EPISODES episodes, start_spread 1): $file"; done
echo "  recording ($RECORD_EPISODES episodes): $ROOT/recording.nc"
echo "  synergies: $ROOT/recording.synergies.png, $ROOT/recording.synergies.nc"
echo "  muscles or movements: $ROOT/recording.muscles-or-movements.png, $ROOT/recording.muscles-or-movements.nc"
