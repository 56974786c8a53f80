#!/bin/bash
# Issue #56: the Train screen says what more data or training would buy, from the run's own validation curve
# (policies/training/advice.py). Two wipe demonstrations from `factr2 collect --no-cameras`; the app trains
# tryout policies on the twin's object state (one episode trains, one validates; a tryout validates every
# 10 steps): 20 steps, too few evaluations to read (capture 43), then 500 steps (capture 44). Needs tmux.
set -u
S=f2advice
OUT=/tmp/tuiadvice
CAP="$(cd "$(dirname "$0")" && pwd)"
rm -rf $OUT; mkdir -p $OUT/runs
factr2 collect --rig sim-piper --task wipe --episodes 2 --no-cameras --out $OUT/demos > /dev/null 2>&1
tmux kill-session -t $S 2>/dev/null
tmux new-session -d -s $S -x 100 -y 30
tmux send-keys -t $S "export PATH='$PATH'; cd $OUT && factr2 tui --recordings $OUT/demos --runs $OUT/runs" Enter
. "$CAP/tmux_helpers.sh"  # cap, waitfor, key
waitfor "press c on this screen" 60
key 5; waitfor "cannot train: obs images" 60; sleep 1
key i; key z; key z
for _ in 1 2 3 4 5; do key "["; done
waitfor "length 20 steps" 30; sleep 1
key g
waitfor "advice:" 900; sleep 1
cap 43_train_advice_no_basis_100x30
key "]"; key "]"  # 20 -> 100 -> 500 steps
waitfor "length 500 steps" 30; sleep 1
key g
waitfor "run TRAINING" 120
waitfor "run DONE" 1800; waitfor "advice:" 60; sleep 1
cap 44_train_advice_100x30
key q
sleep 6
tmux kill-session -t $S
