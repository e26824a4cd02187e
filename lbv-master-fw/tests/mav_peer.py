#!/usr/bin/env python3
"""An independent MAVLink peer for the console tests, built on pymavlink (dialect ardupilotmega).

    mav_peer.py check    exit 0 when pymavlink is importable
    mav_peer.py emit     print a JSON object {name: hex frame} of frames a ground station sends
    mav_peer.py decode [KEY]
                         read hex frames on stdin, print a JSON list of the decoded messages
                         (fields of each message plus "_sys", "_comp", "_seq", "_type", "_signed"); with KEY
                         (64 hex digits), frames must be signed with it: the others come out as BAD_DATA
    mav_peer.py signing KEY TIMESTAMP
                         print a JSON object {name: hex frame} of a ground station's frames for a vehicle
                         with signing: SETUP_SIGNING of KEY (unsigned), and HEARTBEAT and arm frames signed
                         with KEY from TIMESTAMP on, unsigned, signed with another key
    mav_peer.py session  print a JSON list of [time_ms, name, hex frame]: a pilot's dive as a ground
                         station sends it (heartbeats at 1 Hz, arm, the stick pushed forward step by step
                         at about 10 Hz, disarm)
"""
import json
import os
import sys

os.environ["MAVLINK20"] = "1"
try:
    from pymavlink.dialects.v10 import ardupilotmega as mav1
    from pymavlink.dialects.v20 import ardupilotmega as mav2
except ImportError as error:
    print(f"pymavlink is missing ({error}): pip install pymavlink", file=sys.stderr)
    sys.exit(3)

GCS_SYSTEM, GCS_COMPONENT = 255, 190


def link(module, system=GCS_SYSTEM, component=GCS_COMPONENT):
    return module.MAVLink(None, srcSystem=system, srcComponent=component)


def ftp(seq, session, opcode, offset, data):
    """A MAVLink FTP payload as pymavlink.mavftp packs it: the 12-byte header, the data, zeros to 251 bytes."""
    import struct

    payload = struct.pack("<HBBBBBBI", seq, session, opcode, len(data), 0, 0, 0, offset) + data
    return list(payload + bytes(251 - len(payload)))


def emit():
    g = link(mav2)
    v = link(mav2, system=2, component=1)
    g1 = link(mav1)
    frames = {
        "heartbeat_gcs": g.heartbeat_encode(
            mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 192, 0, mav2.MAV_STATE_ACTIVE
        ).pack(g),
        "heartbeat_vehicle": v.heartbeat_encode(
            mav2.MAV_TYPE_SUBMARINE, mav2.MAV_AUTOPILOT_ARDUPILOTMEGA, 81, 19, mav2.MAV_STATE_STANDBY
        ).pack(v),
        "manual": g.manual_control_encode(1, 100, -200, 700, -300, 5).pack(g),
        "manual_other": g.manual_control_encode(2, 100, -200, 700, -300, 0).pack(g),
        "arm": g.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(g),
        "disarm": g.command_long_encode(1, 0, 400, 0, 0, 0, 0, 0, 0, 0, 0).pack(g),
        "motor_test": g.command_long_encode(1, 1, 209, 0, 3, 0, -40, 4.5, 0, 0, 0).pack(g),
        "motor_test_pwm": g.command_long_encode(1, 1, 209, 0, 3, 1, 1600, 2, 0, 0, 0).pack(g),
        "unknown_command": g.command_long_encode(1, 1, 31012, 0, 0, 0, 0, 0, 0, 0, 0).pack(g),
        "arm_other_system": g.command_long_encode(2, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(g),
        "param_list": g.param_request_list_encode(1, 1).pack(g),
        # QGroundControl's mode menu: MAV_MODE_FLAG_CUSTOM_MODE_ENABLED and ArduSub's mode number.
        "set_mode_manual": g.command_long_encode(1, 1, 176, 0, 1, 19, 0, 0, 0, 0, 0).pack(g),
        "set_mode_alt_hold": g.command_long_encode(1, 1, 176, 0, 1, 2, 0, 0, 0, 0, 0).pack(g),
        "set_mode_base_only": g.command_long_encode(1, 1, 176, 0, 128, 0, 0, 0, 0, 0, 0).pack(g),
        "mission_list_fence": g.mission_request_list_encode(1, 1, mav2.MAV_MISSION_TYPE_FENCE).pack(g),
        "mission_list_other": g.mission_request_list_encode(2, 1, mav2.MAV_MISSION_TYPE_MISSION).pack(g),
        "param_read_name": g.param_request_read_encode(1, 1, b"THR_MAX", -1).pack(g),
        "param_read_index": g.param_request_read_encode(1, 0, b"", 3).pack(g),
        "param_set": g.param_set_encode(1, 1, b"THR_MAX", 0.75, mav2.MAV_PARAM_TYPE_REAL32).pack(g),
        "param_set_int8": g.param_set_encode(1, 1, b"FS_PILOT_INPUT", 2, mav2.MAV_PARAM_TYPE_INT8).pack(g),
        "arm_half": g.command_long_encode(1, 1, 400, 0, 0.5, 0, 0, 0, 0, 0, 0).pack(g),
        "arm_int": g.command_int_encode(1, 1, 0, 400, 0, 0, 1, 0, 0, 0, 0, 0, 0).pack(g),
        "request_version": g.command_long_encode(1, 1, 512, 0, 148, 0, 0, 0, 0, 0, 0).pack(g),
        "request_version_int": g.command_int_encode(1, 1, 0, 512, 0, 0, 148, 0, 0, 0, 0, 0, 0).pack(g),
        "request_capabilities": g.command_long_encode(1, 1, 520, 0, 1, 0, 0, 0, 0, 0, 0).pack(g),
        "request_home": g.command_long_encode(1, 1, 512, 0, 242, 0, 0, 0, 0, 0, 0).pack(g),
        "esc_status_off": g.command_long_encode(1, 1, 511, 0, 291, -1, 0, 0, 0, 0, 0).pack(g),
        "arm_v1": g1.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(g1),
        "manual_v1": g1.manual_control_encode(1, -1000, 1000, 0, 1000, 0).pack(g1),
        # MAVLink FTP as pymavlink's MAVFTP sends it (the payload padded to 251 bytes), and the apply command.
        "ftp_list": g.file_transfer_protocol_encode(0, 1, 1, ftp(7, 3, 3, 0, b"/update")).pack(g),
        "ftp_write": g.file_transfer_protocol_encode(0, 1, 0, ftp(8, 3, 7, 239, bytes(range(1, 240)))).pack(g),
        "ftp_other_system": g.file_transfer_protocol_encode(0, 2, 1, ftp(9, 3, 3, 0, b"/update")).pack(g),
        "ftp_v1": g1.file_transfer_protocol_encode(0, 1, 1, ftp(10, 3, 3, 0, b"/")).pack(g1),
        "apply_update": g.command_long_encode(1, 1, 31010, 0, 2, 0, 0, 0, 0, 0, 0).pack(g),
        "query_version": g.command_long_encode(1, 1, 31011, 0, 4, 0, 0, 0, 0, 0, 0).pack(g),
        # Not in the console's dialect.
        "system_time": g.system_time_encode(1234567, 890).pack(g),
    }
    print(json.dumps({name: frame.hex() for name, frame in frames.items()}))


def session():
    g = link(mav2)
    heartbeat = lambda: g.heartbeat_encode(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 192, 0, mav2.MAV_STATE_ACTIVE)
    events = []
    for t in range(0, 3001, 1000):
        events.append((t, "heartbeat", heartbeat()))
    events.append((100, "arm", g.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)))
    # The stick moves forward a little more with every frame; the frames come at uneven times, so they meet the
    # master's 50 Hz polling at every phase.
    for k in range(18):
        t = 300 + 100 * k + (k * 7) % 20
        events.append((t, "manual", g.manual_control_encode(1, 100 + 50 * k, 0, 500, 0, 0)))
    events.append((2500, "disarm", g.command_long_encode(1, 1, 400, 0, 0, 0, 0, 0, 0, 0, 0)))
    events.sort(key=lambda event: event[0])
    print(json.dumps([[t, name, message.pack(g).hex()] for t, name, message in events]))


