# Two CPU-bound processes beside the suite: `source .ci/burners.sh; start_burners; ...;
# stop_burners`. Each spins one core in plain Python and dies with the shell that started
# it, however that shell ends (PR_SET_PDEATHSIG), so no burner outlives a run.
BURNERS=()

start_burners() {
  local python=${PYTHON:-python3} k
  for k in 1 2; do
    "$python" -c 'import ctypes, signal
ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG: die with the shell
while True:
    pass' &
    BURNERS+=("$!")
  done
  echo "ci: two CPU-bound processes beside the suite: ${BURNERS[*]}"
}

stop_burners() {
  local pid
  for pid in "${BURNERS[@]}"; do
    kill "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
  done
  BURNERS=()
}
