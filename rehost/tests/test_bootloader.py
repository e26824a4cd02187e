"""The bootloader (lbv-boot), built for the thruster's G431 and for the master's G474, under the models: it starts
the image in ACTIVE with that image's vector table, stack pointer and reset handler, starts the trial watchdog first
(the thruster's after it has driven the power stage's gate inputs off), and checks an image marked for the swap
before it swaps it in: the application's ticket in the record, the image info, the bytes past the payload and the
signature with the key the running image embeds. A good image is swapped in through the flash interface's erase
and programming sequences, byte for byte as embassy-boot's swap does on the host (lbv-boot's tests), with the
watchdog fed between every flash operation; a refused one leaves its verdict in the record and the old image starts.
On the G474 the swap crosses the banks: ACTIVE in bank 1, DFU in bank 2.

The partitions and the formats come from `rehost expected` (g431_hw::memory, update-image); the made-up images are
signed with a key the tests hold (`rehost sign`)."""

import hashlib
import random
import struct
from dataclasses import dataclass

import pytest
from unicorn import arm_const as arm

from conftest import image, sign
from g431.chip import Stm32g4
from g431.core import FLASH_BASE, G431RB, G474RE, SRAM_BASE
from g431.gpio import MODER, ODR
from g431.iwdg import KR, PR, RLR, START
from g431.system import ERASE_US, PROGRAM_US

# embassy-boot 0.7 (lib.rs): the state partition's magic, eight bytes of it: an update marked for the swap, and an
# image that runs confirmed (what `mark_booted` writes).
SWAP_MAGIC = bytes([0xF0] * 8)
BOOT_MAGIC = bytes([0xD0] * 8)
# The secret key the tests sign their images with, and the running images embed its public half.
SEED = "7e57" * 16
# LSI at its fastest (DS12589 Table 48: 34 kHz): the trial watchdog at its shortest, 2.0 s.
LSI_FASTEST_HZ = 34_000


@dataclass
class Board:
    """A bootloader image and its partitions (`rehost expected`: g431_hw::memory's THRUSTER_PARTITIONS and
    MASTER_PARTITIONS)."""

    name: str
    image: str
    target: int
    state: int
    state_bytes: int
    ticket: int
    counter: int
    active: int
    active_bytes: int
    dfu: int
    page: int
    # Where a made-up application puts its stack: near the top of the chip's RAM.
    stack: int
    # update-image's offsets in an image: its info, the key after it; and in the record's first page.
    info_offset: int
    key_offset: int
    min_payload: int
    verdict_offset: int
    previous_offset: int
    verdicts: dict

    @property
    def reset_handler(self):
        """A made-up application's reset handler: just past its info and key."""
        return self.active + self.min_payload

    @property
    def pages(self):
        return self.active_bytes // self.page


def board_of(expected, name):
    boot = expected["boot"]
    parts = boot[name]
    target = boot["targets"]["ThrusterSeabotix" if name == "thruster" else "Master"]
    sram = (G431RB if name == "thruster" else G474RE).sram_size
    return Board(
        name=name,
        image=f"{name}-boot",
        target=target,
        state=parts["state"]["origin"],
        state_bytes=parts["state"]["length"],
        ticket=parts["ticket"]["origin"],
        counter=parts["counter"]["origin"],
        active=parts["active"]["origin"],
        active_bytes=parts["active"]["length"],
        dfu=parts["dfu"]["origin"],
        page=boot["page"],
        stack=SRAM_BASE + sram - 0x1000,
        info_offset=boot["info_offset"],
        key_offset=boot["key_offset"],
        min_payload=boot["min_payload"],
        verdict_offset=boot["verdict_offset"],
        previous_offset=boot["previous_offset"],
        verdicts={name: bytes.fromhex(verdict["word"]) for name, verdict in boot["verdicts"].items()},
    )


BOARDS = ["thruster", "master"]


@pytest.fixture(params=BOARDS)
def board(request, expected):
    return board_of(expected, request.param)


@pytest.fixture(scope="session")
def key(expected):
    """The public half of the tests' key (`rehost sign` on the shortest image)."""
    board = board_of(expected, "thruster")
    return sign(SEED, application(board, 0, board.min_payload + 8, 0, bytes(32)))["public_key"]


