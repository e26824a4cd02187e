"""Field update on the chip. The thruster image's side (thruster-fw/src/update.rs, board.rs's `ImageSwap`), with its
bootloader (lbv-boot) in the same modelled flash: a payload in DFU signed with the development key the bench images
are built with is handed to the bootloader with its ticket when the master sends `Finish` (the thruster checks the
image info, not the signature), the bootloader judges it at the next start, and the image that runs tells its verdict
in its `Version` reply. The payload is laid into DFU directly: the writes that put it there over the bus are the host
tests' and the bench's (thruster-fw's update tests, lbv's field-update scenario). The master image's own update,
whole: put over MAVLink FTP on its VCP, written into DFU, checked and marked when applied."""

import struct

import pytest

from conftest import image, rehost
from g431.chip import Stm32g4
from g431.core import FLASH_BASE
from master import Ftp, mavlink
from master import start as start_master
from thruster import exchange, set_analog, set_halls

FAMILIES = {"thruster-fw": "seabotix", "thruster-fw-legacy": "legacy"}
# embassy-boot 0.7 (lib.rs): the state partition's magic, eight bytes of it: an update marked for the swap, and an
# image that runs confirmed (what `mark_booted` writes, as the bootloader does when it refuses an image).
SWAP_MAGIC = 0xF0
BOOT_MAGIC = 0xD0
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


def flash(chip, address, length):
    return bytes(chip.flash[address - FLASH_BASE : address - FLASH_BASE + length])


def started(chip, spec, update, expected):
    """The image running again after its bootloader, at rest and past its trial check: its `Version` reply."""
    chip.run_until(chip.idle, seconds=0.5, what="the image started by its bootloader reaching idle")
    chip.run_for(0.05)
    exchange(chip, spec, expected["orders"][spec["family"]]["0"])
    version = command(chip, spec, update["version"], update["version_reply_len"])
    assert (version["command"], version["result"]) == ("Version", "done"), version
    return version["version"]


def reboot(chip, spec, update):
    rebooted = command(chip, spec, update["reboot"], update["reboot_reply_len"])
    assert (rebooted["command"], rebooted["result"]) == ("Reboot", "done"), rebooted
    chip.run_until(lambda: chip.resets, seconds=0.2, what="the reset after Reboot")
    assert [kind for _, kind in chip.resets] == ["software"]
    chip.resets.clear()


@pytest.mark.parametrize("name", list(FAMILIES))
def test_the_thruster_marks_a_payload_with_its_ticket_and_its_bootloader_judges_it(name, expected):
    """A signature one bit off no longer stops `Finish`: the ticket carries it to the bootloader, which refuses the
    image at the next start (Signature), clears the mark and starts the image that ran, which tells the verdict in
    its `Version` reply. The right signature, marked the same way, is swapped in at the next start."""
    spec = expected["images"][name]
    update = rehost("update", FAMILIES[name])
    verdicts = expected["boot"]["verdicts"]
    state, ticket_page, active, dfu = update["state"], update["ticket_page"], update["active"], update["dfu"]
    payload = bytes.fromhex(update["payload"])
    chip = Stm32g4(image("thruster-boot"), application=image(name))
    chip.flash[dfu - FLASH_BASE : dfu - FLASH_BASE + len(payload)] = payload
    running = flash(chip, active, expected["boot"]["thruster"]["active"]["length"])
    set_analog(chip, spec)
    set_halls(chip, spec["forward"][0]["hall"])
    chip.power_on()
    wait = update["finish_wait_ms"] / 1000

    version = started(chip, spec, update, expected)
    assert (version["on_trial"], version["marked"], version["verdict"]) == (False, False, None), version
    begun = command(chip, spec, update["begin"], update["begin_reply_len"])
    assert (begun["command"], begun["result"]) == ("Begin", "done"), begun
    forged = command(chip, spec, update["finish_forged"], update["finish_reply_len"], wait)
    assert (forged["command"], forged["result"]) == ("Finish", "done"), forged
    ticket = bytes.fromhex(update["ticket_forged"])
    assert flash(chip, ticket_page, len(ticket)) == ticket, "the ticket, with the signature as sent"
    assert flash(chip, state, 8) == bytes([SWAP_MAGIC] * 8)
    version = command(chip, spec, update["version"], update["version_reply_len"])
    assert version["version"]["marked"], version

    # The bootloader refuses it: its verdict in the record, the mark cleared, the same image started again.
    reboot(chip, spec, update)
    version = started(chip, spec, update, expected)
    assert (version["verdict"], version["marked"], version["on_trial"]) == ("Signature", False, False), version
    assert flash(chip, ticket_page + expected["boot"]["verdict_offset"], 8).hex() == verdicts["Signature"]["word"]
    assert flash(chip, state, 8) == bytes([BOOT_MAGIC] * 8)
    assert flash(chip, active, len(running)) == running, "ACTIVE untouched"
    assert flash(chip, dfu, len(payload)) == payload, "DFU untouched"

    # The right signature: marked, and swapped in at the next start.
    begun = command(chip, spec, update["begin"], update["begin_reply_len"])
    assert (begun["command"], begun["result"]) == ("Begin", "done"), begun
    finished = command(chip, spec, update["finish"], update["finish_reply_len"], wait)
    assert (finished["command"], finished["result"]) == ("Finish", "done"), finished
    ticket = bytes.fromhex(update["ticket"])
    assert flash(chip, ticket_page, 256) == ticket + b"\xff" * (256 - len(ticket)), "a new ticket, no verdict"
    assert flash(chip, state, 8) == bytes([SWAP_MAGIC] * 8)
    reboot(chip, spec, update)
    chip.run_until(lambda: chip.core.pc == update["reset_handler"], seconds=5, what="the new image's reset handler")
    assert chip.resets == []
    assert flash(chip, active, len(payload)) == payload
    assert flash(chip, dfu + expected["boot"]["page"], len(running)) == running, "the old image kept in DFU"


