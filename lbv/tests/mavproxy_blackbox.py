#!/usr/bin/env python3
"""The master's black box fetched with MAVProxy and read with pymavlink's mavlogdump.py, for
tests/integration/mavproxy.rs.

    mavproxy_blackbox.py GCS_PORT OBSERVER_PORT WORK_DIR [TIMEOUT_S]

MAVProxy headless on udpin:127.0.0.1:GCS_PORT (where `lbv bench --udp --trace WORK_DIR/trace.jsonl` sends), as
mavproxy_pilot.py starts it; pymavlink watches what the vehicle sends live on OBSERVER_PORT. The steps:

    connect    MAVProxy sees the vehicle
    ready      SYS_STATUS says the pre-arm check healthy (the master has asked its thrusters what they run)
    motortest  `motortest 1 0 10 2`: thruster 1 turns for 2 s (ESC telemetry), then stops
    blackbox   `ftp get @SYS/blackbox.tlog WORK_DIR/blackbox.tlog`, then `mavlogdump.py --format json` on the file:
               every frame reads (no BAD_DATA), and it holds the samples of the session at 10 Hz; thruster 1's rpm in
               ESC_TELEMETRY_1_TO_4 turns for 2 s of samples, its peak that of the live telemetry within a speed step;
               and each sample's rpm, of every thruster, is the bench's own (its trace: what the motors did) within
               1.5 speed steps, over the 0.3 s around the sample's time

Prints a JSON summary; exit 0 when every step held, 1 with the reason on stderr when one did not, 3 when pymavlink
or MAVProxy is missing.
"""
import json
import os
import shutil
import subprocess
import sys

from mavproxy_pilot import Failed, Pilot, run

# A speed step of a SeaBotix status: 4500 rpm over 102 steps.
STEP_RPM = 4500 / 102
# SERVO_OUTPUT_RAW's neutral, the black box's order for a stop.
NEUTRAL_US = 1500


def against_the_bench(read, trace_path):
    """Each black-box sample's rpm against the bench's trace: (samples compared, worst excess in rpm, the first one
    out of bounds or None). The log's clock starts at its first sample and the bench's at its start: the first
    sample whose order is not a stop is put at the bench's first such order. That sample may be up to 100 ms late
    (ten samples a second), a thruster's report up to one poll (20 ms) old: each sample is held to the bench's rpm
    from 100 ms before its time to 200 ms after."""
    trace = []
    with open(trace_path) as lines:
        for line in lines:
            try:
                trace.append(json.loads(line))
            except json.JSONDecodeError:
                break  # the line the bench is writing
    samples = {}
    for message in read:
        kind, at = message["meta"]["type"], round(message["meta"]["timestamp"], 3)
        if kind == "SERVO_OUTPUT_RAW":
            samples.setdefault(at, {})["order"] = message["data"]["servo1_raw"]
        elif kind == "ESC_TELEMETRY_1_TO_4":
            samples.setdefault(at, {})["rpm"] = message["data"]["rpm"]
        elif kind == "ESC_TELEMETRY_5_TO_8":
            samples.setdefault(at, {})["rpm_5_to_8"] = message["data"]["rpm"]
    samples = sorted((t, s) for t, s in samples.items() if "order" in s and "rpm" in s)
    ordered = [t for t, s in samples if s["order"] != NEUTRAL_US]
    bench_ordered = [s["t"] for s in trace if s["thrusters"][0]["ordered_step"] != 0]
    if not ordered or not bench_ordered:
        raise Failed(f"no order in the log ({len(ordered)}) or the bench's trace ({len(bench_ordered)})")
    offset = bench_ordered[0] - ordered[0]
    compared, worst, out = 0, 0.0, None
    for t, sample in samples:
        at = t + offset
        window = [s for s in trace if at - 0.1 <= s["t"] <= at + 0.2]
        if not window or window[-1]["t"] < at + 0.19:
            continue  # before the bench's trace begins, or after it ends
        thrusters = len(window[0]["thrusters"])
        for n, rpm in enumerate((sample["rpm"] + sample.get("rpm_5_to_8", []))[:thrusters]):
            bench = [abs(s["thrusters"][n]["rpm"]) for s in window]
            excess = max(min(bench) - rpm, rpm - max(bench), 0.0)
            worst = max(worst, excess)
            if excess > 1.5 * STEP_RPM and out is None:
                out = f"T{n + 1} at {t:.1f} s of the log: {rpm} rpm, the bench's {min(bench):.0f}..{max(bench):.0f}"
        compared += 1
    return compared, round(worst, 1), out


