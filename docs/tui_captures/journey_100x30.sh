#!/bin/bash
# Drive `factr2 tui` in a 100x30 tmux pane through record -> train -> rollout -> episodes, saving text
# captures beside this script (docs/tui_captures/20-34_*_100x30.txt). Needs tmux; about 5 minutes.
set -u
S=f2cap
OUT=/tmp/tuicap
CAP="$(cd "$(dirname "$0")" && pwd)"
rm -rf $OUT; mkdir -p $OUT
tmux kill-session -t $S 2>/dev/null
tmux new-session -d -s $S -x 100 -y 30
tmux send-keys -t $S "cd $OUT && factr2 tui --out $OUT --connect" Enter
. "$CAP/tmux_helpers.sh"  # cap, waitfor, key
waitfor "connected to sim-piper" 60
cap 20_journeys_first_screen_100x30
key 3; key v; key t
waitfor "phase coupled" 30; sleep 6
key r; sleep 2.5; key p; sleep 3; key s; sleep 0.5
key r; sleep 3; key f; sleep 1
cap 21_teleop_demos_recorded_100x30
key t; sleep 2
key 5; waitfor "press h" 120; sleep 0.5
cap 22_train_no_thresholds_100x30
key h; sleep 0.5; tmux send-keys -t $S "1:2" ; sleep 0.3; key Enter
waitfor "shading:" 60; sleep 1
cap 23_train_phase_preview_100x30
key z; key z
for _ in 1 2 3 4 5; do key "["; done  # the shortest length, 20 steps (the keys run in order of length)
sleep 0.5
cap 24_train_choices_tryout_100x30
key g
waitfor "step [1-9]" 120; sleep 4
cap 25_train_progress_100x30
waitfor "run DONE" 600; sleep 1
cap 26_train_done_100x30
key 4; sleep 2
cap 27_episodes_and_runs_100x30
key 6; waitfor "rig check: OK" 60; sleep 0.5
cap 28_rollout_pick_run_100x30
key t; waitfor "rig check: OK for sim-piper with task" 60
key "]"; key "]"
key g
waitfor "stage run" 120; sleep 1.5
cap 29_rollout_running_task_100x30
waitfor "rollout DONE" 180; sleep 1
cap 30_rollout_done_100x30
key t; key t; key t; sleep 1; key "]"; key "]"; key "]"
waitfor "rig check: OK for sim-piper$" 60
key g
waitfor "stage run" 120; sleep 2
key Space; waitfor "rollout E-STOPPED" 60; sleep 0.5
cap 31_rollout_estop_100x30
key 4; sleep 2
cap 32_episodes_with_rollouts_100x30
key 5; sleep 1; key "]"; key "]"; key g
waitfor "step [1-9]" 120; sleep 3
cap 33_train_long_run_before_quit_100x30
key q
sleep 8
tmux send-keys -t $S "echo exit status \$?; cat runs/*/checkpoints/last; ls runs/*/checkpoints | head -20" Enter
sleep 2
cap 34_after_quit_mid_training_100x30
tmux kill-session -t $S
