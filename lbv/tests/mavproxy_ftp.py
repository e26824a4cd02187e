#!/usr/bin/env python3
"""Field update with MAVProxy, a real ground station, typed at its prompt, for tests/integration/mavproxy_ftp.rs.

    mavproxy_ftp.py GCS_PORT OBSERVER_PORT WORK_DIR [TIMEOUT_S]

Starts MAVProxy headless on udpin:127.0.0.1:GCS_PORT (where `lbv bench --udp` sends) with its default modules
(ftp and cmdlong among them) and forwards what the vehicle sends to OBSERVER_PORT, where pymavlink watches the
STATUSTEXTs and COMMAND_ACKs (it never sends). The steps, as a person would type them:

    connect   MAVProxy sees the vehicle
    list      `ftp list /update`: one file per thruster slot, one per family and the master's, 0 bytes each
    versions  `ftp list /` (`update`, `@SYS` and `@PARAM`), `ftp list @SYS` (`versions.txt` and its length) and `ftp get
              @SYS/versions.txt WORK_DIR/versions-before.txt`: what every board runs before the updates (got again
              until no thruster is left to be asked what it runs, as the master asks each once it answers)
    unsigned  `ftp put WORK_DIR/thruster2.lbvu /update/thruster2.lbvu` over the link without signing (the vehicle's
              LBV_UPD_UNSIGNED at its default, 0): refused at its CreateFile, "thruster2.lbvu: refused, the link is
              not signed"
    signing   `signing setup PASSPHRASE`, as docs/field-update.md says to before updating: MAVProxy sends the key to
              the vehicle (SETUP_SIGNING) and signs every frame from then on; the vehicle's frames come signed too
              (every step after goes over the signed link)
    older     `ftp put WORK_DIR/older.lbvu /update/thruster2.lbvu`, a validly signed 0.0.9, older than the 0.1.0
              the thruster runs: refused with its reason at its first page, before anything is written
    flipped   `ftp put WORK_DIR/flipped.lbvu /update/thruster2.lbvu`, a 0.3.0 with one payload bit flipped after
              signing: received whole, then `long MAV_CMD_USER_1 2`: the thruster marks it, restarts, and its
              bootloader refuses it: FAILED and "T3: refused by its bootloader: signature"; `long MAV_CMD_USER_2 2`:
              it still runs 0.1.0
    lossy     `ftp set pkt_loss_tx 20`, `ftp set pkt_loss_rx 20`, `ftp set loss_seed 5` (MAVProxy's own link
              simulator: a fifth of its requests and of the vehicle's replies lost, the same ones every run) and
              `ftp set debug 2` (MAVProxy prints every request, reply and loss), then `ftp put
              WORK_DIR/thruster2.lbvu /update/thruster2.lbvu` (the test's SeaBotix update file, signed with the
              development key): "Sent file of length 4176"; the vehicle's "thruster2.lbvu: received, ready to
              apply" and, once the thruster holds it, "thruster2.lbvu: 4096 B verified, 0 pages kept"; the writes
              MAVProxy sent more than once
    crc       `ftp crc /update/thruster2.lbvu` (losses off again): the CRC32 `ftp crclocal` gives the file
    listed    `ftp list /update`: thruster2.lbvu 4176 bytes
    apply     `long MAV_CMD_USER_1 2`: COMMAND_ACK IN_PROGRESS, then ACCEPTED once the thruster runs the image and
              has confirmed it, and the texts on the way
    version   `long MAV_CMD_USER_2 2`: COMMAND_ACK IN_PROGRESS, then ACCEPTED, and "thruster2.lbvu: runs 0.2.0, dev key"
    remove    `ftp rm /update/thruster2.lbvu`: "thruster2.lbvu: removed"; `long MAV_CMD_USER_1 2`: DENIED
    fleet     `ftp put WORK_DIR/fleet.lbvu /update/thrusters-seabotix.lbvu` (a SeaBotix 0.3.0) and, once every
              SeaBotix thruster (T1, T3, T5) has it verified, `long MAV_CMD_USER_1 200`: COMMAND_ACK IN_PROGRESS,
              then IN_PROGRESS with its progress as the three restart and confirm ("thrusters-seabotix.lbvu: 1 of 3
              done, T3 60 %" at most once a second, as MAVProxy prints them), then ACCEPTED
    fleet_legacy  as fleet, with WORK_DIR/fleet-legacy.lbvu (a Legacy 0.3.0) to /update/thrusters-legacy.lbvu and
              `long MAV_CMD_USER_1 201` for the Legacy thrusters (T2, T4, T6)
    versions_after  as versions, into WORK_DIR/versions-after.txt: every thruster runs 0.3.0 now (got again
              until none is on trial or left to be asked)
    again     the same file put to /update/thrusters-seabotix.lbvu again: each SeaBotix thruster "runs 0.3.0 already"
              and is left be; `long MAV_CMD_USER_1 200`: ACCEPTED at once, "all run it already"

Prints a JSON summary;
exit 0 when every step held, 1 with the reason on stderr when one did not, 3 when pymavlink or MAVProxy is
missing.
"""
import json
import os
import re
import shutil
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from mavproxy_pilot import Failed, MavProxy, Observer  # noqa: E402 (pymavlink checked there)

