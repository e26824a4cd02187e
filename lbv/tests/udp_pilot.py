#!/usr/bin/env python3
"""A pilot's pymavlink script flying the bench over UDP (`lbv bench --udp`), for tests/integration/udp_pymavlink.rs.

    udp_pilot.py GCS_PORT BENCH_PORT [TIMEOUT_S]

Listens on 127.0.0.1:GCS_PORT like a ground station (the bench sends there) and answers to where the vehicle's
datagrams come from, which must be 127.0.0.1:BENCH_PORT. Sends GCS heartbeats at 1 Hz throughout (the master
arms only with them and disarms 5 s after they stop), then: vehicle HEARTBEAT (submarine), AUTOPILOT_VERSION by
MAV_CMD_REQUEST_MESSAGE and by MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES (COMMAND_ACK 0 first; MAVLink 2, COMMAND_INT and
C_CAST parameters, the bench's unique id), FS_PILOT_INPUT read as INT8 and set as INT8 (taken) and as INT32
(refused: the value unchanged), SYS_STATUS's pre-arm check healthy, arm (COMMAND_ACK 0),
MANUAL_CONTROL x=700 z=500 at 10 Hz for 4 s with the SeaBotix thrusters (1 and 3) reporting rpm above 500 in
ESC_TELEMETRY_1_TO_4, disarm (COMMAND_ACK 0), a HEARTBEAT without the armed flag. Prints a JSON summary on
stdout; exit 0 when every step held, 1 with the reason on stderr when one did not (or time ran out), 3 when
pymavlink is missing.
"""
import json
import os
import sys
import time

os.environ["MAVLINK20"] = "1"
os.environ["MAVLINK_DIALECT"] = "ardupilotmega"
try:
    from pymavlink import mavutil
    from pymavlink.dialects.v20 import ardupilotmega as mav
except ImportError as error:
    print(f"pymavlink is missing ({error}): pip install pymavlink", file=sys.stderr)
    sys.exit(3)

VEHICLE_SYSTEM = 1
GCS_SYSTEM, GCS_COMPONENT = 255, 190
ARM_DISARM = 400
REQUEST_MESSAGE = 512
REQUEST_AUTOPILOT_CAPABILITIES = 520
# MAVLINK2 | COMMAND_INT | PARAM_ENCODE_C_CAST
CAPABILITIES = 0x2000 | 0x8 | 0x20000
PREARM_CHECK = 0x10000000
BENCH_UID = b"LBV bench 01"
AHEAD = dict(x=700, y=0, z=500, r=0)
STICK_SECONDS = 4.0
RPM_WANTED = 500
SEABOTIX = (0, 2)  # thrusters 1 and 3; the Legacy ones (2, 4) report current only


class Failed(Exception):
    pass