def signing(key, timestamp):
    def signer(secret):
        g = link(mav2)
        g.signing.secret_key = secret
        g.signing.timestamp = timestamp
        g.signing.link_id = 0
        g.signing.sign_outgoing = True
        return g
    g = link(mav2)
    s = signer(key)
    other = signer(bytes(32 - i for i in range(32)))
    heartbeat = lambda: s.heartbeat_encode(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 192, 0, mav2.MAV_STATE_ACTIVE)
    arm = lambda: g.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    frames = {
        "setup": g.setup_signing_encode(1, 1, key, timestamp).pack(g),
        "heartbeat_unsigned": heartbeat().pack(g),
        "arm_unsigned": arm().pack(g),
        "heartbeat_signed": heartbeat().pack(s),
        "arm_signed": arm().pack(s),
        "arm_other_key": arm().pack(other),
        "heartbeat_signed_later": heartbeat().pack(s),
        "disarm_signed": g.command_long_encode(1, 1, 400, 0, 0, 0, 0, 0, 0, 0, 0).pack(s),
    }
    print(json.dumps({name: bytes(frame).hex() for name, frame in frames.items()}))


def plain(value):
    if isinstance(value, (bytes, bytearray)):
        return value.decode("latin-1")
    if isinstance(value, list):
        return [plain(v) for v in value]
    return value


def decode(key=None):
    data = bytes.fromhex("".join(sys.stdin.read().split()))
    parser = link(mav2)
    parser.robust_parsing = True
    if key is not None:
        parser.signing.secret_key = key
    out = []
    for msg in parser.parse_buffer(data) or []:
        fields = {k: plain(v) for k, v in msg.to_dict().items() if k != "mavpackettype"}
        fields["_type"] = msg.get_type()
        # A well-formed frame of a message this pymavlink does not know (ESC_INFO and ESC_STATUS are newer than
        # its XML) is not a bad frame.
        if msg.get_type().startswith("UNKNOWN_"):
            fields = {"_type": "UNKNOWN", "_id": int(msg.get_type()[len("UNKNOWN_"):])}
            out.append(fields)
            continue
        fields["_sys"] = msg.get_srcSystem()
        fields["_comp"] = msg.get_srcComponent()
        fields["_seq"] = msg.get_seq()
        fields["_signed"] = msg.get_signed()
        out.append(fields)
    print(json.dumps(out))


if __name__ == "__main__":
    command = sys.argv[1] if len(sys.argv) > 1 else ""
    if command == "check":
        sys.exit(0)
    elif command == "emit":
        emit()
    elif command == "decode":
        decode(bytes.fromhex(sys.argv[2]) if len(sys.argv) > 2 else None)
    elif command == "signing":
        signing(bytes.fromhex(sys.argv[2]), int(sys.argv[3]))
    elif command == "session":
        session()
    else:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
