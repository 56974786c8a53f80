#!/bin/bash
# Issue #56: the Train screen showing the advice of three real runs (SIMULATED twin demonstrations), each
# opened as `factr2 tui --recordings DEMOS --runs RUN` shows the run it lists first (docs/policies.md, "What
# the run advises"): 45 too little data, 46 enough for its length, 47 over-long training. Nothing is trained
# here; the runs are read, never written.
#   journey_advice_real_100x30.sh LITTLE_RUN LITTLE_DEMOS ENOUGH_RUN ENOUGH_DEMOS LONG_RUN LONG_DEMOS
# The runs are linked under /tmp (a name that says what each is) so the captures name no machine folder.
# Needs tmux.
set -u
[ $# -eq 6 ] || { echo "usage: $0 LITTLE_RUN LITTLE_DEMOS ENOUGH_RUN ENOUGH_DEMOS LONG_RUN LONG_DEMOS"; exit 2; }
S=f2advreal
OUT=/tmp/tuiadvreal
CAP="$(cd "$(dirname "$0")" && pwd)"
. "$CAP/tmux_helpers.sh"  # cap, waitfor, key
rm -rf $OUT
shot() {  # NAME RUN DEMOS CAPTURE
  mkdir -p $OUT/$1/runs
  ln -s "$(realpath "$2")" $OUT/$1/runs/$1
  ln -s "$(realpath "$3")" $OUT/$1/demos
  tmux kill-session -t $S 2>/dev/null
  tmux new-session -d -s $S -x 100 -y 30
  tmux send-keys -t $S "export PATH='$PATH'; cd $OUT && nice -n 15 factr2 tui --recordings $OUT/$1/demos --runs $OUT/$1/runs" Enter
  waitfor "press c on this screen" 60
  key 5; waitfor "advice:" 300; waitfor "usable episodes chosen" 300; sleep 2
  cap "$4"
  key q
  sleep 4
  tmux kill-session -t $S 2>/dev/null
}
shot peg-insert-12-demos "$1" "$2" 45_train_advice_too_little_data_100x30
shot cap-screw-50-demos "$3" "$4" 46_train_advice_enough_100x30
shot peg-insert-49-demos "$5" "$6" 47_train_advice_over_long_100x30
