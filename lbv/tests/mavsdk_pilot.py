#!/usr/bin/env python3
"""MAVSDK, an SDK's own MAVLink implementation, against the bench, for tests/integration/mavsdk.rs.

    mavsdk_pilot.py GCS_PORT [TIMEOUT_S]

Listens on udpin://127.0.0.1:GCS_PORT (where `lbv bench --udp` sends) as the operator's ground station (system
255, component 190: the master takes settings from SYSID_MYGCS only) and runs MAVSDK's plugins, C++ behind a
Python binding:

    connect        MAVSDK finds the autopilot (the master's HEARTBEAT)
    mission        MissionRaw.download_mission(): an empty list, with no retry logged (the master answers
                   MISSION_COUNT 0 at once, so the SDK waits for no timeout)
    params         Param.get_all_params(): the 27 settings and 37 read-only stand-ins, each of the kind (integer
                   or float) MAVSDK decodes from its type
    param_set      set_param_int LBV_GAIN 60: taken; set_param_int FLTMODE1 0: refused, MAVSDK reads the value
                   unchanged (19) and gives up without waiting for its timeout

Prints a JSON summary on stdout; exit 0 when every step held, 1 with the reason on stderr when one did not, 3 when
MAVSDK (the `mavsdk` package) is missing.
"""
import json
import sys
import time

try:
    from mavsdk import Configuration, LogLevel, Mavsdk, log_subscribe
    from mavsdk.plugins.mission_raw import MissionRaw
    from mavsdk.plugins.param import Param, ParamError
except ImportError as error:
    print(f"MAVSDK is missing ({error}): pip install mavsdk", file=sys.stderr)
    sys.exit(3)

OPERATOR = (255, 190)
SETTINGS = 27
STAND_INS = 37
# The stand-ins MAVSDK reads as floats (ArduSub's REAL32: the accelerometer's and compasses' offsets, the
# declination) and the settings' two timeouts.
FLOATS = 15


class Failed(Exception):
    pass


class Pilot:
    STEPS = ["connect", "mission", "params", "param_set"]

    def __init__(self, gcs_port, timeout):
        self.gcs_port = gcs_port
        self.timeout = timeout
        self.start = time.monotonic()
        self.summary = {}
        self.logs = []  # (time, level, message) of every line MAVSDK logs
        log_subscribe(lambda level, message, *_: self.logs.append((time.monotonic(), level, message)))
        self.mavsdk = Mavsdk(Configuration.create_manual(*OPERATOR, True))
        self.system = None

    def elapsed(self):
        return round(time.monotonic() - self.start, 2)

    def warnings(self, since):
        return [message for t, level, message in self.logs if t >= since and level >= LogLevel.WARN]

    def connect(self):
        result = self.mavsdk.add_any_connection(f"udpin://127.0.0.1:{self.gcs_port}")
        if int(result) != 0:
            raise Failed(f"add_any_connection: {result}")
        self.system = self.mavsdk.first_autopilot(min(20.0, self.timeout))
        if self.system is None:
            raise Failed("MAVSDK found no autopilot")
        self.summary["connected_at_s"] = self.elapsed()

    def mission(self):
        since = time.monotonic()
        items = MissionRaw(self.system).download_mission()
        took = time.monotonic() - since
        self.summary["mission"] = {"items": len(items), "ms": round(took * 1000), "warnings": self.warnings(since)}
        if items:
            raise Failed(f"download_mission: {len(items)} items, not none")
        if self.warnings(since):
            raise Failed(f"download_mission retried: {self.warnings(since)}")

    def params(self):
        every = Param(self.system).get_all_params()
        ints = {p.name: p.value for p in every.int_params}
        floats = {p.name: p.value for p in every.float_params}
        self.summary["params"] = {"int": len(ints), "float": len(floats)}
        if (len(ints) + len(floats), len(floats)) != (SETTINGS + STAND_INS, FLOATS):
            raise Failed(f"get_all_params: {len(ints)} integers and {len(floats)} floats")
        expected = {
            "BTN6_FUNCTION": (ints, 3),
            "FLTMODE1": (ints, 19),
            "COMPASS_DEV_ID": (ints, 0),
            "BATT_MONITOR": (ints, -1),
            "INS_ACCOFFS_X": (floats, 0.0),
            "FS_GCS_TIMEOUT": (floats, 5.0),
        }
        for name, (kind, value) in expected.items():
            if kind.get(name) != value:
                raise Failed(f"{name}: {kind.get(name)}, not {value}")

    def param_set(self):
        param = Param(self.system)
        param.set_param_int("LBV_GAIN", 60)
        gain = param.get_param_int("LBV_GAIN")
        since = time.monotonic()
        try:
            param.set_param_int("FLTMODE1", 0)
            refused = None
        except ParamError as error:  # the vehicle kept its value
            refused = str(error)
        took = time.monotonic() - since
        mode = param.get_param_int("FLTMODE1")
        told = [message for t, _, message in self.logs if t >= since and "FLTMODE1: read-only" in message]
        self.summary["param_set"] = {
            "gain": gain,
            "read_only": {"refused": refused, "value": mode, "told": bool(told), "ms": round(took * 1000)},
        }
        if gain != 60:
            raise Failed(f"LBV_GAIN {gain} after set_param_int 60")
        if refused is None or mode != 19 or not told:
            raise Failed(f"FLTMODE1 set to 0: {self.summary['param_set']}")

    def fly(self):
        for step in self.STEPS:
            getattr(self, step)()
            self.summary.setdefault("steps", []).append(step)
        self.summary["elapsed_s"] = self.elapsed()


def main():
    if len(sys.argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    timeout = float(sys.argv[2]) if len(sys.argv) > 2 else 60.0
    pilot = Pilot(int(sys.argv[1]), timeout)
    try:
        pilot.fly()
    except Failed as failure:
        pilot.summary.update(failed=str(failure), elapsed_s=pilot.elapsed())
        pilot.summary["mavsdk"] = [message for _, _, message in pilot.logs][-30:]
        print(json.dumps(pilot.summary))
        print(f"mavsdk_pilot: {failure}", file=sys.stderr)
        return 1
    finally:
        pilot.mavsdk.destroy()
    pilot.summary["passed"] = True
    print(json.dumps(pilot.summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
