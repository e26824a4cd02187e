"""The post-mortem record on the chip. Each way the master image stops (a panic, a HardFault, an NMI, an interrupt it
never enables, the watchdog) leaves a record at the bottom of RAM that the next start reads, tells the ground
station of (STATUSTEXT) and serves over MAVLink FTP as `@SYS/crash/master.bin`; a power-on start shows none,
whatever RAM held; a record torn in RAM is refused by its CRC. Each way a thruster image stops leaves one too,
which its next start reads and logs. The record is read here as its format is documented (crash-record's lib.rs:
little-endian fields, zlib's CRC-32), not by the crate that writes it."""

import struct
import zlib

import pytest
from unicorn import arm_const as arm

from g431.chip import CRASH_REGION, kept_ram
from g431.core import G474RE, IRQ0, NMI, SRAM_BASE
from master import Ftp, start
from test_faults import call, driving, symbol_ending
from thruster import set_analog
from conftest import rehost
from test_update import FAMILIES, command

CRASH = "@SYS/crash/master.bin"
KINDS = {"panic": 1, "hard fault": 2, "nmi": 3, "stray interrupt": 4, "watchdog": 5}
# RCC_CSR's IWDGRSTF (RM0440 7.4.30): every stop ends in the watchdog's reset.
IWDGRSTF = 1 << 29
# Events (crash-record's `What`): the image started, a thruster answers again, a thruster's orders lost (its link
# failsafe tripped), a fault stopped a thruster's motor (its FAULT bits).
STARTED, THRUSTER_BACK, ORDERS_LOST, FAULT_LATCHED = 1, 5, 9, 10
# tmc-proto's Faults: a stalled motor.
STALL = 1 << 1
# Where the test puts what it injects: RAM far below any stack's reach, above what the master keeps there.
SCRATCH = SRAM_BASE + kept_ram(G474RE) + 0x800
FILE, LINE = b"src/injected.rs", 42
# FileNotFound (MAVLink FTP's NAK code 10).
FILE_NOT_FOUND = 10


def decode(data):
    """The record as its format says: refused (None) unless magic, format and CRC hold."""
    if len(data) != 128 or data[:4] != b"LBVC" or data[4] != 1:
        return None
    if struct.unpack_from("<I", data, 124)[0] != zlib.crc32(data[:124]):
        return None
    words = struct.unpack_from("<12I", data, 12)
    names = ("pc", "lr", "xpsr", "sp", "cfsr", "hfsr", "mmfar", "bfar", "reset_cause", "uptime_ms", "file", "line")
    record = dict(zip(names, words), kind=data[5], target=data[6], told=bool(data[7] & 1))
    record["file_len"], record["exception"] = struct.unpack_from("<HH", data, 60)
    record["events"] = [struct.unpack_from("<IHH", data, 68 + 8 * n) for n in range(data[64])]
    return record


def in_thread_mode(chip):
    chip.run_until(lambda: not chip.core.active and not chip.core.sleeping, 0.01, "thread mode")


def inject(chip, fault):
    """Stops the master as `fault` would; the PC it stopped at (None where no frame is stacked)."""
    uc = chip.core.uc
    in_thread_mode(chip)
    pc = chip.core.pc
    if fault == "panic":
        # core::panicking::panic_bounds_check(index, len, &Location) from a task, its Location (file, line, column)
        # and path laid in RAM.
        path_at, location_at = SCRATCH, SCRATCH + 0x40
        uc.mem_write(path_at, FILE)
        uc.mem_write(location_at, struct.pack("<IIII", path_at, len(FILE), LINE, 7))
        function = next(a for n, a in chip.image.symbols.items() if n.endswith("9panicking18panic_bounds_check"))
        uc.reg_write(arm.UC_ARM_REG_R0, 5)
        uc.reg_write(arm.UC_ARM_REG_R1, 3)
        uc.reg_write(arm.UC_ARM_REG_R2, location_at)
        uc.reg_write(arm.UC_ARM_REG_LR, pc | 1)
        chip.core.pc = function & ~1
        return None
    if fault == "hard fault":
        chip.core.enter_fault("a bus fault injected by the test", pc)
        return pc
    if fault == "nmi":
        chip.core.pend(NMI)
        return None
    if fault == "stray interrupt":
        # WWDG's interrupt, which the image never enables: enabled and pended as a wild write would.
        chip.nvic.enabled.add(IRQ0 + 0)
        chip.nvic.set_pending(IRQ0 + 0)
        return None
    # A task that never yields, interrupts masked: `b .` in RAM, and nothing feeds the watchdog.
    uc.mem_write(SCRATCH, bytes([0xFE, 0xE7]))
    uc.reg_write(arm.UC_ARM_REG_PRIMASK, 1)
    chip.core.pc = SCRATCH
    return None


