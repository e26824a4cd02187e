#!/usr/bin/env python3
"""Field update over MAVLink FTP with pymavlink's own client (pymavlink.mavftp), for tests/integration/udp_ftp.rs.

    ftp_upload.py GCS_PORT BENCH_PORT WORK_DIR [TIMEOUT_S]

Listens on 127.0.0.1:GCS_PORT like a ground station (`lbv bench --udp` sends there; the script answers to where
the datagrams come from, which must be 127.0.0.1:BENCH_PORT) and, as the operator (system 255):

    list       ListDirectory `/` and `/update`: the directories (`update`, `@SYS`, `@PARAM`), then one file per thruster slot and
               the master's
    versions   MAVFTP's get of `@SYS/versions.txt` (OpenFileRO, BurstReadFile of 80 bytes until a shorter reply,
               TerminateSession) into WORK_DIR/versions.txt: what every board runs
    unsigned   a put over the link without signing: refused ("thruster0.lbvu: refused, the link is not signed");
               then PARAM_SET LBV_UPD_UNSIGNED 1 (the vehicle answers PARAM_VALUE 1), which allows updates over it
               (tests/integration/mavproxy_ftp.rs signs the link instead, as docs/field-update.md recommends)
    put        WORK_DIR/thruster0.lbvu (the test's signed SeaBotix update file: 80-byte header, 4096-byte payload)
               to /update/thruster0.lbvu with MAVFTP's put; STATUSTEXT "thruster0.lbvu: received, ready to apply",
               then "thruster0.lbvu: 4096 B verified, 0 pages kept" once the thruster holds it
    listed     `/update` again: thruster0.lbvu now 4176 bytes
    crc        CalcFileCRC32 of /update/thruster0.lbvu: ArduPilot's CRC32 of the file (what MAVProxy's `ftp
               crclocal` computes)
    refused    the same image to /update/thruster1.lbvu, a Legacy slot: the put fails, STATUSTEXT says why
    apply      MAV_CMD_LBV_APPLY_UPDATE (31010) param1 0: COMMAND_ACK IN_PROGRESS, then the final one once the
               thruster has confirmed the image (ACCEPTED) or it failed, and what was done; param1 2 (nothing
               received there): DENIED
    master     WORK_DIR/master.lbvu (a master image, 4096-byte payload) to /update/master.lbvu, applied with
               param1 255: IN_PROGRESS, the master restarts into its bootloader's swap, and the new image sends
               ACCEPTED once it has heard this ground station's heartbeats (sent at 1 Hz throughout)

Prints a JSON summary on stdout; exit 0 when every step held, 1 with the reason on stderr when one did not, 3 when
pymavlink is missing.
"""
import json
import os
import struct
import sys
import time
import zlib

os.environ["MAVLINK20"] = "1"
os.environ["MAVLINK_DIALECT"] = "ardupilotmega"
try:
    from pymavlink import mavftp, mavutil
except ImportError as error:
    print(f"pymavlink is missing ({error}): pip install pymavlink", file=sys.stderr)
    sys.exit(3)

VEHICLE = (1, 1)
GCS_SYSTEM, GCS_COMPONENT = 255, 190
APPLY_UPDATE = 31010
CALC_FILE_CRC32 = 14
IN_PROGRESS = 5


class Failed(Exception):
    pass


def ardupilot_crc32(data):
    """ArduPilot's crc_crc32 from 0 (no inversions), as MAVProxy's `ftp crclocal` computes it."""
    return zlib.crc32(data, 0xFFFFFFFF) ^ 0xFFFFFFFF


