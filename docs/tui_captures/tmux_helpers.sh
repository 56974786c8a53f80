# Shared by the capture scripts beside this file (source it after setting S, the tmux session, and CAP,
# the capture folder): cap NAME saves the pane, waitfor TEXT SECONDS waits for it, key KEYS... types.
cap() { tmux capture-pane -t $S -p > "$CAP/$1.txt"; echo "captured $1"; }
waitfor() {  # text, timeout s
  for i in $(seq 1 $(( $2 * 2 ))); do
    tmux capture-pane -t $S -p | grep -q -- "$1" && return 0; sleep 0.5; done
  echo "TIMEOUT waiting for: $1"; tmux capture-pane -t $S -p | tail -5; return 1; }
key() { tmux send-keys -t $S "$@"; sleep 0.4; }