def crashed(chip, ground, fault):
    """Injects `fault` into a master that has polled its thrusters for a while, and runs it until the watchdog has
    reset it."""
    chip.run_for(0.3)
    resets = len(chip.resets)
    pc = inject(chip, fault)
    chip.run_until(lambda: len(chip.resets) > resets, 2.5, f"the watchdog's reset after the {fault}")
    assert chip.resets[-1][1] == "watchdog", chip.resets
    return pc


def told(ground):
    return [m.text for m in ground.of("STATUSTEXT") if "Crash before this start" in m.text or "Its record" in m.text]


@pytest.mark.parametrize("fault", list(KINDS))
def test_each_stop_leaves_a_record_the_next_start_tells_and_serves(fault, expected):
    chip, _, ground = start("lbv-master-fw", expected)
    pc = crashed(chip, ground, fault)
    before = len(ground.of("STATUSTEXT"))
    chip.run_until(lambda: len(told(ground)) >= 2, 1.0, "the record told")
    texts = told(ground)
    assert texts[-1] == "Its record: ftp get @SYS/crash/master.bin", texts
    record = decode(Ftp(chip, ground).get(CRASH))
    assert record is not None, "a record the documented format refuses"
    assert record["kind"] == KINDS[fault], record
    assert record["target"] == 3 and record["told"], record  # the master, as update files name it
    assert record["reset_cause"] & IWDGRSTF, f"{record['reset_cause']:#x}"
    # The last events before it: the start, then the thrusters answering (T1 at least).
    codes = [(code, arg) for _, code, arg in record["events"]]
    assert codes[0][0] == STARTED, codes
    assert (THRUSTER_BACK, 0) in codes, codes
    assert 200 <= record["uptime_ms"] <= 2000 or fault == "watchdog", record["uptime_ms"]
    if fault == "panic":
        assert (record["file"], record["file_len"], record["line"]) == (SCRATCH, len(FILE), LINE), record
    elif fault == "hard fault":
        assert record["pc"] == pc, f"{record['pc']:#x} {pc:#x}"
        assert record["exception"] == 3, record
    elif fault == "nmi":
        assert record["exception"] == 2, record
    elif fault == "stray interrupt":
        assert record["exception"] == 16 + 0, record
    else:
        assert record["pc"] == 0 and record["exception"] == 0, record
    if fault == "hard fault":
        # Told once: a later reset serves it still, untold again.
        chip.request_reset("software")
        chip.run_for(0.3)
        assert len(told(ground)) == len(texts), told(ground)
        assert decode(Ftp(chip, ground).get(CRASH))["kind"] == KINDS[fault]
        assert len(ground.of("STATUSTEXT")) > before


def test_a_power_on_start_shows_no_record_and_a_torn_one_is_refused(expected):
    chip, _, ground = start("lbv-master-fw", expected)
    ftp = Ftp(chip, ground)
    assert ftp.get(CRASH) is None and ftp.refused == FILE_NOT_FOUND, "a record at the first power-on"
    assert len(bytes(chip.core.uc.mem_read(SRAM_BASE, CRASH_REGION))) == expected["crash_region"]["length"]
    crashed(chip, ground, "hard fault")
    chip.run_until(lambda: len(told(ground)) >= 2, 1.0, "the record told")
    assert ftp.get(CRASH) is not None
    # A byte of the record changed in RAM (as a cut or a stray write would): the next start refuses it.
    byte = chip.core.uc.mem_read(SRAM_BASE + 20, 1)[0]
    chip.core.uc.mem_write(SRAM_BASE + 20, bytes([byte ^ 0x10]))
    chip.request_reset("software")
    chip.run_for(0.3)
    assert ftp.get(CRASH) is None and ftp.refused == FILE_NOT_FOUND
    # A record left in RAM does not survive a power cycle (RAM holds noise then, which is never taken for one).
    crashed(chip, ground, "panic")
    chip.run_for(0.3)
    assert ftp.get(CRASH) is not None
    chip.power_on()
    chip.run_until(chip.idle, seconds=0.2, what="idle after the power cycle")
    chip.run_for(0.3)
    assert ftp.get(CRASH) is None and ftp.refused == FILE_NOT_FOUND
    listed = ftp.reply(3, data=b"@SYS/crash")
    assert listed[3] == 129, "an empty @SYS/crash"


