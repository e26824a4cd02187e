#!/usr/bin/env python3
"""A pilot flying the bench with MAVProxy, a real ground station, for tests/integration/mavproxy.rs.

    mavproxy_pilot.py GCS_PORT OBSERVER_PORT [TIMEOUT_S]

Starts MAVProxy headless on udpin:127.0.0.1:GCS_PORT (where `lbv bench --udp` sends) with its own defaults
(modules, 1 Hz heartbeats, its parameter download) and types the pilot's commands on its stdin, as a person at
its prompt would. MAVProxy forwards what the vehicle sends to OBSERVER_PORT, where pymavlink watches every
message for the detailed checks (it never sends). The steps:

    connect        MAVProxy sees the vehicle (HEARTBEAT of a submarine)
    params         MAVProxy's own parameter download gets all 64 over FTP (`@PARAM/param.pck`, decoded by
                   MAVProxy); then `param fetch` without FTP: the PARAM_VALUE list has the same values, each with
                   its type: ArduSub's for the ArduSub names (the timeouts and the read-only sensor offsets REAL32,
                   SYSID_MYGCS and SERVOn_FUNCTION INT16, the compass ids INT32), INT8 for the others
    version        `version`: MAV_CMD_REQUEST_MESSAGE AUTOPILOT_VERSION is accepted and answered (MAVLink 2,
                   COMMAND_INT and C_CAST parameters, no mission or FTP, the bench's unique id)
    plans          `wp list`, `fence list`, `rally list`: MAVProxy asks for each plan and is told it holds
                   nothing ("Requesting 0 waypoints", "0 fence items", "0 rally items"); `wp clear`: MISSION_ACK
                   accepted, of the mission type
    param set      `param set LBV_GAIN 80`: the vehicle answers PARAM_VALUE 80
    arm            `arm throttle`: COMMAND_ACK accepted, HEARTBEAT armed
    hold           8 s armed with nothing from the pilot: every HEARTBEAT armed, no failsafe text (MAVProxy sends
                   its 1 Hz heartbeats and nothing that steers)
    disarm         `disarm`: COMMAND_ACK accepted, HEARTBEAT disarmed
    reboot         `reboot`: COMMAND_ACK accepted, "Rebooting", then the master starts again (its sequence numbers
                   start over and it finds its thrusters again: "T1 online")
    persisted      `param fetch LBV_GAIN` after the reboot: still 80 (read from the master's flash)
    motortest      `motortest 1 0 10 2`: COMMAND_ACK accepted, thruster 1 turns (ESC telemetry), stops after 2 s

Prints a JSON summary on stdout; exit 0 when every step held, 1 with the reason on stderr when one did not (or
time ran out), 3 when pymavlink or MAVProxy is missing. Further steps go in STEPS.
"""
import json
import os
import queue
import shutil
import subprocess
import sys
import tempfile
import threading
import time

os.environ["MAVLINK20"] = "1"
try:
    from pymavlink import mavutil
    from pymavlink.dialects.v20 import ardupilotmega as mav
except ImportError as error:
    print(f"pymavlink is missing ({error}): pip install pymavlink", file=sys.stderr)
    sys.exit(3)

VEHICLE = 1
# The 27 settings and the 37 read-only stand-ins for ArduSub's (lbv-master-fw's params::STAND_INS).
PARAMS = 64
HOLD_S = 8.0


def param_type(name):
    """A parameter's MAVLink type, as ArduSub declares the parameter of that name (AP_Float, AP_Vector3f, AP_Int16,
    AP_Int32), INT8 for the rest."""
    floats = ("FS_GCS_TIMEOUT", "FS_PILOT_TIMEOUT", "COMPASS_DEC")
    if name in floats or name.startswith(("INS_ACCOFFS_", "COMPASS_OFS")):
        return mav.MAV_PARAM_TYPE_REAL32
    if name == "SYSID_MYGCS" or (name.startswith("SERVO") and name.endswith("_FUNCTION")):
        return mav.MAV_PARAM_TYPE_INT16
    if name.startswith("COMPASS_DEV_ID"):
        return mav.MAV_PARAM_TYPE_INT32
    return mav.MAV_PARAM_TYPE_INT8