APPLY_UPDATE = 31010
# MAVProxy makes the key of it (SHA-256); the vehicle keeps it in its flash, and takes only frames signed with it.
PASSPHRASE = "lbv-bench-mavproxy-ftp"
QUERY_VERSION = 31011
# The bench vehicle's SeaBotix thrusters (the mixed vehicle: SeaBotix and Legacy in turn), as the texts number them.
SEABOTIX = (1, 3, 5)
LEGACY = (2, 4, 6)
IN_PROGRESS = 5


class Session:
    def __init__(self, gcs_port, observer_port, work, timeout):
        self.work = work
        self.state_dir = tempfile.mkdtemp(prefix="mavproxy-ftp-")
        self.observer = Observer(observer_port)
        self.mavproxy = MavProxy(gcs_port, observer_port, self.state_dir)
        self.start = time.monotonic()
        self.deadline = self.start + timeout
        self.summary = {}

    def elapsed(self):
        return round(time.monotonic() - self.start, 2)

    def wait(self, done, within, what):
        end = min(time.monotonic() + within, self.deadline)
        while True:
            self.observer.pump()
            self.mavproxy.drain()
            if done():
                return
            if self.mavproxy.process.poll() is not None:
                raise Failed(f"{what}: MAVProxy exited ({self.mavproxy.process.returncode})")
            if time.monotonic() >= end:
                raise Failed(f"{what}: not within {within} s")

    def lines(self, since, pattern):
        return [m for t, line in self.mavproxy.log if t >= since for m in [re.search(pattern, line)] if m]

    def acks(self, since, command=APPLY_UPDATE):
        return [m.result for _, m in self.observer.since(since, "COMMAND_ACK") if m.command == command]

    def ack(self, since, command=APPLY_UPDATE):
        """The command's final COMMAND_ACK result, None before it."""
        acks = self.acks(since, command)
        return acks[-1] if acks and acks[-1] != IN_PROGRESS else None

    def listing(self):
        since = time.monotonic()
        self.mavproxy.type("ftp list /update")
        self.wait(lambda: self.lines(since, r"Total size"), 10.0, "the listing")
        return [[m.group(1), int(m.group(2))] for m in self.lines(since, r"^\s+(\S+\.lbvu)\t(\d+)")]

    # The steps, in order.

    def connect(self):
        self.wait(lambda: self.mavproxy.said("Detected vehicle 1:1"), 20.0, "MAVProxy sees the vehicle")
        self.wait(lambda: self.observer.since(0.0, "HEARTBEAT"), 5.0, "the observer sees the vehicle")

    def list(self):
        self.summary["list"] = self.listing()

    def get_versions(self, name):
        """`ftp list /`, `ftp list @SYS` and `ftp get @SYS/versions.txt` into WORK_DIR/`name`, got again until no
        thruster is on trial or left to be asked what it runs: the listings, the text and the gets it took."""
        since = time.monotonic()
        self.mavproxy.type("ftp list /")
        self.wait(lambda: self.lines(since, r"Total size"), 10.0, "the listing of /")
        root = [m.group(1) for m in self.lines(since, r"^ D (\S+)$")]
        since = time.monotonic()
        self.mavproxy.type("ftp list @SYS")
        self.wait(lambda: self.lines(since, r"Total size"), 10.0, "the listing of @SYS")
        files = [[m.group(1), int(m.group(2))] for m in self.lines(since, r"^\s+(\S+\.txt)\t(\d+)")]
        local = os.path.join(self.work, name)
        for gets in range(1, 21):
            since = time.monotonic()
            self.mavproxy.type(f"ftp get @SYS/versions.txt {local}")
            self.wait(lambda: self.lines(since, r"Wrote \d+ bytes to"), 10.0, "the get of @SYS/versions.txt")
            # MAVProxy says how much it wrote before it has closed the file: read it once it is all there.
            wrote = int(self.lines(since, r"Wrote (\d+) bytes to")[-1].group(1))
            self.wait(lambda: os.path.getsize(local) >= wrote, 5.0, "versions.txt whole on disk")
            with open(local, encoding="ascii") as file:
                text = file.read()
            if not re.search(r" (unasked|on-trial)$", text, re.M):
                break
            # Half a second between two gets, pumping the links meanwhile.
            again = since + 0.5
            self.wait(lambda: time.monotonic() >= again, 1.0, "the pause before the next get")
        return {"root": root, "sys": files, "text": text, "wrote": wrote, "gets": gets}

    def versions(self):
        self.summary["versions"] = self.get_versions("versions-before.txt")

    def versions_after(self):
        self.summary["versions_after"] = self.get_versions("versions-after.txt")

    def put(self, name):
        """`ftp put` of WORK_DIR/`name` to thruster2's file; the vehicle's texts since."""
        since = time.monotonic()
        self.mavproxy.type(f"ftp put {os.path.join(self.work, name)} /update/thruster2.lbvu")
        return since

    def unsigned(self):
        since = self.put("thruster2.lbvu")
        refusal = "thruster2.lbvu: refused, the link is not signed"
        self.wait(lambda: refusal in self.observer.texts(since), 10.0, "the refusal")
        self.wait(lambda: self.lines(since, r"(Write|Create) failed|Sent file of length"), 10.0, "MAVProxy's put ends")
        self.summary["unsigned"] = {
            "texts": self.observer.texts(since),
            "failed": [m.group(0) for m in self.lines(since, r"(Write|Create) failed.*")],
        }

    def signing(self):
        since = time.monotonic()
        self.mavproxy.type(f"signing setup {PASSPHRASE}")

        def signed_heartbeats():
            # The incompatibility flags of the frame as it came: bit 0, signed (pymavlink reads it without the key).
            return [bool(m.get_msgbuf()[2] & 0x01) for _, m in self.observer.since(since, "HEARTBEAT")]

        self.wait(lambda: signed_heartbeats()[-2:] == [True, True], 10.0, "the vehicle signing its frames")
        self.summary["signing"] = {"signed": signed_heartbeats()[-1], "mavproxy": self.mavproxy.said("Sent secret_key")}

    def older(self):
        since = self.put("older.lbvu")
        self.wait(lambda: any("(not a rollback)" in text for text in self.observer.texts(since)), 15.0, "the refusal")
        self.wait(lambda: self.lines(since, r"(Write|Create) failed|Sent file of length"), 10.0, "MAVProxy's put ends")
        self.summary["older"] = {
            "texts": self.observer.texts(since),
            "failed": [m.group(0) for m in self.lines(since, r"(Write|Create) failed.*")],
        }

    def flipped(self):
        since = self.put("flipped.lbvu")
        self.wait(
            lambda: "thruster2.lbvu: 4096 B verified, 0 pages kept" in self.observer.texts(since),
            20.0,
            "the flipped image on the thruster",
        )
        applied = time.monotonic()
        self.mavproxy.type("long MAV_CMD_USER_1 2")
        self.wait(lambda: self.ack(applied) is not None, 20.0, "the apply's final COMMAND_ACK")
        asked = time.monotonic()
        self.mavproxy.type("long MAV_CMD_USER_2 2")
        self.wait(lambda: self.ack(asked, QUERY_VERSION) is not None, 5.0, "the version query's COMMAND_ACK")
        self.wait(lambda: self.observer.texts(asked), 2.0, "the version query's STATUSTEXT")
        self.summary["flipped"] = {
            "results": self.acks(applied),
            "texts": self.observer.texts(applied),
            "version": self.observer.texts(asked),
        }

    def lossy(self):
        local = os.path.join(self.work, "thruster2.lbvu")
        with open(local, "rb") as file:
            image = file.read()
        for setting in ("pkt_loss_tx 20", "pkt_loss_rx 20", "loss_seed 5", "debug 2"):
            self.mavproxy.type(f"ftp set {setting}")
        since = time.monotonic()
        self.mavproxy.type(f"ftp put {local} /update/thruster2.lbvu")
        self.wait(lambda: self.lines(since, r"Sent file of length (\d+)"), 25.0, "MAVProxy's put")
        sent = int(self.lines(since, r"Sent file of length (\d+)")[-1].group(1))
        self.wait(
            lambda: "thruster2.lbvu: 4096 B verified, 0 pages kept" in self.observer.texts(since),
            5.0,
            "the thruster's copy verified",
        )
        # MAVProxy's debug lines: "> OP seq:.. opcode:7 ... ofs:N" for each write it sends.
        writes = [int(m.group(1)) for m in self.lines(since, r"^> OP .*opcode:7 .*ofs:(\d+)")]
        self.summary["put"] = {
            "sent": sent,
            "bytes": len(image),
            "seconds": round(time.monotonic() - since, 2),
            "texts": self.observer.texts(since),
            "failed": [line for t, line in self.mavproxy.log if t >= since and re.search(r"(Write|Create) failed", line)],
            "lost_requests": len(self.lines(since, r"dropping packet TX")),
            "lost_replies": len(self.lines(since, r"dropping packet RX")),
            "writes": len(writes),
            "sent_again": sorted({offset for offset in writes if writes.count(offset) > 1}),
        }
        for setting in ("pkt_loss_tx 0", "pkt_loss_rx 0", "debug 0"):
            self.mavproxy.type(f"ftp set {setting}")

    def crc(self):
        local = os.path.join(self.work, "thruster2.lbvu")
        since = time.monotonic()
        self.mavproxy.type(f"ftp crclocal {local}")
        self.mavproxy.type("ftp crc /update/thruster2.lbvu")
        self.wait(lambda: self.lines(since, r"crc: \S+ (0x[0-9a-f]{8})"), 10.0, "the vehicle's CRC")
        remote = self.lines(since, r"crc: \S+ (0x[0-9a-f]{8})")[-1].group(1)
        mine = self.lines(since, r"(0x[0-9a-f]{8})")
        self.summary["crc"] = {"vehicle": remote, "seen": [m.group(1) for m in mine]}

    def listed(self):
        self.summary["listed"] = self.listing()

    def apply(self):
        since = time.monotonic()
        self.mavproxy.type("long MAV_CMD_USER_1 2")
        self.wait(lambda: self.ack(since) is not None, 20.0, "the apply command's final COMMAND_ACK")
        self.wait(lambda: len(self.observer.texts(since)) >= 4, 2.0, "the apply command's STATUSTEXTs")
        self.summary["apply"] = {"results": self.acks(since), "texts": self.observer.texts(since)}

    def version(self):
        since = time.monotonic()
        self.mavproxy.type("long MAV_CMD_USER_2 2")
        self.wait(lambda: self.ack(since, QUERY_VERSION) is not None, 5.0, "the version query's final COMMAND_ACK")
        self.wait(lambda: self.observer.texts(since), 2.0, "the version query's STATUSTEXT")
        self.summary["version"] = {"results": self.acks(since, QUERY_VERSION), "texts": self.observer.texts(since)}

    def fleet(self):
        self.summary["fleet"] = self.put_family("fleet.lbvu", "thrusters-seabotix.lbvu", 200, SEABOTIX)

    def fleet_legacy(self):
        self.summary["fleet_legacy"] = self.put_family("fleet-legacy.lbvu", "thrusters-legacy.lbvu", 201, LEGACY)

    def put_family(self, local, name, apply_slot, members):
        """`ftp put WORK_DIR/local /update/name`, then, once each of `members` has it verified, the family apply
        `apply_slot`; what it answered and said."""
        since = time.monotonic()
        self.mavproxy.type(f"ftp put {os.path.join(self.work, local)} /update/{name}")

        def verified():
            texts = self.observer.texts(since)
            return all(f"T{n}: 4096 B verified, 0 pages kept" in texts for n in members)

        self.wait(verified, 30.0, f"{name}'s image on every thruster")
        applied = time.monotonic()
        self.mavproxy.type(f"long MAV_CMD_USER_1 {apply_slot}")
        self.wait(lambda: self.ack(applied) is not None, 30.0, f"{name}'s apply's final COMMAND_ACK")
        progress = [
            m.progress
            for _, m in self.observer.since(applied, "COMMAND_ACK")
            if m.command == APPLY_UPDATE and m.result == IN_PROGRESS
        ]
        return {
            "results": self.acks(applied),
            "progress": progress,
            "texts": self.observer.texts(since),
            # As MAVProxy prints the vehicle's STATUSTEXTs.
            "printed": [m.group(0) for m in self.lines(applied, re.escape(name) + r": \d of 3 done.*")],
        }

    def again(self):
        since = time.monotonic()
        self.mavproxy.type(f"ftp put {os.path.join(self.work, 'fleet.lbvu')} /update/thrusters-seabotix.lbvu")
        self.wait(lambda: self.lines(since, r"(Write|Create) failed|Sent file of length"), 10.0, "MAVProxy's put ends")
        self.wait(
            lambda: all(f"T{n}: runs 0.3.0 already" in self.observer.texts(since) for n in SEABOTIX),
            5.0,
            "each thruster running the image already",
        )
        applied = time.monotonic()
        self.mavproxy.type("long MAV_CMD_USER_1 200")
        self.wait(lambda: self.ack(applied) is not None, 5.0, "the apply's COMMAND_ACK")
        self.wait(lambda: self.observer.texts(applied), 2.0, "the apply's STATUSTEXT")
        self.summary["again"] = {
            "put": [m.group(0) for m in self.lines(since, r"(Write|Create) failed|Sent file of length \d+")],
            "results": self.acks(applied),
            "texts": self.observer.texts(since),
        }

    def remove(self):
        since = time.monotonic()
        self.mavproxy.type("ftp rm /update/thruster2.lbvu")
        self.wait(lambda: "thruster2.lbvu: removed" in self.observer.texts(since), 5.0, "the removal")
        again = time.monotonic()
        self.mavproxy.type("long MAV_CMD_USER_1 2")
        self.wait(lambda: self.ack(again) is not None, 5.0, "the second apply's COMMAND_ACK")
        self.summary["remove"] = {"apply": self.ack(again), "texts": self.observer.texts(since)}

    STEPS = [
        "connect",
        "list",
        "versions",
        "unsigned",
        "signing",
        "older",
        "flipped",
        "lossy",
        "crc",
        "listed",
        "apply",
        "version",
        "remove",
        "fleet",
        "fleet_legacy",
        "versions_after",
        "again",
    ]

    def run(self):
        for step in self.STEPS:
            getattr(self, step)()
            self.summary.setdefault("steps", []).append(step)
        self.summary["elapsed_s"] = self.elapsed()


def main():
    if len(sys.argv) < 4:
        print(__doc__, file=sys.stderr)
        return 2
    gcs_port, observer_port, work = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
    timeout = float(sys.argv[4]) if len(sys.argv) > 4 else 60.0
    session = Session(gcs_port, observer_port, work, timeout)
    try:
        session.run()
    except Failed as failure:
        session.mavproxy.drain()
        session.summary.update(failed=str(failure), elapsed_s=session.elapsed())
        session.summary["mavproxy"] = [line for _, line in session.mavproxy.log][-40:]
        print(json.dumps(session.summary))
        print(f"mavproxy_ftp: {failure}", file=sys.stderr)
        return 1
    finally:
        session.mavproxy.stop()
        shutil.rmtree(session.state_dir, ignore_errors=True)
    session.summary["passed"] = True
    print(json.dumps(session.summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