def info(target, version=(1, 0, 0), counter=0):
    """update-image's ImageInfo, format 2, as its table gives it (update-image/src/info.rs): magic, format, target,
    flags, a reserved byte, the version (major, minor, patch u16), the security counter (u32), 16 reserved bytes."""
    major, minor, patch = version
    return b"LBVI" + bytes([2, target, 0, 0, major, minor]) + struct.pack("<HI", patch, counter) + bytes(16)


def application(board, seed, length, stack_pointer, key, version=(1, 0, 0), counter=0):
    """A made-up image of `length` bytes linked at ACTIVE: its vector table (the initial stack pointer, the reset
    handler), its image info for the board's target and the update key after it, the reset handler (a branch to
    itself), and bytes `seed` picks."""
    body = bytearray(random.Random(seed).randbytes(length))
    struct.pack_into("<II", body, 0, stack_pointer, board.reset_handler | 1)
    body[board.info_offset : board.info_offset + 32] = info(board.target, version, counter)
    body[board.key_offset : board.key_offset + 32] = key
    struct.pack_into("<H", body, board.reset_handler - board.active, 0xE7FE)  # b .
    return bytes(body)


def chip_with(board, active, dfu=b"", state=b"", ticket=b"", lsi_hz=None):
    chip = Stm32g4(image(board.image))
    lay(chip, [(board.active, active), (board.dfu, dfu), (board.state, state), (board.ticket, ticket)])
    if lsi_hz:
        chip.iwdg.lsi_hz = lsi_hz
    chip.power_on()
    return chip


def lay(chip, pieces):
    for address, data in pieces:
        chip.flash[address - FLASH_BASE : address - FLASH_BASE + len(data)] = data


def flash(chip, address, length):
    return bytes(chip.flash[address - FLASH_BASE : address - FLASH_BASE + length])


def padded(board, data):
    """`data` as it sits in ACTIVE: the rest of the partition erased."""
    return data + b"\xff" * (board.active_bytes - len(data))


def run_to_the_application(board, chip, seconds):
    chip.run_until(
        lambda: chip.core.pc == board.reset_handler, seconds=seconds, what="the application's reset handler"
    )
    assert chip.core.fault is None
    assert chip.resets == [], "no reset on the way"


def on_first_write(peripheral, take, when=lambda offset, value: True):
    """Calls `take()` at the first write to `peripheral` that `when` picks, before the write lands; its result goes
    into the list returned."""
    taken = []
    write = peripheral.write

    def watched(offset, value):
        if not taken and when(offset, value):
            taken.append(take())
        write(offset, value)

    peripheral.write = watched
    return taken


def pins(chip):
    """What the GPIO models hold: each port's MODER and ODR, and the pins moved from their reset state."""
    return {
        letter: {"moder": port.regs.get(MODER, 0), "odr": port.regs.get(ODR, 0), "moved": port.changed_pins()}
        for letter, port in chip.gpio.items()
    }


def gate_levels(expected):
    """The power stage's six gate inputs, the phases' pins of the thruster image (g431_hw::images), each at the level
    that holds its switch off: the L6398's HIN is active high, its LIN active low (ST's L6398 datasheet)."""
    return {
        (pin["port"], pin["pin"]): 0 if pin["function"].endswith(" high") else 1
        for pin in expected["images"]["thruster-fw"]["pins"]
        if pin["function"].startswith("phase ") and pin["function"].endswith((" high", " low"))
    }


def assert_gates_off(snapshot, expected):
    """The six gate inputs are outputs at their off level, as g431_hw::images::THRUSTER_GATES_OFF writes them and
    as the power stage needs them, and no other pin has moved."""
    levels = gate_levels(expected)
    assert len(levels) == 6, levels
    for write in expected["boot"]["thruster_gates_off"]:
        port = snapshot[write["port"]]
        assert port["moder"] & write["moder_mask"] == write["moder_output"], f"GPIO{write['port']} MODER"
        high, low = write["bsrr"] & 0xFFFF, write["bsrr"] >> 16
        assert (port["odr"] & high, port["odr"] & low) == (high, 0), f"GPIO{write['port']} ODR"
    for (letter, pin), level in levels.items():
        assert (snapshot[letter]["moder"] >> 2 * pin) & 3 == 1, f"P{letter}{pin} an output"
        assert (snapshot[letter]["odr"] >> pin) & 1 == level, f"P{letter}{pin} at {level}"
    moved = {(letter, pin) for letter, port in snapshot.items() for pin in port["moved"]}
    assert moved == set(levels), moved


