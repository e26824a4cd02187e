#!/usr/bin/env bash
# Throughput of `lbv decode can` against cantools on the same candump log of one million BAT frames.
#
# Usage: lbv/bench-decode-can.sh [FRAMES]      (default 1000000; needs python3 with cantools: pip install cantools)
#
# Makes the log once (${TMPDIR:-/tmp}/lbv-bench-decode-can-FRAMES.log: 0x620, 0x629 and 0x628 in turn, random but
# deterministic values), builds lbv (the dev profile, optimised: Cargo.toml), then times, each writing to /dev/null:
#   lbv --json      lbv decode can --json LOG
#   lbv             lbv decode can LOG          (human output)
#   cantools loop   python3: read each line, db.decode_message() with lbv/dbc/bat.dbc, json.dumps() a line with
#                   the same fields as lbv's --json (the status word and set bits rebuilt from the bit signals)
#   cantools CLI    python3 -m cantools decode --single-line lbv/dbc/bat.dbc < LOG
# and prints the wall time and frames per second of each. Every run is checked to have decoded all the frames.
set -euo pipefail
cd "$(dirname "$0")/.."

FRAMES=${1:-1000000}
LOG=${TMPDIR:-/tmp}/lbv-bench-decode-can-$FRAMES.log
DBC=lbv/dbc/bat.dbc

python3 -c 'import cantools' 2>/dev/null || { echo "cantools is missing: pip install cantools" >&2; exit 3; }

cargo build --locked -p lbv --quiet
LBV="${CARGO_TARGET_DIR:-target}/debug/lbv"

if [ ! -s "$LOG" ]; then
  python3 - "$FRAMES" "$LOG" <<'PY'
import random
import sys

frames, path = int(sys.argv[1]), sys.argv[2]
rng = random.Random(1)
lines = []
status = 0x00AC
for i in range(frames):
    t = 1_700_000_000_000_000 + i * 100
    kind = i % 3
    if kind == 0:
        data = (rng.randrange(300, 500).to_bytes(2, "little")
                + rng.randrange(-600, 600).to_bytes(2, "little", signed=True)
                + bytes([rng.randrange(101), 0])
                + rng.randrange(-200, 600).to_bytes(2, "little", signed=True))
        frame = "620#" + data.hex().upper()
    elif kind == 1:
        if rng.randrange(4) == 0:
            status ^= 1 << rng.randrange(12)
        frame = "629#" + (status.to_bytes(2, "little") + bytes(6)).hex().upper()
    else:
        frame = "628#" + (bytes([rng.randrange(128) if rng.randrange(8) == 0 else 0]) + bytes(7)).hex().upper()
    lines.append(f"({t // 1_000_000}.{t % 1_000_000:06d}) can0 {frame}\n")
with open(path, "w") as log:
    log.writelines(lines)
PY
fi
echo "log: $LOG ($FRAMES frames, $(du -h "$LOG" | cut -f1))"

CANTOOLS_LOOP='
import json, sys
import cantools
db = cantools.database.load_file(sys.argv[1])
decode, dumps, write = db.decode_message, json.dumps, sys.stdout.write
bit_messages = {m.frame_id: [(s.start, s.name) for s in m.signals] for m in db.messages if m.frame_id != 0x620}
n = 0
with open(sys.argv[2]) as log:
    for line in log:
        fields = line.split()
        ident, _, data = fields[2].partition("#")
        frame_id = int(ident, 16)
        signals = decode(frame_id, bytes.fromhex(data), decode_choices=False)
        record = {"time": float(fields[0][1:-1]), "id": frame_id}
        if frame_id == 0x620:
            record.update(voltage_v=signals["Voltage"], current_a=signals["Current"] or None,
                          charge_pct=signals["Charge"], temperature_c=signals["Temperature"] or None)
        else:
            ones = [(start, name) for start, name in bit_messages[frame_id] if signals[name]]
            record.update(bits=sum(1 << start for start, _ in ones), names=[name for _, name in ones])
        write(dumps(record) + "\n")
        n += 1
print(n, file=sys.stderr)
'

# time_run NAME COMMAND...: runs COMMAND with its output to /dev/null, prints seconds and frames/s.
time_run() {
  local name=$1
  shift
  local start end
  start=$(date +%s.%N)
  "$@" >/dev/null 2>"$LOG.stderr" || [ $? -eq 1 ]
  end=$(date +%s.%N)
  awk -v name="$name" -v s="$start" -v e="$end" -v n="$FRAMES" \
    'BEGIN { printf "%-14s %8.2f s  %12.0f frames/s\n", name, e - s, n / (e - s) }'
}

echo
printf '%-14s %10s  %19s\n' "decoder" "wall time" "throughput"
time_run "lbv --json" "$LBV" decode can --json "$LOG"
grep -q "$FRAMES BAT frames decoded" "$LOG.stderr" || { cat "$LOG.stderr" >&2; exit 1; }
time_run "lbv" "$LBV" decode can "$LOG"
grep -q "$FRAMES BAT frames decoded" "$LOG.stderr" || { cat "$LOG.stderr" >&2; exit 1; }
time_run "cantools loop" python3 -c "$CANTOOLS_LOOP" "$DBC" "$LOG"
grep -qx "$FRAMES" "$LOG.stderr" || { cat "$LOG.stderr" >&2; exit 1; }
if [ "${SKIP_CANTOOLS_CLI:-0}" != 1 ]; then
  time_run "cantools CLI" sh -c 'python3 -m cantools decode --single-line "$1" < "$2"' sh "$DBC" "$LOG"
fi
rm -f "$LOG.stderr"
