"""Field update on the chip. The thruster image's side (thruster-fw/src/board.rs, `ImageSwap`): a payload in its DFU
partition, signed with the development key the bench images are built with, is checked with salty on the modelled
Cortex-M4 when the master sends `Finish`, and embassy-boot's state is marked for the swap; a signature one bit off
is refused and marks nothing. The payload is laid into DFU directly: the writes that put it there over the bus are
the host tests' and the bench's (thruster-fw's update tests, lbv's field-update scenario). The master image's own
update, whole: put over MAVLink FTP on its VCP, written into DFU, checked and marked when applied."""

import struct

import pytest

from conftest import rehost
from master import mavlink
from master import start as start_master
from thruster import exchange, start

FAMILIES = {"thruster-fw": "seabotix", "thruster-fw-legacy": "legacy"}
# embassy-boot 0.7 (`SWAP_MAGIC`, lib.rs): the state partition's magic once an update is marked for the swap.
SWAP_MAGIC = 0xF0
# The master reads a reply again this often while it is busy (lbv-master-fw's courier).
BUSY_PAUSE_S = 0.002


def command(chip, spec, frame, reply_len, wait_s=0.0):
    """Write an extension command, wait as the master does, read its reply until it is not busy; decoded."""
    i2c = chip.i2c[3]
    written = i2c.master_transfer(spec["address"], bytes.fromhex(frame))
    chip.run_until(lambda: written.done, seconds=0.05, what="the command written")
    assert written.error is None, written.error
    chip.run_for(wait_s)
    for _ in range(500):
        read = i2c.master_transfer(spec["address"], read_length=reply_len)
        chip.run_until(lambda: read.done, seconds=0.05, what="the reply read")
        assert read.error is None, read.error
        reply = rehost("reply", bytes(read.read).hex())
        if reply["result"] != "busy":
            return reply
        chip.run_for(BUSY_PAUSE_S)
    raise AssertionError("still busy after 500 reads")


@pytest.mark.parametrize("name", list(FAMILIES))
def test_a_signed_payload_in_dfu_is_checked_on_the_chip_and_marked_for_the_swap(name, expected):
    chip, spec = start(name, expected)
    update = rehost("update", FAMILIES[name])
    payload = bytes.fromhex(update["payload"])
    dfu, state = update["dfu"], update["state"]
    offset = dfu - 0x0800_0000
    chip.flash[offset : offset + len(payload)] = payload
    chip.core.uc.mem_write(dfu, payload)
    # Updates are taken at a zero order only.
    exchange(chip, spec, expected["orders"][spec["family"]]["0"])
    begun = command(chip, spec, update["begin"], update["begin_reply_len"])
    assert (begun["command"], begun["result"]) == ("Begin", "done"), begun

    wait = update["finish_wait_ms"] / 1000
    forged = command(chip, spec, update["finish_forged"], update["finish_reply_len"], wait)
    assert (forged["command"], forged["result"]) == ("Finish", "BadSignature"), forged
    assert chip.flash_word(state) != SWAP_MAGIC * 0x0101_0101, "a forged signature marked the update"

    finished = command(chip, spec, update["finish"], update["finish_reply_len"], wait)
    assert (finished["command"], finished["result"]) == ("Finish", "done"), finished
    magic = bytes(chip.flash[state - 0x0800_0000 : state - 0x0800_0000 + 8])
    assert magic == bytes([SWAP_MAGIC] * 8), magic.hex()


# MAVLink FTP (the wire format lbv-master-fw/src/update/ftp.rs serves): opcodes and the payload's header.
FTP_TERMINATE, FTP_CREATE, FTP_WRITE, FTP_ACK = 1, 6, 7, 128
FTP_DATA = 239
APPLY_UPDATE = 31010
IN_PROGRESS, FAILED = 5, 4


class Ftp:
    """An operator's MAVLink FTP client on the modelled VCP, one request at a time."""

    def __init__(self, chip, ground):
        self.chip, self.ground, self.seq = chip, ground, 0

    def request(self, opcode, session=0, offset=0, data=b""):
        self.seq += 1
        header = struct.pack("<HBBBBBBI", self.seq, session, opcode, len(data), 0, 0, 0, offset)
        payload = (header + data).ljust(251, b"\0")
        self.ground.send(mavlink.MAVLink_file_transfer_protocol_message(0, 1, 1, list(payload)))
        seq = self.seq
        reply = self.ground.wait(
            "FILE_TRANSFER_PROTOCOL", 1.0, lambda m: struct.unpack_from("<H", bytes(m.payload))[0] == seq + 1
        )
        reply = bytes(reply.payload)
        assert reply[3] == FTP_ACK, f"opcode {opcode}: NAK {reply[12]}"
        return reply[2]

    def put(self, path, file):
        session = self.request(FTP_CREATE, data=path.encode())
        for offset in range(0, len(file), FTP_DATA):
            self.request(FTP_WRITE, session, offset, file[offset : offset + FTP_DATA])
        self.request(FTP_TERMINATE, session)


def apply_master(chip, ground):
    """The apply command for the master: its COMMAND_ACK results until one is not IN_PROGRESS (or a reset)."""
    before = len(ground.of("COMMAND_ACK"))
    ground.send(mavlink.MAVLink_command_long_message(1, 1, APPLY_UPDATE, 0, 255, 0, 0, 0, 0, 0, 0))

    def results():
        return [m.result for m in ground.of("COMMAND_ACK")[before:] if m.command == APPLY_UPDATE]

    chip.run_until(lambda: (results() and results()[-1] != IN_PROGRESS) or chip.resets, 5.0, "the apply's end")
    return results()


def test_a_master_image_put_over_ftp_is_checked_on_the_chip_and_marked_for_the_swap(expected):
    """The master image's own update (lbv-master-fw/src/own.rs) on the modelled G474: an update file put over MAVLink
    FTP on the VCP goes into DFU (bank 2, by embassy-stm32's async flash driver and the FLASH interrupt); applied,
    a signature one bit off is refused and marks nothing, and the good one is checked with salty, marks embassy-boot's
    state for the swap and restarts the master."""
    update = rehost("update", "master")
    dfu, state = update["dfu"], update["state"]
    chip, _, ground = start_master("lbv-master-fw", expected)
    # The vehicle takes the operator's orders once it has published whom it takes them from.
    ground.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
    chip.run_for(0.2)
    ftp = Ftp(chip, ground)

    forged = bytes.fromhex(update["forged"])
    ftp.put("/update/master.lbvu", forged)
    payload = forged[80:]
    assert bytes(chip.flash[dfu - 0x0800_0000 : dfu - 0x0800_0000 + len(payload)]) == payload, "DFU holds the payload"
    assert apply_master(chip, ground) == [IN_PROGRESS, FAILED]
    assert chip.resets == []
    assert bytes(chip.flash[state - 0x0800_0000 : state - 0x0800_0000 + 8]) != bytes([SWAP_MAGIC] * 8)

    ftp.put("/update/master.lbvu", bytes.fromhex(update["file"]))
    assert apply_master(chip, ground) == [IN_PROGRESS]
    texts = [m.text for m in ground.of("STATUSTEXT") if m.text.startswith("master.lbvu: ")]
    assert "master.lbvu: signature bad: image refused" in texts, texts
    assert texts[-1] == "master.lbvu: signature good, restarting", texts
    assert [kind for _, kind in chip.resets] == ["software"]
    magic = bytes(chip.flash[state - 0x0800_0000 : state - 0x0800_0000 + 8])
    assert magic == bytes([SWAP_MAGIC] * 8), magic.hex()
