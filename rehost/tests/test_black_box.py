"""The master's black box on the chip: the shipping image records ten samples a second into the RAM above its
post-mortem record, keeps them over a warm reset, begins anew after a power-on, and serves them over MAVLink FTP as
`@SYS/blackbox.tlog`, which pymavlink's own tlog reader (mavlogdump's) reads message by message."""

import os
import tempfile

from pymavlink import mavutil

from g431.chip import BLACK_BOX, CRASH_REGION
from master import Ftp, start

TLOG = "@SYS/blackbox.tlog"
STARTED = "Black box: master started"


def messages(data):
    """Every message of the log as pymavlink reads a .tlog: (its timestamp, the message)."""
    with tempfile.NamedTemporaryFile(suffix=".tlog", delete=False) as f:
        f.write(data)
    # MAVLink 2's dialect, as mavlogdump.py reads a log: ESC_INFO and ESC_STATUS have ids past MAVLink 1's.
    os.environ["MAVLINK20"] = "1"
    try:
        log = mavutil.mavlink_connection(f.name, dialect="ardupilotmega", robust_parsing=False)
        read = []
        while (message := log.recv_match()) is not None:
            assert message.get_type() != "BAD_DATA", message
            read.append((message._timestamp, message))
        return read
    finally:
        os.unlink(f.name)


def texts(read):
    return [(round(t, 3), m.text) for t, m in read if m.get_type() == "STATUSTEXT"]


def test_the_region_is_where_the_layout_puts_it(expected):
    assert expected["black_box"] == {"origin": 0x2000_0000 + CRASH_REGION, "length": BLACK_BOX}


def test_a_power_on_begins_it_empty_a_warm_reset_keeps_it_and_it_is_served_as_a_telemetry_log(expected):
    # The chip's power-on leaves noise in RAM (the model's): the black box begins empty.
    chip, _, ground = start("lbv-master-fw", expected)
    chip.run_for(0.5)
    chip.request_reset("software")
    chip.run_for(0.3)
    read = messages(Ftp(chip, ground).get(TLOG, size=239))
    kinds = {m.get_type() for _, m in read}
    # ESC_INFO is common.xml's, newer than pymavlink 2.4.50's tables: a frame it reads, as UNKNOWN_290.
    assert kinds == {"HEARTBEAT", "SERVO_OUTPUT_RAW", "BATTERY_STATUS", "ESC_TELEMETRY_1_TO_4",
                     "ESC_TELEMETRY_5_TO_8", "UNKNOWN_290", "STATUSTEXT"}, kinds
    # The first message is the first start's mark: nothing the power-on left is taken for a sample.
    assert read[0][1].get_type() == "HEARTBEAT" and texts(read)[0][1] == STARTED, read[:8]
    started = [t for t, text in texts(read) if text == STARTED]
    assert len(started) == 2, texts(read)
    # Ten samples a second, each with its HEARTBEAT, before the reset and after it; the clock runs on over it.
    heartbeats = [t for t, m in read if m.get_type() == "HEARTBEAT"]
    before = [t for t in heartbeats if t < started[1]]
    assert 3 <= len(before) <= 6, before
    assert all(b > a for a, b in zip(heartbeats, heartbeats[1:])), heartbeats
    # The six modelled thrusters, in two blocks, every one reporting once the master has found them (its count the
    # sample's number), none past them.
    last_1_to_4 = [m for _, m in read if m.get_type() == "ESC_TELEMETRY_1_TO_4"][-1]
    last_5_to_8 = [m for _, m in read if m.get_type() == "ESC_TELEMETRY_5_TO_8"][-1]
    counts = list(last_1_to_4.count) + list(last_5_to_8.count)
    assert counts[:6] == [counts[0]] * 6 and counts[0] > 0 and counts[6:] == [0, 0], counts