class BlackBoxPilot(Pilot):
    def __init__(self, gcs_port, observer_port, work_dir, timeout):
        super().__init__(gcs_port, observer_port, timeout)
        self.work_dir = work_dir

    def ready(self):
        """The vehicle would arm: the master has asked each thruster what it runs, and takes a motor test."""

        def armable():
            statuses = self.observer.since(0.0, "SYS_STATUS")
            # MAV_SYS_STATUS_PREARM_CHECK (1 << 28) healthy.
            return bool(statuses) and bool(statuses[-1][1].onboard_control_sensors_health & 1 << 28)

        self.wait(armable, 15.0, "the pre-arm check healthy")

    def blackbox(self):
        path = os.path.join(self.work_dir, "blackbox.tlog")
        since = self.elapsed()
        self.mavproxy.type(f"ftp get @SYS/blackbox.tlog {path}")
        self.wait(lambda: self.mavproxy.said(f"bytes to {path}"), 60.0, "the black box fetched")
        # MAVProxy says how much it wrote before it has closed the file: read it once it is all there.
        said = [line for _, line in self.mavproxy.log if f"bytes to {path}" in line][-1]
        wrote = int(said.split("Wrote ")[1].split()[0])
        self.wait(lambda: os.path.getsize(path) >= wrote, 5.0, "the black box whole on disk")
        tool = shutil.which("mavlogdump.py")
        if tool is None:
            raise Failed("mavlogdump.py is not on PATH (pymavlink installs it)")
        dump = subprocess.run(
            [sys.executable, tool, "--format", "json", path], capture_output=True, text=True, timeout=60
        )
        if dump.returncode != 0:
            raise Failed(f"mavlogdump.py: {dump.stderr.strip()}")
        read = [json.loads(line) for line in dump.stdout.splitlines() if line.startswith("{")]
        kinds = {}
        for message in read:
            kind = message["meta"]["type"]
            kinds[kind] = kinds.get(kind, 0) + 1
        if "BAD_DATA" in kinds or not read:
            raise Failed(f"mavlogdump.py read {kinds}")
        telemetry = [m["data"] for m in read if m["meta"]["type"] == "ESC_TELEMETRY_1_TO_4"]
        turning = [t["rpm"][0] for t in telemetry if t["rpm"][0] > 100]
        live_peak = self.summary["motortest"]["peak_rpm"]
        self.summary["blackbox"] = {
            "bytes": os.path.getsize(path),
            "messages": kinds,
            "samples": kinds.get("HEARTBEAT", 0),
            "turning_samples": len(turning),
            "peak_rpm": max(turning, default=0),
            "live_peak_rpm": live_peak,
            "fetched_after_s": round(self.elapsed() - since, 2),
        }
        # Every sample has its HEARTBEAT and its telemetry of the first four thrusters.
        if kinds.get("ESC_TELEMETRY_1_TO_4") != kinds.get("HEARTBEAT"):
            raise Failed(f"samples without their telemetry: {kinds}")
        # The motor test's 2 s at ten samples a second (the first and last may fall either side).
        if not 18 <= len(turning) <= 22:
            raise Failed(f"thruster 1 turns in {len(turning)} samples, not 2 s of them")
        if abs(max(turning) - live_peak) > STEP_RPM:
            raise Failed(f"peak rpm {max(turning)} in the log, {live_peak} live")
        compared, worst, out = against_the_bench(read, os.path.join(self.work_dir, "trace.jsonl"))
        self.summary["blackbox"].update(held_to_the_bench=compared, worst_rpm_off=worst)
        if out is not None:
            raise Failed(f"the black box is not the bench: {out}")
        if compared < kinds.get("HEARTBEAT", 0) - 5:
            raise Failed(f"{compared} of {kinds.get('HEARTBEAT', 0)} samples held to the bench's trace")

    STEPS = ["connect", "ready", "motortest", "blackbox"]


def main():
    if len(sys.argv) < 4:
        print(__doc__, file=sys.stderr)
        return 2
    gcs_port, observer_port, work_dir = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
    timeout = float(sys.argv[4]) if len(sys.argv) > 4 else 90.0
    return run(BlackBoxPilot(gcs_port, observer_port, work_dir, timeout), "mavproxy_blackbox")


if __name__ == "__main__":
    sys.exit(main())