def region(chip):
    return bytes(chip.core.uc.mem_read(SRAM_BASE, 128))


@pytest.mark.parametrize("fault", list(KINDS))
def test_each_stop_of_a_thruster_leaves_a_record_its_next_start_reads(fault, expected):
    chip, spec = driving(expected)
    in_thread_mode(chip)
    resets = len(chip.resets)
    pc = chip.core.pc
    if fault == "panic":
        call(chip, symbol_ending(chip, "9panicking18panic_bounds_check"), 5, 3, chip.image.symbols["__sdata"])
    elif fault == "watchdog":
        # The sampling task hangs: ADC1 never ends a conversion, and nothing feeds the watchdog.
        chip.adc1.inputs.clear()
        chip.adc1.stuck = True
    else:
        inject(chip, fault)
    timeout = spec["watchdog_timeout_us"] / 1e6
    chip.run_until(lambda: len(chip.resets) > resets, timeout * 1.5, f"the watchdog's reset after the {fault}")
    chip.adc1.stuck = False
    set_analog(chip, spec)
    chip.run_until(chip.idle, 0.05, "idle after the reset")
    record = decode(region(chip))
    assert record is not None, region(chip).hex()
    assert record["kind"] == KINDS[fault], record
    # The update file's target byte of the image's family, why the chip reset, and the start before it.
    assert record["target"] == {"SeaBotix": 1, "Legacy": 2}[spec["family"]], record
    assert record["reset_cause"] & IWDGRSTF, f"{record['reset_cause']:#x}"
    assert record["events"][0][1] == STARTED, record["events"]
    if fault == "hard fault":
        assert (record["pc"], record["exception"]) == (pc, 3), record
    elif fault == "stray interrupt":
        assert record["exception"] == 16, record
    elif fault == "nmi":
        assert record["exception"] == 2, record
    said = [text for _, text in chip.log.lines if "stopped before this start" in text]
    name = {"panic": "panic", "hard fault": "HardFault", "nmi": "NMI", "stray interrupt": "stray interrupt",
            "watchdog": "watchdog reset"}[fault]
    assert said and name in said[-1], chip.log_text()
    # And a master reads it over the bus, as the courier does: `Version` says protocol 2, then two parts of 64.
    update = rehost("update", FAMILIES["thruster-fw"])
    version = command(chip, spec, update["version"], update["version_reply_len"])
    assert version["version"]["protocol"] == 2, version
    parts = [command(chip, spec, frame, update["post_mortem_reply_len"]) for frame in update["post_mortem"]]
    assert [(p["result"], p["post_mortem"]["len"], p["post_mortem"]["offset"]) for p in parts] == [
        ("done", 128, 0), ("done", 128, 64)], parts
    assert b"".join(bytes.fromhex(p["post_mortem"]["data"]) for p in parts) == region(chip)


def test_a_thruster_notes_a_stall_and_its_orders_lost_and_its_record_keeps_them(expected):
    """The binding hands the region to the tasks: what they note reaches the record of the next stop."""
    chip, spec = driving(expected)
    # One order, then nothing: the held rotor stalls (its 400 ms window), then the link failsafe trips (1 s).
    chip.run_for(1.1)
    resets = len(chip.resets)
    inject(chip, "hard fault")
    timeout = spec["watchdog_timeout_us"] / 1e6
    chip.run_until(lambda: len(chip.resets) > resets, timeout * 1.5, "the watchdog's reset after the hard fault")
    set_analog(chip, spec)
    chip.run_until(chip.idle, 0.05, "idle after the reset")
    record = decode(region(chip))
    assert record is not None, region(chip).hex()
    codes = [code for _, code, _ in record["events"]]
    assert codes == [STARTED, FAULT_LATCHED, ORDERS_LOST], record["events"]
    _, _, bits = record["events"][1]
    assert bits & STALL, record["events"]
    stalled_at, lost_at = record["events"][1][0], record["events"][2][0]
    assert 0.4 <= stalled_at / 1000 < 1.0 and lost_at > stalled_at, record["events"]
