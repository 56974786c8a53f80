#!/usr/bin/env bash
# The FIRST headline (issue #31, docs/first.md): first vs base-torque, 3 tasks x 3 training seeds x 32
# rollouts on evaluation seed 15 (pre-registered), SIMULATED, PRIVILEGED state. From nothing (collections
# included) it ran in one session on two cores with bf16 training (--precision auto, the default; measured
# in docs/first.md). A run stopped part-way resumes: every finished cell goes to the ledger
# results/first_cells.json (commit it), and a new session re-collects the same demonstrations (deterministic:
# the same seeds and the committed NEXT checkpoint) and skips the ledger's cells.
#
#   bash bench/first_headline.sh [WORK]       # WORK: scratch folder (default /tmp/first_headline)
#   python -m bench.bench_first --report ... # the same options: the table of the finished cells
set -euo pipefail
cd "$(dirname "$0")/.."
W=${1:-/tmp/first_headline}
CK=bench/assets/next_sim_piper_first/next.json
export OMP_NUM_THREADS=1
mkdir -p "$W"
collect() {  # folder task episodes seed
  [ -f "$W/$1/done" ] && return 0
  rm -rf "${W:?}/$1"
  factr2 collect --task "$2" --episodes "$3" --seed "$4" --mode next --checkpoint "$CK" --no-cameras \
    --out "$W/$1" > "$W/$1.log" 2>&1 && touch "$W/$1/done"
}
# the demonstrations: peg-insert 122 episodes (seeds 1, 9), press-fit 122 (1, 9), wipe 50 (1); two queues
( collect peg1 peg-insert 50 1 && collect peg9 peg-insert 72 9 ) &
( collect press1 press-fit 50 1 && collect press9 press-fit 72 9 && collect wipe1 wipe 50 1 ) &
wait
for d in peg1 peg9 press1 press9 wipe1; do  # a collection that failed is not trained on
  [ -f "$W/$d/done" ] || { echo "collection $W/$d did not finish: see $W/$d.log, then run again" >&2; exit 1; }
done
python -m bench.bench_first --out "$W/out" --table headline --eval-seed 15 --next "$CK" \
  --ledger results/first_cells.json --jobs 2 \
  --demos-from "peg-insert=$W/peg1+$W/peg9" --demos-from "press-fit=$W/press1+$W/press9" \
  --demos-from "wipe=$W/wipe1" "${@:2}"