def refused(board, chip, verdict, old, dfu):
    """The image marked was refused with `verdict`: its word is in the record's first verdict slot, the state is
    embassy-boot's BOOT, the old image runs and nothing was written in ACTIVE or DFU."""
    slots = flash(chip, board.ticket + board.verdict_offset, 64)
    assert slots[:8] == board.verdicts[verdict], slots[:8].hex()
    assert slots[8:] == b"\xff" * 56
    state = flash(chip, board.state, board.state_bytes)
    assert state[:8] == BOOT_MAGIC, state[:8].hex()
    assert state[8:] == b"\xff" * (board.state_bytes - 8), "the swap's progress cleared"
    assert flash(chip, board.active, board.active_bytes) == old
    assert flash(chip, board.dfu, len(dfu)) == dfu, "DFU left as it was"
    assert chip.core.uc.reg_read(arm.UC_ARM_REG_MSP) == board.stack, "the old image's stack pointer"
    touched = {address for _, _, _, address in chip.flash_interface.operations}
    assert all(
        board.state <= address < board.state + board.state_bytes or board.ticket <= address < board.ticket + board.page
        for address in touched
    ), "only the state and the ticket page are written"


def test_the_bootloader_starts_the_image_in_active_with_its_vector_table_and_the_trial_watchdog(board, expected, key):
    app = application(board, 1, board.active_bytes, board.stack - 0x100, key)
    chip = chip_with(board, app)
    run_to_the_application(board, chip, seconds=0.01)
    assert chip.core.vtor == board.active
    assert chip.core.uc.reg_read(arm.UC_ARM_REG_MSP) == board.stack - 0x100
    assert chip.iwdg.running
    trial = expected["boot"]["trial"]
    assert (chip.iwdg.regs.get(PR), chip.iwdg.regs.get(RLR)) == (trial["pr"], trial["rlr"])
    assert chip.flash_interface.operations == [], "nothing to swap, no counter to raise: nothing written"
    assert flash(chip, board.active, board.active_bytes) == app
    # The image finds the chip as the reset left it: the clocks on HSI16, the reset flags not cleared.
    assert chip.rcc.sysclk_hz() == 16_000_000
    if board.name == "thruster":
        assert_gates_off(pins(chip), expected)
    else:
        assert all(not port.writes for port in chip.gpio.values()), "the master's bootloader moves no pin"
    # Left alone, the trial watchdog resets the chip after its 2.1 s at 32 kHz.
    chip.run_for(2.2)
    assert [kind for _, kind in chip.resets] == ["watchdog"]


# The good image's payload: the thruster's nearly fills ACTIVE; the master's is the size of its application (some
# 136 KiB). Both end inside a page, and DFU holds stray bytes in the pages after, which the swap must not carry.
PAYLOAD = {"thruster": 46 * 1024 - 0x100, "master": 136 * 1024 - 0x100}
STRAY_PAGES = 2


@dataclass
class Swap:
    board: Board
    old: bytes
    new: bytes
    chip: Stm32g4
    start: int
    checked: dict  # at the first flash operation: instructions run, the pins
    watchdog_started: list  # the pins when the watchdog starts
    watchdog_started_at: int
    active: bytes
    dfu: bytes
    state: bytes
    ticket: bytes
    resets: list
    operations: list
    refreshes: list
    jumped: int  # the cycle the application starts at
    stack: int  # the bootloader's stack high-water mark at the jump
    reverted_active: bytes
    reverted_dfu: bytes
    reverted_stack: int


