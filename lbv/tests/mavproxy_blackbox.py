#!/usr/bin/env python3
"""The master's black box fetched with MAVProxy and read with pymavlink's mavlogdump.py, for
tests/integration/mavproxy.rs.

    mavproxy_blackbox.py GCS_PORT OBSERVER_PORT WORK_DIR [TIMEOUT_S]

MAVProxy headless on udpin:127.0.0.1:GCS_PORT (where `lbv bench --udp` sends), as mavproxy_pilot.py starts it;
pymavlink watches what the vehicle sends live on OBSERVER_PORT. The steps:

    connect    MAVProxy sees the vehicle
    ready      SYS_STATUS says the pre-arm check healthy (the master has asked its thrusters what they run)
    motortest  `motortest 1 0 10 2`: thruster 1 turns for 2 s (ESC telemetry), then stops
    blackbox   `ftp get @SYS/blackbox.tlog WORK_DIR/blackbox.tlog`, then `mavlogdump.py --format json` on the file:
               every frame reads (no BAD_DATA), and it holds the samples of the session at 10 Hz; thruster 1's rpm in
               ESC_TELEMETRY_1_TO_4 turns for 2 s of samples, its peak that of the live telemetry within a speed step

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