class Pilot:
    def __init__(self, gcs_port, bench_port, timeout):
        self.link = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{gcs_port}",
            dialect="ardupilotmega",
            source_system=GCS_SYSTEM,
            source_component=GCS_COMPONENT,
        )
        self.bench_port = bench_port
        self.start = time.monotonic()
        self.deadline = self.start + timeout
        self.next_heartbeat = 0.0
        self.sticks = None
        self.next_stick = 0.0
        self.armed = None
        self.heartbeats = 0
        self.vehicle_type = None
        self.acks = []
        self.rpm = [0, 0, 0, 0]
        self.current_ca = [0, 0, 0, 0]
        self.rpm_max = [0, 0, 0, 0]
        self.versions = []
        self.params = []
        self.prearm = []
        self.texts = []
        self.summary = {}

    def elapsed(self):
        return round(time.monotonic() - self.start, 2)

    def vehicle_addresses(self):
        """Where udpin answers: the senders seen (newer pymavlink keeps a set, older versions the last one)."""
        clients = getattr(self.link, "clients", None)
        if clients is not None:
            return sorted(clients)
        return [self.link.last_address] if self.link.last_address else []

    def send_due(self):
        """Heartbeats at 1 Hz (once the vehicle is known) and the sticks at 10 Hz while set."""
        if not self.vehicle_addresses():
            return  # nothing to answer to yet
        now = time.monotonic()
        if now >= self.next_heartbeat:
            self.next_heartbeat = now + 1.0
            self.link.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)
        if self.sticks is not None and now >= self.next_stick:
            self.next_stick = now + 0.1
            s = self.sticks
            self.link.mav.manual_control_send(VEHICLE_SYSTEM, s["x"], s["y"], s["z"], s["r"], 0)

    def handle(self, msg):
        if msg.get_srcSystem() != VEHICLE_SYSTEM:
            return
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self.heartbeats += 1
            self.vehicle_type = msg.type
            self.armed = bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
        elif kind == "COMMAND_ACK":
            self.acks.append((msg.command, msg.result))
            self.versions.append(("ack", msg.command, msg.result))
        elif kind == "AUTOPILOT_VERSION":
            self.versions.append(("version", msg))
        elif kind == "PARAM_VALUE":
            self.params.append(msg)
        elif kind == "SYS_STATUS":
            present = msg.onboard_control_sensors_present & msg.onboard_control_sensors_enabled & PREARM_CHECK
            self.prearm.append(bool(present) and bool(msg.onboard_control_sensors_health & PREARM_CHECK))
        elif kind == "STATUSTEXT":
            self.texts.append(msg.text)
        elif kind == "ESC_TELEMETRY_1_TO_4":
            self.rpm = list(msg.rpm)
            self.current_ca = list(msg.current)
            self.rpm_max = [max(a, b) for a, b in zip(self.rpm_max, self.rpm)]

    def pump(self, until, within, what):
        """Keep the link going (send what is due, read what came) until `until()` holds; fail after `within` s."""
        end = min(time.monotonic() + within, self.deadline)
        while True:
            self.send_due()
            if until():
                return
            if time.monotonic() >= end:
                late = "the overall time limit" if end == self.deadline else f"{within} s"
                raise Failed(f"{what}: not within {late}")
            msg = self.link.recv_match(blocking=True, timeout=0.02)
            while msg is not None:
                self.handle(msg)
                msg = self.link.recv_match(blocking=False)

    def wait_ack(self, command, what):
        seen = len(self.acks)
        self.pump(lambda: len(self.acks) > seen and any(c == command for c, _ in self.acks[seen:]), 3.0, what)
        result = next(r for c, r in self.acks[seen:] if c == command)
        if result != mav.MAV_RESULT_ACCEPTED:
            raise Failed(f"{what}: COMMAND_ACK result {result}, not 0 (accepted)")
        return result

    def autopilot_version(self, command, param1):
        """Ask AUTOPILOT_VERSION with `command`; the COMMAND_ACK (accepted) comes first, then the message."""
        seen = len(self.versions)
        self.link.mav.command_long_send(VEHICLE_SYSTEM, 1, command, 0, param1, 0, 0, 0, 0, 0, 0)
        self.pump(lambda: any(e[0] == "version" for e in self.versions[seen:]), 3.0, f"AUTOPILOT_VERSION ({command})")
        events = self.versions[seen:]
        first = next(i for i, e in enumerate(events) if e[0] == "version")
        acks = [e for e in events[:first] if e[0] == "ack" and e[1] == command]
        if not acks or acks[-1][2] != mav.MAV_RESULT_ACCEPTED:
            raise Failed(f"AUTOPILOT_VERSION ({command}) without an accepted COMMAND_ACK before it: {events}")
        v = events[first][1]
        uid2 = bytes(v.uid2)
        if v.capabilities != CAPABILITIES:
            raise Failed(f"capabilities {v.capabilities:#x}, not {CAPABILITIES:#x}")
        if uid2 != BENCH_UID + bytes(6):
            raise Failed(f"uid2 {uid2!r}, not {BENCH_UID!r}")
        return {
            "capabilities": v.capabilities,
            "flight_sw_version": v.flight_sw_version,
            "git": bytes(v.flight_custom_version).decode("latin-1"),
            "vendor_id": v.vendor_id,
            "product_id": v.product_id,
        }

    def param(self, name, send, what):
        seen = len(self.params)
        send()
        self.pump(lambda: any(p.param_id == name for p in self.params[seen:]), 3.0, what)
        return next(p for p in self.params[seen:] if p.param_id == name)

    def typed_parameter(self):
        """FS_PILOT_INPUT (INT8): read, set as INT8, set as INT32 (refused), restored."""
        name = "FS_PILOT_INPUT"
        read = self.param(name, lambda: self.link.mav.param_request_read_send(VEHICLE_SYSTEM, 1, name.encode(), -1), "PARAM_VALUE read")
        if read.param_type != mav.MAV_PARAM_TYPE_INT8:
            raise Failed(f"{name}: type {read.param_type}, not INT8")
        def set_as(value, param_type):
            return self.param(
                name,
                lambda: self.link.mav.param_set_send(VEHICLE_SYSTEM, 1, name.encode(), value, param_type),
                f"PARAM_VALUE after a set of type {param_type}",
            )
        taken = set_as(2, mav.MAV_PARAM_TYPE_INT8)
        texts = len(self.texts)
        refused = set_as(0, mav.MAV_PARAM_TYPE_INT32)
        restored = set_as(read.param_value, mav.MAV_PARAM_TYPE_INT8)
        result = {
            "read": [read.param_value, read.param_type],
            "set_int8": [taken.param_value, taken.param_type],
            "set_int32": [refused.param_value, refused.param_type],
            "restored": restored.param_value,
            "texts": self.texts[texts:],
        }
        if taken.param_value != 2 or refused.param_value != 2:
            raise Failed(f"{name}: {result}")
        return result

    def fly(self):
        self.pump(lambda: self.heartbeats > 0, 10.0, "the vehicle's HEARTBEAT")
        s = self.summary
        s["vehicle_type"] = self.vehicle_type
        addresses = [list(address) for address in self.vehicle_addresses()]
        s["vehicle_addresses"] = addresses
        if self.vehicle_type != mav.MAV_TYPE_SUBMARINE:
            raise Failed(f"HEARTBEAT type {self.vehicle_type}, not {mav.MAV_TYPE_SUBMARINE} (submarine)")
        if addresses != [["127.0.0.1", self.bench_port]]:
            raise Failed(f"the vehicle sends from {addresses}, not 127.0.0.1:{self.bench_port}")

        s["autopilot_version"] = self.autopilot_version(REQUEST_MESSAGE, 148)
        self.autopilot_version(REQUEST_AUTOPILOT_CAPABILITIES, 1)
        s["param_types"] = self.typed_parameter()

        seen = len(self.prearm)
        self.pump(lambda: any(self.prearm[seen:]), 5.0, "SYS_STATUS's pre-arm check healthy")
        s["prearm_healthy"] = True
        self.link.mav.command_long_send(VEHICLE_SYSTEM, 1, ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        s["arm_ack"] = self.wait_ack(ARM_DISARM, "arming")
        s["arm_at_s"] = self.elapsed()

        self.sticks = AHEAD
        self.next_stick = 0.0
        rpm_at_start = list(self.rpm)
        stop = time.monotonic() + STICK_SECONDS
        self.pump(lambda: time.monotonic() >= stop, STICK_SECONDS + 1.0, "the sticks ahead")
        s["rpm_before_sticks"] = rpm_at_start
        s["rpm_after_sticks"] = list(self.rpm)
        s["rpm_max"] = list(self.rpm_max)
        s["current_ca_after_sticks"] = list(self.current_ca)
        s["armed_while_flying"] = self.armed
        if not self.armed:
            raise Failed("the vehicle's HEARTBEAT says disarmed while flying (console failsafe?)")
        slow = [i + 1 for i in SEABOTIX if self.rpm[i] <= RPM_WANTED]
        if slow:
            raise Failed(f"SeaBotix thruster(s) {slow} report rpm {self.rpm}, not above {RPM_WANTED}")

        self.sticks = None
        self.link.mav.command_long_send(VEHICLE_SYSTEM, 1, ARM_DISARM, 0, 0, 0, 0, 0, 0, 0, 0)
        s["disarm_ack"] = self.wait_ack(ARM_DISARM, "disarming")
        beats = self.heartbeats
        self.pump(lambda: self.heartbeats > beats and not self.armed, 3.0, "a HEARTBEAT without the armed flag")
        s["disarmed_heartbeat"] = True
        s["elapsed_s"] = self.elapsed()


def main():
    if len(sys.argv) < 3:
        print(__doc__, file=sys.stderr)
        return 2
    gcs_port, bench_port = int(sys.argv[1]), int(sys.argv[2])
    timeout = float(sys.argv[3]) if len(sys.argv) > 3 else 30.0
    pilot = Pilot(gcs_port, bench_port, timeout)
    try:
        pilot.fly()
    except Failed as failure:
        pilot.summary.update(failed=str(failure), elapsed_s=pilot.elapsed(), acks=pilot.acks, rpm=pilot.rpm)
        print(json.dumps(pilot.summary))
        print(f"udp_pilot: {failure}", file=sys.stderr)
        return 1
    pilot.summary["passed"] = True
    print(json.dumps(pilot.summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