class Ground:
    def __init__(self, gcs_port, bench_port, timeout):
        self.link = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{gcs_port}",
            dialect="ardupilotmega",
            source_system=GCS_SYSTEM,
            source_component=GCS_COMPONENT,
        )
        self.bench_port = bench_port
        self.deadline = time.monotonic() + timeout
        self.start = time.monotonic()
        self.texts = []
        self.acks = []
        self.crcs = []
        self.values = {}
        self.heartbeat_at = 0.0
        # Every message read, whoever reads it (MAVFTP's own loop only wants FILE_TRANSFER_PROTOCOL).
        self.link.message_hooks.append(self.hook)

    def hook(self, link, msg):
        kind = msg.get_type()
        if kind == "BAD_DATA" or msg.get_srcSystem() != VEHICLE[0]:
            return
        if kind == "STATUSTEXT":
            self.texts.append(msg.text)
        elif kind == "COMMAND_ACK":
            self.acks.append((msg.command, msg.result))
        elif kind == "PARAM_VALUE":
            self.values[msg.param_id] = msg.param_value
        elif kind == "FILE_TRANSFER_PROTOCOL":
            payload = bytes(msg.payload)
            if payload[3] == 128 and payload[5] == CALC_FILE_CRC32 and payload[4] == 4:
                self.crcs.append(struct.unpack("<I", payload[12:16])[0])

    def elapsed(self):
        return round(time.monotonic() - self.start, 2)

    def beat(self):
        """A GCS HEARTBEAT once a second, as a ground station sends them."""
        if time.monotonic() >= self.heartbeat_at:
            self.heartbeat_at = time.monotonic() + 1.0
            self.link.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def pump(self, seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.beat()
            self.link.recv_match(blocking=True, timeout=0.05)

    def wait(self, done, within, what):
        end = min(time.monotonic() + within, self.deadline)
        while not done():
            if time.monotonic() >= end:
                raise Failed(f"{what}: not within {within} s")
            self.beat()
            self.link.recv_match(blocking=True, timeout=0.05)

    def connect(self):
        self.wait(lambda: self.link.messages.get("HEARTBEAT") is not None, 15.0, "the vehicle's HEARTBEAT")
        # Where udpin answers: the senders seen (newer pymavlink keeps a set, older versions the last one).
        clients = getattr(self.link, "clients", None)
        addresses = sorted(clients) if clients is not None else [self.link.last_address]
        if addresses != [("127.0.0.1", self.bench_port)]:
            raise Failed(f"the vehicle sends from {addresses}, not 127.0.0.1:{self.bench_port}")
        self.link.target_system, self.link.target_component = VEHICLE

    def set_param(self, name, value):
        """PARAM_SET, as pymavlink sends it (REAL32); the value the vehicle answers with."""
        self.values.pop(name, None)
        self.link.mav.param_set_send(*VEHICLE, name.encode(), value, mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
        self.wait(lambda: name in self.values, 3.0, f"PARAM_VALUE {name}")
        return self.values[name]

    def apply(self, slot, within=20.0):
        """The apply command's COMMAND_ACK results, up to its final one."""
        since = len(self.acks)
        self.link.mav.command_long_send(*VEHICLE, APPLY_UPDATE, 0, float(slot), 0, 0, 0, 0, 0, 0)

        def results():
            return [result for command, result in self.acks[since:] if command == APPLY_UPDATE]

        self.wait(lambda: results() and results()[-1] != IN_PROGRESS, within, f"the final COMMAND_ACK (slot {slot})")
        return results()


def listing(ret):
    return [[entry.name, entry.size_b, entry.is_dir] for entry in ret.directory_listing or []]


def main():
    if len(sys.argv) < 4:
        print(__doc__, file=sys.stderr)
        return 2
    gcs_port, bench_port, work = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
    timeout = float(sys.argv[4]) if len(sys.argv) > 4 else 30.0
    ground = Ground(gcs_port, bench_port, timeout)
    summary = {}
    try:
        ground.connect()
        # pymavlink's client resets the vehicle's FTP sessions as it starts.
        ftp = mavftp.MAVFTP(ground.link, *VEHICLE)

        ret = ftp.cmd_list(["/"])
        summary["root"] = listing(ret)
        ret = ftp.cmd_list(["/update"])
        summary["before"] = listing(ret)

        versions = os.path.join(work, "versions.txt")
        ftp.cmd_get(["@SYS/versions.txt", versions])
        ret = ftp.process_ftp_reply("OpenFileRO", timeout=10)
        with open(versions, encoding="ascii") as file:
            summary["versions"] = {"error": int(ret.error_code), "text": file.read()}

        local = os.path.join(work, "thruster0.lbvu")
        since = len(ground.texts)
        ftp.cmd_put([local, "/update/thruster0.lbvu"])
        ret = ftp.process_ftp_reply("put", timeout=10)
        ground.pump(0.3)
        summary["unsigned"] = {"error": int(ret.error_code), "texts": ground.texts[since:]}
        summary["allowed"] = ground.set_param("LBV_UPD_UNSIGNED", 1.0)

        local = os.path.join(work, "thruster0.lbvu")
        with open(local, "rb") as file:
            image = file.read()
        since = len(ground.texts)
        ftp.cmd_put([local, "/update/thruster0.lbvu"])
        ret = ftp.process_ftp_reply("put", timeout=20)
        if ret.error_code != 0:
            raise Failed(f"put: MAVFTP error {ret.error_code}; texts {ground.texts[since:]}")
        ground.wait(
            lambda: "thruster0.lbvu: 4096 B verified, 0 pages kept" in ground.texts[since:],
            5.0,
            "the thruster's copy verified",
        )
        summary["put"] = {"bytes": len(image), "texts": ground.texts[since:]}

        summary["after"] = listing(ftp.cmd_list(["/update"]))
        ftp.cmd_crc(["/update/thruster0.lbvu"])
        ground.wait(lambda: ground.crcs, 3.0, "the CRC32 reply")
        summary["crc"] = {"vehicle": ground.crcs[-1], "local": ardupilot_crc32(image)}

        since = len(ground.texts)
        ftp.cmd_put([local, "/update/thruster1.lbvu"])
        ret = ftp.process_ftp_reply("put", timeout=10)
        ground.pump(0.3)
        summary["refused"] = {"error": int(ret.error_code), "texts": ground.texts[since:]}

        since = len(ground.texts)
        summary["apply"] = {"thruster0": ground.apply(0), "thruster2": ground.apply(2)}
        ground.pump(0.3)
        summary["apply"]["texts"] = ground.texts[since:]

        local = os.path.join(work, "master.lbvu")
        since = len(ground.texts)
        ftp.cmd_put([local, "/update/master.lbvu"])
        ret = ftp.process_ftp_reply("put", timeout=20)
        if ret.error_code != 0:
            raise Failed(f"put master: MAVFTP error {ret.error_code}; texts {ground.texts[since:]}")
        results = ground.apply(255, within=40.0)
        ground.pump(0.3)
        texts = [text for text in ground.texts[since:] if text.startswith("master.lbvu:")]
        summary["master"] = {"results": results, "texts": texts}
    except Failed as failure:
        summary.update(failed=str(failure), texts=ground.texts[-10:], elapsed_s=ground.elapsed())
        print(json.dumps(summary))
        print(f"ftp_upload: {failure}", file=sys.stderr)
        return 1
    summary["elapsed_s"] = ground.elapsed()
    summary["passed"] = True
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
