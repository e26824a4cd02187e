#!/usr/bin/env python3
"""Decodes a candump log with cantools and lbv/dbc/bat.dbc, for tests/integration/decode_can_cantools.rs.

    decode_can_cantools.py DBC LOG

Reads LOG with cantools' own candump log reader and decodes every classic, standard-ID, non-remote frame whose
ID the DBC knows. Prints one JSON object per such frame with the field names of `lbv decode can --json`, plus
`line` (the frame's line number in LOG):

- BAT_INFO (0x620): voltage_v, current_a, charge_pct, temperature_c, exactly as cantools scales them (a 0 on the
  wire stays 0.0 here, where bat-proto reads "not reported");
- BAT_STATUS (0x629): status (the word made of the 12 bit signals), status_bits (the names of the signals that
  are 1), changed (the bits that differ from the previous status frame on the same interface; [] on the first);
- BMS_ALARMS (0x628): alarms (the byte made of the 7 bit signals), alarm_bits (bat-proto's words for the
  signals that are 1), changed (the alarms that differ from the previous BMS frame on the same interface, or
  from none on the first);
- a frame cantools cannot decode (wrong length): error.

The status and alarm fields are rebuilt from the DBC's single-bit signals here, independently of lbv. Exit 0;
2 on a usage error; 3 when cantools is missing.
"""
import json
import sys

try:
    import cantools
    from cantools.logreader import Parser
except ImportError as error:
    print(f"cantools is missing ({error}): pip install cantools", file=sys.stderr)
    sys.exit(3)

# The DBC's BMS alarm signals in bat-proto's words (BmsAlarms::name).
ALARM_WORDS = {
    "LowVoltage": "low voltage",
    "HighVoltage": "high voltage",
    "OvercurrentDischarge": "overcurrent discharge",
    "OvercurrentCharge": "overcurrent charge",
    "LowCharge": "low state of charge",
    "LowTemperature": "low temperature",
    "HighTemperature": "high temperature",
}


def bits(message, signals):
    """The word made of a message's single-bit signals, and the names of those set, in bit order."""
    ones = sorted((s.start, s.name) for s in message.signals if s.length == 1 and signals[s.name] == 1)
    return sum(1 << start for start, _ in ones), [name for _, name in ones]


def changed(message, word, previous):
    """Names of the single-bit signals that differ between two words, in bit order."""
    if previous is None:
        return []
    diff = word ^ previous
    return [s.name for s in sorted(message.signals, key=lambda s: s.start) if diff >> s.start & 1]


def main():
    if len(sys.argv) != 3:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    db = cantools.database.load_file(sys.argv[1])  # strict: overlapping or oversized signals fail here
    info, status, bms = (db.get_message_by_name(name) for name in ("BAT_INFO", "BAT_STATUS", "BMS_ALARMS"))
    last_status, last_alarms = {}, {}
    out = sys.stdout
    with open(sys.argv[2], encoding="ascii") as log:
        for number, (_, frame) in enumerate(Parser(log).iterlines(keep_unknowns=True), start=1):
            if frame is None or frame.is_extended_frame or frame.is_remote_frame:
                continue
            try:
                message = db.get_message_by_frame_id(frame.frame_id)
            except KeyError:
                continue
            record = {"line": number, "time": frame.timestamp.timestamp(), "id": frame.frame_id}
            try:
                signals = message.decode(frame.data, decode_choices=False)
            except cantools.database.DecodeError as error:
                record["error"] = str(error)
                out.write(json.dumps(record) + "\n")
                continue
            if message is info:
                record["voltage_v"] = signals["Voltage"]
                record["current_a"] = signals["Current"]
                record["charge_pct"] = signals["Charge"]
                record["temperature_c"] = signals["Temperature"]
            elif message is status:
                word, names = bits(message, signals)
                record["status"] = word
                record["status_bits"] = names
                record["changed"] = changed(message, word, last_status.get(frame.channel))
                last_status[frame.channel] = word
            elif message is bms:
                word, names = bits(message, signals)
                record["alarms"] = word
                record["alarm_bits"] = [ALARM_WORDS[name] for name in names]
                previous = last_alarms.get(frame.channel, 0)
                record["changed"] = [ALARM_WORDS[name] for name in changed(message, word, previous)]
                last_alarms[frame.channel] = word
            out.write(json.dumps(record) + "\n")


if __name__ == "__main__":
    main()