# AUTOPILOT_VERSION: MAVLINK2 | COMMAND_INT | PARAM_ENCODE_C_CAST, and the unique id `lbv bench` gives its master.
CAPABILITIES = 0x2000 | 0x8 | 0x20000
BENCH_UID = b"LBV bench 01"


class Failed(Exception):
    pass


class Observer:
    """pymavlink on MAVProxy's output: every message the vehicle sends, with the time it came."""

    def __init__(self, port):
        self.link = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="ardupilotmega")
        self.messages = []  # (time, message)

    def pump(self):
        msg = self.link.recv_match(blocking=True, timeout=0.05)
        while msg is not None:
            if msg.get_srcSystem() == VEHICLE and msg.get_type() != "BAD_DATA":
                self.messages.append((time.monotonic(), msg))
            msg = self.link.recv_match(blocking=False)

    def since(self, start, kind):
        return [(t, m) for t, m in self.messages if t >= start and m.get_type() == kind]

    def armed(self, since=0.0):
        beats = self.since(since, "HEARTBEAT")
        return bool(beats) and bool(beats[-1][1].base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)

    def texts(self, since=0.0):
        return [m.text for _, m in self.since(since, "STATUSTEXT")]


class MavProxy:
    """MAVProxy at its prompt: commands on stdin, every line it prints kept with its time."""

    def __init__(self, gcs_port, observer_port, state_dir):
        try:
            import MAVProxy  # noqa: F401
        except ImportError as error:
            print(f"MAVProxy is missing ({error}): pip install mavproxy", file=sys.stderr)
            sys.exit(3)
        self.process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "MAVProxy.mavproxy",
                f"--master=udpin:127.0.0.1:{gcs_port}",
                f"--out=udpout:127.0.0.1:{observer_port}",
                f"--state-basedir={state_dir}",
                "--no-state",
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
            cwd=state_dir,
        )
        self.lines = queue.Queue()
        self.log = []  # (time, line)
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.process.stdout:
            self.lines.put((time.monotonic(), line.rstrip()))

    def drain(self):
        while True:
            try:
                self.log.append(self.lines.get_nowait())
            except queue.Empty:
                return

    def type(self, command):
        self.process.stdin.write(command + "\n")
        self.process.stdin.flush()

    def said(self, needle, since=0.0):
        return any(needle in line for t, line in self.log if t >= since)

    def stop(self):
        try:
            self.type("exit")
            self.process.wait(timeout=5)
        except Exception:
            self.process.kill()
            self.process.wait()


