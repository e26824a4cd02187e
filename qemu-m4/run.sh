#!/usr/bin/env bash
# The firmware cores on QEMU's mps2-an386 (Cortex-M4F): builds the image, runs its three sessions side by side,
# judges them and prints their figures (docs/qemu-m4.md).
#   acceptance seabotix / legacy  the dev-kit acceptance test looped back inside the chip, judged by
#                                 `lbv hil --replay` as a log from the dev kits would be
#   vehicle                       the master's whole core, six thruster cores, a scripted pilot
# Logs go to target/qemu-m4/. Needs qemu-system-arm (test.sh installs it).
# Usage: qemu-m4/run.sh
set -euo pipefail
cd "$(dirname "$0")/.."

TARGET=thumbv7em-none-eabihf
# The firmware's target directory: test.sh gives the firmware one of its own.
FIRMWARE_DIR="${LBV_FIRMWARE_TARGET_DIR:-target}"
ELF="$FIRMWARE_DIR/$TARGET/release/qemu-m4"
LOGS=target/qemu-m4
# Emulated time per run is bounded by the scripts (about 20 s); this only catches a hang.
WALL_LIMIT=120

command -v qemu-system-arm >/dev/null || { echo "qemu-m4: qemu-system-arm is missing (Debian: qemu-system-arm)" >&2; exit 2; }

# The image, and the judge, `lbv hil --replay`, with the test profile and the workspace's features (the release
# profile's fat LTO would take minutes for a log reader). test.sh has built both (LBV_TOOLS_BUILT): a build here
# would wait for the cargo its other steps run.
if [ -z "${LBV_TOOLS_BUILT:-}" ]; then
  CARGO_TARGET_DIR="$FIRMWARE_DIR" cargo build --release --target "$TARGET" -p qemu-m4 --locked
  cargo build --profile test --locked -q --workspace --bin lbv
fi
mkdir -p "$LOGS"

# -icount shift=3: 8 ns of virtual time per instruction, and every timer runs on that time, so the image counts
# instructions with a timer; sleep=off: while the core waits in WFI the virtual clock jumps to the next timer.
emulate() {
  local log="$LOGS/$1.log"
  shift
  local args
  args=$(printf ',arg=%s' qemu-m4 "$@")
  timeout "$WALL_LIMIT" qemu-system-arm -M mps2-an386 -nographic -monitor none -serial none \
    -icount shift=3,align=off,sleep=off -semihosting-config "enable=on,target=native$args" \
    -kernel "$ELF" >"$log" 2>&1
}

declare -A status
emulate acceptance-seabotix acceptance seabotix & seabotix=$!
emulate acceptance-legacy acceptance legacy & legacy=$!
emulate vehicle vehicle & vehicle=$!
wait "$seabotix" && status[acceptance-seabotix]=0 || status[acceptance-seabotix]=$?
wait "$legacy" && status[acceptance-legacy]=0 || status[acceptance-legacy]=$?
wait "$vehicle" && status[vehicle]=0 || status[vehicle]=$?

failed=0
for run in acceptance-seabotix acceptance-legacy vehicle; do
  log="$LOGS/$run.log"
  printf '\n--- %s (QEMU exit status %s; log %s)\n' "$run" "${status[$run]}" "$log"
  grep -E '^(ACCEPT step|ACCEPT verdict|PILOT|FAIL|panicked)' "$log" || true
  grep -E '^(CALIBRATION|BUS|HEAP|WATCHDOG|CONSOLE|STACK|CPU|LOAD|LATENCY)' "$log" || true
  # The image's own exit status: its verdict, and no watchdog that would have bitten.
  [ "${status[$run]}" -eq 0 ] || { echo "FAIL: $run ended with status ${status[$run]}" >&2; failed=1; }
  case "$run" in
    acceptance-*)
      # The judge of the dev kits' log, on this one.
      target/debug/lbv hil --replay "$log" >"$LOGS/$run.judged" 2>&1 || { cat "$LOGS/$run.judged"; failed=1; }
      echo "lbv hil --replay: $(tail -n 1 "$LOGS/$run.judged")"
      ;;
    vehicle)
      grep -q '^PILOT verdict=PASS' "$log" || { echo "FAIL: the pilot's session did not pass" >&2; failed=1; }
      ;;
  esac
done
[ "$failed" -eq 0 ] || { echo "qemu-m4: a run failed" >&2; exit 1; }
echo "qemu-m4: both acceptance loops and the vehicle run passed"
