#!/bin/bash
# Issue #32: the terminal app on the command line's folders. `factr2 collect --no-cameras` and `factr2 train
# --out` write where the user says; `factr2 tui --recordings DEMOS --runs RUN` opens them, trains on the
# twin's object state and rolls out (a task mismatch refused in keys, then the demonstrations' task).
# Captures 35-42 beside this script, the command line's output in journey_folders_cli.txt. Needs tmux.
set -u
S=f2fold
OUT=/tmp/tuifold
CAP="$(cd "$(dirname "$0")" && pwd)"
rm -rf $OUT; mkdir -p $OUT
{
  echo "\$ factr2 collect --rig sim-piper --task wipe --episodes 2 --no-cameras --out $OUT/demos"
  factr2 collect --rig sim-piper --task wipe --episodes 2 --no-cameras --out $OUT/demos 2>&1 | tr '\r' '\n' \
    | grep -v "it/s\|ep/s" | tail -9
  echo "\$ factr2 train $OUT/demos --obs state --out $OUT/cli-run --steps 20 --batch 16 --warmup 5 ..."
  factr2 train $OUT/demos --obs state --out $OUT/cli-run --steps 20 --batch 16 --warmup 5 --val-every 10 \
    --log-every 5 --no-progress 2>&1 | tail -6
  echo "\$ ls $OUT/demos   # only what was recorded: the caches live in ~/.cache/factr2/recordings"
  ls $OUT/demos
} > "$CAP/journey_folders_cli.txt" 2>&1
tmux kill-session -t $S 2>/dev/null
tmux new-session -d -s $S -x 100 -y 30
tmux send-keys -t $S "export PATH='$PATH'; cd $OUT && factr2 tui --recordings $OUT/demos --runs $OUT/cli-run" Enter
. "$CAP/tmux_helpers.sh"  # cap, waitfor, key
waitfor "press c on this screen" 60
key 4; waitfor "recordings in $OUT/demos" 30; waitfor "wipe" 60; sleep 1
cap 35_episodes_collect_folder_100x30
key 5; waitfor "cannot train: obs images" 60; sleep 1
cap 36_train_obs_images_cannot_train_100x30
key i; key z; key z
for _ in 1 2 3 4 5; do key "["; done
waitfor "length 20 steps" 10; sleep 1
cap 37_train_obs_state_tryout_100x30
key g
waitfor "run DONE" 600; sleep 1
cap 38_train_obs_state_done_100x30
key 6; waitfor "rig check: " 120; sleep 0.5  # no task yet: a state policy needs one, the check says so
cap 39_rollout_runs_of_the_command_line_100x30
key t; waitfor "not peg-insert" 120; sleep 0.5
cap 40_rollout_task_mismatch_refused_100x30
key t; waitfor "rig check: OK for sim-piper with task wipe" 120
key "]"; key "]"; key g
waitfor "stage run" 180; sleep 1.5
cap 41_rollout_state_policy_on_wipe_100x30
waitfor "rollout DONE" 300; sleep 1
cap 42_rollout_state_policy_done_100x30
key q
sleep 6
tmux kill-session -t $S