class Pilot:
    def __init__(self, gcs_port, observer_port, timeout):
        self.state_dir = tempfile.mkdtemp(prefix="mavproxy-pilot-")
        self.observer = Observer(observer_port)
        self.mavproxy = MavProxy(gcs_port, observer_port, self.state_dir)
        self.start = time.monotonic()
        self.deadline = self.start + timeout
        self.summary = {}

    def elapsed(self):
        return round(time.monotonic() - self.start, 2)

    def wait(self, done, within, what):
        """Keep reading both sides until `done()` holds; fail after `within` s."""
        end = min(time.monotonic() + within, self.deadline)
        while True:
            self.observer.pump()
            self.mavproxy.drain()
            if done():
                return
            if self.mavproxy.process.poll() is not None:
                raise Failed(f"{what}: MAVProxy exited ({self.mavproxy.process.returncode})")
            if time.monotonic() >= end:
                late = "the overall time limit" if end == self.deadline else f"{within} s"
                raise Failed(f"{what}: not within {late}")

    def ack(self, command, since):
        acks = [m for _, m in self.observer.since(since, "COMMAND_ACK") if m.command == command]
        return acks[-1].result if acks else None

    # The steps, in order.

    def connect(self):
        self.wait(lambda: self.mavproxy.said("Detected vehicle 1:1"), 20.0, "MAVProxy sees the vehicle")
        beats = self.observer.since(0.0, "HEARTBEAT")
        self.wait(lambda: self.observer.since(0.0, "HEARTBEAT"), 5.0, "the observer sees the vehicle")
        beats = self.observer.since(0.0, "HEARTBEAT")
        if beats[-1][1].type != mav.MAV_TYPE_SUBMARINE:
            raise Failed(f"HEARTBEAT type {beats[-1][1].type}, not a submarine")

    def params(self):
        # MAVProxy asks for `@PARAM/param.pck?withdefaults=1` over FTP first and decodes it itself.
        self.wait(
            lambda: self.mavproxy.said(f"Received {PARAMS} parameters (ftp)"), 30.0, "MAVProxy's download over FTP"
        )
        self.summary["params_at_s"] = self.elapsed()
        shown = time.monotonic()
        self.mavproxy.type("param show *")
        ftp = {}

        def all_shown():
            for t, line in self.mavproxy.log:
                # "NAME value", the first after MAVProxy's prompt.
                words = line.split()[-2:]
                if t >= shown and len(words) == 2 and words[0].isupper():
                    try:
                        ftp[words[0]] = float(words[1])
                    except ValueError:
                        pass
            return len(ftp) == PARAMS

        self.wait(all_shown, 5.0, "`param show *` of the parameters MAVProxy read over FTP")
        # The list the slow way (MAVProxy's `param fetch` without FTP: PARAM_REQUEST_LIST), each PARAM_VALUE with
        # its type, and each value what MAVProxy read in the file.
        fetched = time.monotonic()
        self.mavproxy.type("set param_ftp 0")
        self.mavproxy.type("param fetch")

        def listed():
            return {m.param_id: m for _, m in self.observer.since(fetched, "PARAM_VALUE")}

        self.wait(lambda: len(listed()) == PARAMS, 10.0, "the parameter list")
        types = {name: m.param_type for name, m in listed().items()}
        self.summary["param_types"] = types
        for name, declared in types.items():
            if declared != param_type(name):
                raise Failed(f"PARAM_VALUE {name}: type {declared}, not {param_type(name)}")
        values = {name: round(m.param_value, 4) for name, m in listed().items()}
        self.summary["ftp_params"] = ftp
        if {name: round(value, 4) for name, value in ftp.items()} != values:
            raise Failed(f"param.pck read by MAVProxy {ftp} is not the list {values}")
        # The list cost MAVProxy 64 frames of its 80-frame allowance (lbv-master-fw's console::limit, 10 frames a
        # second back): a pilot's next requests come seconds later, and so do the next steps'.
        rested = time.monotonic() + 3.0
        self.wait(lambda: time.monotonic() >= rested, 4.0, "the allowance refilled")

    def version(self):
        since = time.monotonic()
        self.mavproxy.type("version")
        self.wait(lambda: self.observer.since(since, "AUTOPILOT_VERSION"), 5.0, "AUTOPILOT_VERSION")
        result = self.ack(mav.MAV_CMD_REQUEST_MESSAGE, since)
        if result != mav.MAV_RESULT_ACCEPTED:
            raise Failed(f"REQUEST_MESSAGE AUTOPILOT_VERSION: COMMAND_ACK result {result}")
        v = self.observer.since(since, "AUTOPILOT_VERSION")[-1][1]
        uid2 = bytes(v.uid2)
        self.summary["version"] = {
            "capabilities": v.capabilities,
            "flight_sw_version": v.flight_sw_version,
            "git": bytes(v.flight_custom_version).decode("latin-1"),
            "vendor_id": v.vendor_id,
            "product_id": v.product_id,
            "uid2": uid2[:12].decode("latin-1"),
        }
        if v.capabilities != CAPABILITIES:
            raise Failed(f"capabilities {v.capabilities:#x}, not {CAPABILITIES:#x}")
        if v.flight_sw_version == 0:
            raise Failed("flight_sw_version is 0")
        if uid2 != BENCH_UID + bytes(6):
            raise Failed(f"uid2 {uid2!r}, not the bench's {BENCH_UID!r}")

    def plans(self):
        since = time.monotonic()
        for plan, items in [("wp", "waypoints"), ("fence", "fence items"), ("rally", "rally items")]:
            self.mavproxy.type(f"{plan} list")
            self.wait(lambda: self.mavproxy.said(f"Requesting 0 {items}", since), 5.0, f"MAVProxy's `{plan} list`")
        cleared = time.monotonic()
        self.mavproxy.type("wp clear")
        self.wait(lambda: self.observer.since(cleared, "MISSION_ACK"), 5.0, "the MISSION_ACK of `wp clear`")
        ack = self.observer.since(cleared, "MISSION_ACK")[-1][1]
        self.summary["plans"] = {"clear": [ack.type, ack.mission_type]}
        if (ack.type, ack.mission_type) != (mav.MAV_MISSION_ACCEPTED, mav.MAV_MISSION_TYPE_MISSION):
            raise Failed(f"`wp clear`: MISSION_ACK {ack.type} of mission type {ack.mission_type}")

    def param_set(self):
        since = time.monotonic()
        self.mavproxy.type("param set LBV_GAIN 80")

        def answered():
            values = [m for _, m in self.observer.since(since, "PARAM_VALUE") if m.param_id == "LBV_GAIN"]
            return values and values[-1].param_value == 80.0

        self.wait(answered, 5.0, "PARAM_VALUE LBV_GAIN 80")
        value = [m for _, m in self.observer.since(since, "PARAM_VALUE") if m.param_id == "LBV_GAIN"][-1]
        self.summary["param_set"] = {"index": value.param_index, "count": value.param_count}
        if value.param_count != PARAMS:
            raise Failed(f"PARAM_VALUE param_count {value.param_count}, not {PARAMS}")

    def arm(self):
        since = time.monotonic()
        self.mavproxy.type("arm throttle")
        self.wait(lambda: self.ack(mav.MAV_CMD_COMPONENT_ARM_DISARM, since) is not None, 5.0, "the arm's COMMAND_ACK")
        result = self.ack(mav.MAV_CMD_COMPONENT_ARM_DISARM, since)
        if result != mav.MAV_RESULT_ACCEPTED:
            raise Failed(f"arm: COMMAND_ACK result {result}")
        self.wait(lambda: self.observer.armed(since), 3.0, "a HEARTBEAT that says armed")
        self.wait(lambda: self.mavproxy.said("ARMED", since), 3.0, "MAVProxy says ARMED")
        self.summary["armed_at_s"] = self.elapsed()

    def hold(self):
        since = time.monotonic()
        end = since + HOLD_S
        self.wait(lambda: time.monotonic() >= end, HOLD_S + 1.0, "holding armed")
        beats = self.observer.since(since, "HEARTBEAT")
        armed = [bool(m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED) for _, m in beats]
        self.summary["hold"] = {"seconds": HOLD_S, "heartbeats": len(armed), "all_armed": all(armed)}
        if len(armed) < HOLD_S - 1:
            raise Failed(f"only {len(armed)} vehicle heartbeats in {HOLD_S} s")
        if not all(armed):
            raise Failed(f"disarmed while MAVProxy was connected: {armed}; texts {self.observer.texts(since)}")
        failsafes = [t for t in self.observer.texts(since) if "Failsafe" in t]
        if failsafes:
            raise Failed(f"failsafe while MAVProxy was connected: {failsafes}")
        if self.mavproxy.said("fence breach"):
            raise Failed("MAVProxy reports a fence breach: SYS_STATUS must show the absent fence healthy")

    def disarm(self):
        since = time.monotonic()
        self.mavproxy.type("disarm")
        self.wait(lambda: self.ack(mav.MAV_CMD_COMPONENT_ARM_DISARM, since) is not None, 5.0, "the disarm's COMMAND_ACK")
        result = self.ack(mav.MAV_CMD_COMPONENT_ARM_DISARM, since)
        if result != mav.MAV_RESULT_ACCEPTED:
            raise Failed(f"disarm: COMMAND_ACK result {result}")
        self.wait(lambda: not self.observer.armed(since) and self.observer.since(since, "HEARTBEAT"), 3.0, "a disarmed HEARTBEAT")

    def reboot(self):
        since = time.monotonic()
        self.mavproxy.type("reboot")
        self.wait(
            lambda: self.ack(mav.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, since) is not None, 5.0, "the reboot's COMMAND_ACK"
        )
        result = self.ack(mav.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, since)
        if result != mav.MAV_RESULT_ACCEPTED:
            raise Failed(f"reboot: COMMAND_ACK result {result}")

        def restarted():
            texts = self.observer.texts(since)
            return "Rebooting" in texts and "T1 online" in texts[texts.index("Rebooting") :]

        self.wait(restarted, 10.0, "the master starting again")
        # A fresh master numbers its frames from 0 again.
        sequences = [m.get_seq() for t, m in self.observer.messages if t >= since]
        restarts = sum(1 for a, b in zip(sequences, sequences[1:]) if b != (a + 1) % 256)
        self.summary["reboot"] = {"texts": self.observer.texts(since)[:6], "sequence_restarts": restarts}
        if restarts < 1:
            raise Failed("the master's sequence numbers did not start over")
        self.wait(lambda: self.observer.since(since, "HEARTBEAT") and not self.observer.armed(since), 3.0, "a disarmed HEARTBEAT")
        # The fresh master takes commands once it has heard the ground station: MAVProxy's next 1 Hz heartbeat.
        heard = time.monotonic() + 1.5
        self.wait(lambda: time.monotonic() >= heard, 2.0, "MAVProxy's next heartbeat")

    def persisted(self):
        since = time.monotonic()
        self.mavproxy.type("param fetch LBV_GAIN")

        def answered():
            return [m for _, m in self.observer.since(since, "PARAM_VALUE") if m.param_id == "LBV_GAIN"]

        self.wait(answered, 5.0, "PARAM_VALUE LBV_GAIN after the reboot")
        value = answered()[-1].param_value
        self.summary["persisted"] = {"LBV_GAIN": value}
        if value != 80.0:
            raise Failed(f"LBV_GAIN is {value} after the reboot, not the 80 set before it")

    def motortest(self):
        since = time.monotonic()
        # Thruster 1, throttle type 0 (percent), 10 %, 2 s.
        self.mavproxy.type("motortest 1 0 10 2")
        self.wait(lambda: self.ack(mav.MAV_CMD_DO_MOTOR_TEST, since) is not None, 5.0, "the motor test's COMMAND_ACK")
        result = self.ack(mav.MAV_CMD_DO_MOTOR_TEST, since)
        if result != mav.MAV_RESULT_ACCEPTED:
            raise Failed(f"motortest: COMMAND_ACK result {result}")

        def turned():
            return any(m.rpm[0] > 100 for _, m in self.observer.since(since, "ESC_TELEMETRY_1_TO_4"))

        self.wait(turned, 3.0, "thruster 1 turning")
        self.wait(lambda: "Motor test 1 done" in self.observer.texts(since), 4.0, "the motor test's end")
        texts = self.observer.texts(since)
        self.summary["motortest"] = {
            "texts": texts,
            "peak_rpm": max(m.rpm[0] for _, m in self.observer.since(since, "ESC_TELEMETRY_1_TO_4")),
        }

    STEPS = [
        "connect",
        "params",
        "version",
        "plans",
        "param_set",
        "arm",
        "hold",
        "disarm",
        "reboot",
        "persisted",
        "motortest",
    ]

    def fly(self):
        for step in self.STEPS:
            getattr(self, step)()
            self.summary.setdefault("steps", []).append(step)
        self.summary["elapsed_s"] = self.elapsed()


def run(pilot, name):
    """Fly `pilot`'s steps and print its JSON summary: the exit status (0 every step held, 1 one did not)."""
    try:
        pilot.fly()
    except Failed as failure:
        pilot.mavproxy.drain()
        pilot.summary.update(failed=str(failure), elapsed_s=pilot.elapsed())
        pilot.summary["mavproxy"] = [line for _, line in pilot.mavproxy.log][-40:]
        print(json.dumps(pilot.summary))
        print(f"{name}: {failure}", file=sys.stderr)
        return 1
    finally:
        pilot.mavproxy.stop()
        shutil.rmtree(pilot.state_dir, ignore_errors=True)
    pilot.summary["passed"] = True
    print(json.dumps(pilot.summary))
    return 0


def main():
    if len(sys.argv) < 3:
        print(__doc__, file=sys.stderr)
        return 2
    gcs_port, observer_port = int(sys.argv[1]), int(sys.argv[2])
    timeout = float(sys.argv[3]) if len(sys.argv) > 3 else 90.0
    return run(Pilot(gcs_port, observer_port, timeout), "mavproxy_pilot")


if __name__ == "__main__":
    sys.exit(main())