# MAVLink FTP (the wire format lbv-master-fw/src/update/ftp.rs serves): opcodes and the payload's header.
APPLY_UPDATE = 31010
IN_PROGRESS, FAILED = 5, 4


def apply_master(chip, ground):
    """The apply command for the master: its COMMAND_ACK results until one is not IN_PROGRESS (or a reset)."""
    before = len(ground.of("COMMAND_ACK"))
    ground.send(mavlink.MAVLink_command_long_message(1, 1, APPLY_UPDATE, 0, 255, 0, 0, 0, 0, 0, 0))

    def results():
        return [m.result for m in ground.of("COMMAND_ACK")[before:] if m.command == APPLY_UPDATE]

    chip.run_until(lambda: (results() and results()[-1] != IN_PROGRESS) or chip.resets, 5.0, "the apply's end")
    return results()


def test_a_master_image_put_over_ftp_is_checked_on_the_chip_and_marked_for_the_swap(expected, figures):
    """The master image's own update (lbv-master-fw/src/update/own.rs) on the modelled G474: an update file put over MAVLink
    FTP on the VCP goes into DFU (bank 2, by embassy-stm32's async flash driver and the FLASH interrupt); applied,
    a signature one bit off is refused and marks nothing, and the good one is checked with salty, its ticket written
    for the bootloader, embassy-boot's state marked for the swap, and the master restarts. (While a page goes to
    flash, some 43 ms in bank 2, the master reads nothing from its VCP; the request that arrives meanwhile can be
    lost, and the client sends it again: the figures count them.)"""
    update = rehost("update", "master")
    dfu, state = update["dfu"], update["state"]
    chip, _, ground = start_master("lbv-master-fw", expected)
    # The vehicle takes the operator's orders once it has published whom it takes them from.
    ground.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
    chip.run_for(0.2)
    # The VCP has no signing: updates over it must be allowed (LBV_UPD_UNSIGNED, kept in flash like any parameter).
    ground.send(mavlink.MAVLink_param_set_message(1, 1, b"LBV_UPD_UNSIGNED", 1.0, mavlink.MAV_PARAM_TYPE_REAL32))
    allowed = ground.wait("PARAM_VALUE", 1.0, lambda m: m.param_id == "LBV_UPD_UNSIGNED")
    assert allowed.param_value == 1.0
    ftp = Ftp(chip, ground)

    forged = bytes.fromhex(update["forged"])
    ftp.put("/update/master.lbvu", forged)
    payload = forged[80:]
    # Its last page goes to flash after the upload's end: an erase and a page of programs in bank 2.
    chip.run_until(lambda: flash(chip, dfu, len(payload)) == payload, seconds=0.5, what="DFU holding the payload")
    assert apply_master(chip, ground) == [IN_PROGRESS, FAILED]
    assert chip.resets == []
    assert flash(chip, state, 8) != bytes([SWAP_MAGIC] * 8)

    ftp.put("/update/master.lbvu", bytes.fromhex(update["file"]))
    requests = ftp.seq
    figures["lbv-master-fw FTP upload, 2 x 4 KiB"] = f"{ftp.resent} of {requests} requests sent again"
    assert apply_master(chip, ground) == [IN_PROGRESS]
    texts = [m.text for m in ground.of("STATUSTEXT") if m.text.startswith("master.lbvu: ")]
    assert "master.lbvu: signature bad: image refused" in texts, texts
    assert texts[-1] == "master.lbvu: signature good, restarting", texts
    assert [kind for _, kind in chip.resets] == ["software"]
    assert flash(chip, state, 8) == bytes([SWAP_MAGIC] * 8)
    ticket = bytes.fromhex(update["ticket"])
    assert flash(chip, update["ticket_page"], len(ticket)) == ticket, "the ticket for its bootloader"
