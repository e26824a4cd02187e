"""The thruster image's side of a field update on the chip (thruster-fw/src/board.rs, `ImageSwap`): a payload in its
DFU partition, signed with the development key the bench images are built with, is checked with salty on the
modelled Cortex-M4 when the master sends `Finish`, and embassy-boot's state is marked for the swap; a signature one
bit off is refused and marks nothing. The payload is laid into DFU directly: the writes that put it there over the
bus are the host tests' and the bench's (thruster-fw's update tests, lbv's field-update scenario)."""

import pytest

from conftest import rehost
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