@pytest.fixture(scope="module", params=BOARDS)
def swap(request, expected, key):
    """A good image marked with its ticket, swapped in with LSI at its fastest (the trial watchdog at its
    shortest); then left to its trial, which it never ends, so the watchdog resets and the bootloader swaps the old
    one back."""
    board = board_of(expected, request.param)
    old = application(board, 2, board.active_bytes, board.stack, key)
    new = application(board, 3, PAYLOAD[board.name], board.stack - 0x1000, key, version=(1, 1, 0))
    signed = sign(SEED, new)
    assert signed["payload_len"] == len(new)
    last = -(-len(new) // board.page) * board.page
    dfu = padded(board, new)[:last] + random.Random(4).randbytes(STRAY_PAGES * board.page)
    chip = Stm32g4(image(board.image))
    lay(chip, [(board.active, old), (board.dfu, dfu), (board.state, SWAP_MAGIC), (board.ticket, signed["ticket"])])
    chip.iwdg.lsi_hz = LSI_FASTEST_HZ
    checked = on_first_write(chip.flash_interface, lambda: {"instructions": chip.core.instructions, "pins": pins(chip)})
    watchdog_started = on_first_write(
        chip.iwdg, lambda: pins(chip), lambda offset, value: offset == KR and value == START
    )
    chip.power_on()
    start = chip.core.cycles
    run_to_the_application(board, chip, seconds=15)
    result = dict(
        board=board,
        old=old,
        new=new,
        chip=chip,
        start=start,
        checked=checked[0],
        watchdog_started=watchdog_started,
        active=flash(chip, board.active, board.active_bytes),
        dfu=flash(chip, board.dfu + board.page, board.active_bytes),
        state=flash(chip, board.state, board.state_bytes),
        ticket=flash(chip, board.ticket, board.page),
        resets=list(chip.resets),
        operations=list(chip.flash_interface.operations),
        refreshes=list(chip.iwdg.refreshes),
        watchdog_started_at=chip.iwdg.started_at,
        jumped=chip.core.cycles,
        stack=chip.stack_high_water(),
    )
    assert chip.core.uc.reg_read(arm.UC_ARM_REG_MSP) == board.stack - 0x1000, "the new image's stack pointer"
    # It never marks itself booted: the trial watchdog resets, and the bootloader swaps the old image back.
    chip.run_until(lambda: chip.resets, seconds=2.5, what="the trial watchdog's reset")
    chip.resets.clear()
    run_to_the_application(board, chip, seconds=15)
    return Swap(
        **result,
        reverted_active=flash(chip, board.active, board.active_bytes),
        reverted_dfu=flash(chip, board.dfu, board.active_bytes),
        reverted_stack=chip.core.uc.reg_read(arm.UC_ARM_REG_MSP),
    )


def test_a_good_image_marked_with_its_ticket_is_swapped_in_and_the_old_one_kept_in_dfu_one_page_up(
    swap, expected, figures
):
    board = swap.board
    assert swap.active == padded(board, swap.new), "the payload, and erased flash where DFU held stray bytes"
    assert swap.dfu == swap.old
    # DFU's pages past the payload's last erased (the stray ones among them), then every page both ways: one erase
    # and 256 double words a page, and a progress word after each page; before them, the note of the image moved
    # out: the first 32 bytes of SHA-512 over ACTIVE, then a checked word, in the ticket's page.
    steps = 2 * board.pages
    past = board.pages - -(-len(swap.new) // board.page)
    erases = [op for op in swap.operations if op[2] == "erase"]
    programs = [op for op in swap.operations if op[2] == "program"]
    assert [address for _, _, _, address in erases[:past]] == [
        board.dfu + board.active_bytes - (past - n) * board.page for n in range(past)
    ]
    assert len(erases) == past + steps
    assert len(programs) == steps * 257 + 5
    previous = swap.ticket[board.previous_offset : board.previous_offset + 40]
    assert previous == hashlib.sha512(swap.old).digest()[:32] + checked_word(0x5052_4556), previous.hex()
    assert swap.state[:8] == SWAP_MAGIC, "on trial until the image marks itself booted"
    assert swap.state[16 : 16 + steps * 8] == bytes(steps * 8), "every step's progress word written"
    assert swap.ticket[board.verdict_offset : board.verdict_offset + 64] == b"\xff" * 64, "no verdict"
    # The bootloader waits for every operation, in either bank: their typical times (system.py) added up. (The
    # model stalls the core for those in the bank it runs from; one in bank 2 keeps BSY set as long.)
    work = (len(erases) * ERASE_US + len(programs) * PROGRAM_US) / 1e6
    took = (swap.jumped - swap.start) / swap.chip.core.hz
    figures[f"{board.image} swap of {board.pages} pages"] = f"{work:.2f} s of flash work, {took:.2f} s to the jump"
    kib = len(swap.new) / 1024
    figures[f"{board.image} check of a {kib:.2f} KiB payload"] = (
        f"{swap.checked['instructions'] / 1e6:.1f} M instructions from reset to the first flash operation "
        f"({swap.checked['instructions'] / swap.chip.core.hz * 1e3:.0f} ms at 170 MHz)"
    )
    # Its stack through the check and the swap, held to its budget (g431_hw::images::BUILDS).
    used, budget = swap.stack, expected["stack_budgets"][board.image]
    figures[f"{board.image} stack high-water"] = f"{used:,} B of its {budget:,} B budget"
    assert used <= budget
    # The old image back: the watchdog reset the new one on trial, and the bootloader swapped back.
    assert swap.reverted_active == swap.old
    assert swap.reverted_dfu == padded(board, swap.new)
    assert swap.reverted_stack == board.stack, "the old image's stack pointer"


def test_the_watchdog_runs_before_the_first_flash_operation_and_is_fed_between_them(swap, figures):
    """Started before the check and the swap, and reloaded (KR = 0xAAAA) before every erase and every write the
    bootloader asks of the flash (a run of pages erased, or of double words programmed, in one go), and once more
    before the jump: through a swap at the datasheet's times and the fastest LSI, the counter never reaches zero."""
    chip, operations, refreshes = swap.chip, swap.operations, swap.refreshes
    assert swap.resets == []
    first = operations[0][0]
    assert swap.watchdog_started_at is not None and swap.watchdog_started_at < first, "started before the first"
    assert refreshes and refreshes[0][0] < first, "the trial timeout loaded before the first flash operation"
    unfed = []
    for before, op in zip(operations, operations[1:]):
        follows = op[2] == before[2] and op[3] == before[3] + (swap.board.page if op[2] == "erase" else 8)
        if not follows and not any(before[1] <= cycle <= op[0] for cycle, _ in refreshes):
            unfed.append((op[2], hex(op[3])))
    assert unfed == [], f"flash operations begun without a reload since the last: {unfed[:5]}"
    assert any(operations[-1][1] <= cycle <= swap.jumped for cycle, _ in refreshes), "fed before the jump"
    # The counter's lowest, at a reload after the trial timeout was loaded.
    lowest = min(counter for cycle, counter in refreshes[1:] if cycle <= swap.jumped)
    reload = chip.iwdg.regs.get(RLR)
    assert lowest > 0
    ticks = chip.core.hz * 4 * 2 ** chip.iwdg.regs.get(PR) / LSI_FASTEST_HZ
    longest = max(b - a for (a, _), (b, _) in zip(refreshes, refreshes[1:]) if b <= swap.jumped)
    figures[f"{swap.board.image} watchdog through the swap"] = (
        f"lowest counter {lowest} of {reload} ({lowest * ticks / chip.core.hz:.2f} s left), "
        f"longest unfed {longest / chip.core.hz * 1e3:.0f} ms, at 34 kHz"
    )


def test_the_gate_inputs_are_held_off_before_the_watchdog_and_before_the_first_flash_operation(swap, expected):
    if swap.board.name == "thruster":
        assert_gates_off(swap.watchdog_started[0], expected)
        assert_gates_off(swap.checked["pins"], expected)
    else:
        assert all(not port["moved"] for port in swap.checked["pins"].values()), "the master's moves no pin"


# A refused image's payload: a few pages, so that the check is short.
SMALL = 8 * 1024 - 0x100


def marked(board, key, payload, tamper=lambda dfu: None, **old):
    """A chip with an old image in ACTIVE and `payload` signed, marked with its ticket, in DFU (which `tamper` may
    change after the signing)."""
    old_image = application(board, 5, board.active_bytes, board.stack, key, **old)
    signed = sign(SEED, payload)
    dfu = bytearray(padded(board, payload))
    tamper(dfu)
    chip = chip_with(board, old_image, dfu=bytes(dfu), state=SWAP_MAGIC, ticket=signed["ticket"])
    return chip, old_image, bytes(dfu)


def test_a_payload_one_bit_off_is_refused_for_its_signature_and_the_old_image_starts(board, key):
    payload = application(board, 6, SMALL, board.stack - 0x1000, key, version=(1, 1, 0))

    def flip(dfu):
        dfu[0x1000] ^= 0x04

    chip, old, dfu = marked(board, key, payload, flip)
    run_to_the_application(board, chip, seconds=2)
    refused(board, chip, "Signature", old, dfu)


def test_a_byte_past_the_payload_in_its_last_page_is_refused_and_the_old_image_starts(board, key):
    payload = application(board, 7, SMALL, board.stack - 0x1000, key, version=(1, 1, 0))

    def stray(dfu):
        dfu[SMALL + 5] = 0x00

    chip, old, dfu = marked(board, key, payload, stray)
    run_to_the_application(board, chip, seconds=2)
    refused(board, chip, "PastPayload", old, dfu)


def checked_word(value):
    """update-image's checked word: the value and its complement, u32 little-endian each."""
    return struct.pack("<II", value, ~value & 0xFFFF_FFFF)


def test_a_confirmed_image_raises_the_stored_security_counter_and_one_below_it_is_refused(board, key):
    assert checked_word(1) == board.verdicts["Signature"], "the verdicts' words are checked words"
    old = application(board, 8, board.active_bytes, board.stack, key, counter=7)
    chip = chip_with(board, old)
    run_to_the_application(board, chip, seconds=0.1)
    journal = flash(chip, board.counter, 2 * board.page)
    assert journal[:8] == checked_word(7), journal[:8].hex()
    assert journal[8:] == b"\xff" * (2 * board.page - 8)
    # A newer image with a lower counter, marked: refused at the next start, before any hashing.
    payload = application(board, 9, SMALL, board.stack - 0x1000, key, version=(1, 1, 0), counter=6)
    signed = sign(SEED, payload)
    lay(chip, [(board.dfu, padded(board, payload)), (board.state, SWAP_MAGIC), (board.ticket, signed["ticket"])])
    chip.flash_interface.operations.clear()
    chip.power_on()
    run_to_the_application(board, chip, seconds=0.1)
    refused(board, chip, "Counter", old, padded(board, payload))
    assert flash(chip, board.counter, 16) == checked_word(7) + b"\xff" * 8, "the stored counter as it was"


def test_a_small_master_image_is_swapped_in_before_the_trial_watchdog_bites(expected, key):
    """A 16 KiB image for the master: DFU's 106 pages past it are erased before the swap, 2.3 s of bank 2's erases at
    the datasheet's time, longer than the trial watchdog: the bootloader feeds it between two pages."""
    board = board_of(expected, "master")
    old = application(board, 10, board.active_bytes, board.stack, key)
    new = application(board, 11, 16 * 1024 - 0x100, board.stack - 0x1000, key, version=(1, 1, 0))
    signed = sign(SEED, new)
    chip = chip_with(board, old, dfu=padded(board, new), state=SWAP_MAGIC, ticket=signed["ticket"])
    chip.run_until(lambda: chip.core.pc == board.reset_handler or chip.resets, seconds=15, what="the jump or a reset")
    assert chip.resets == [], f"{chip.flash_interface.erases} pages erased, then the watchdog reset the chip"
    assert flash(chip, board.active, board.active_bytes) == padded(board, new)


def crash_word(crashes, restored=False):
    """update-image's CrashCount in its backup register: the tag 0x4352, then the count byte's complement, then the
    byte (bit 7: the previous image was put back)."""
    byte = crashes | (0x80 if restored else 0)
    return 0x4352_0000 | ((~byte & 0xFF) << 8) | byte


def test_a_confirmed_image_that_the_watchdog_resets_early_three_times_is_undone(board, expected, key):
    """The new image swapped in, then confirmed (embassy-boot's BOOT magic written over the state, as `mark_booted`
    leaves it), never feeds the watchdog: every watchdog reset is an early crash, counted in TAMP's backup register,
    and at the third the bootloader swaps the image it replaced back in."""
    old = application(board, 12, board.active_bytes, board.stack, key)
    new = application(board, 13, SMALL, board.stack - 0x1000, key, version=(1, 1, 0))
    signed = sign(SEED, new)
    chip = chip_with(board, old, dfu=padded(board, new), state=SWAP_MAGIC, ticket=signed["ticket"])
    run_to_the_application(board, chip, seconds=15)
    assert flash(chip, board.active, board.active_bytes) == padded(board, new)
    confirmed = BOOT_MAGIC + b"\xff" * (board.state_bytes - 8)
    chip.flash[board.state - FLASH_BASE : board.state - FLASH_BASE + board.state_bytes] = confirmed
    chip.core.uc.mem_write(board.state, confirmed)
    register = 0x100 + 4 * expected["boot"]["crash_register"]
    words = []
    for _ in range(expected["boot"]["early_crashes"]):
        chip.resets.clear()
        chip.run_until(lambda: chip.resets, seconds=2.5, what="the watchdog's reset")
        chip.resets.clear()
        run_to_the_application(board, chip, seconds=15)
        words.append(chip.tamp.regs.get(register))
    assert words == [crash_word(1), crash_word(2), crash_word(0, restored=True)], [hex(w or 0) for w in words]
    assert flash(chip, board.active, board.active_bytes) == old, "the image it replaced, back"
    assert flash(chip, board.state, 8) == bytes([0xC0] * 8), "embassy-boot's REVERT magic, for the image to find"
    assert chip.core.uc.reg_read(arm.UC_ARM_REG_MSP) == board.stack, "the old image's stack pointer"
