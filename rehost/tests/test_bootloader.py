"""The bootloader (lbv-boot), built for the thruster's G431 and for the master's G474, under the models: it starts
the image in ACTIVE with that image's vector table, stack pointer and reset handler, starts the trial watchdog first,
and swaps in an image marked updated in DFU through the flash interface's programming sequence, byte for byte as
embassy-boot's swap does on the host (lbv-boot's tests). On the G474 the swap crosses the banks: ACTIVE in bank 1,
DFU in bank 2."""

import random
import struct
from dataclasses import dataclass

import pytest
from unicorn import arm_const as arm

from conftest import image
from g431.chip import Stm32g4
from g431.core import FLASH_BASE
from g431.iwdg import PR, RLR
from g431.system import ERASE_US, PROGRAM_US

PAGE = 2048


@dataclass
class Board:
    """A bootloader image and its partitions (g431_hw::memory::THRUSTER_PARTITIONS, MASTER_PARTITIONS)."""

    image: str
    state: int
    active: int
    dfu: int
    active_bytes: int
    # Where a made-up application puts its stack: inside the chip's RAM.
    stack: int

    @property
    def reset_handler(self):
        return self.active + 0x200

    @property
    def pages(self):
        return self.active_bytes // PAGE


THRUSTER = Board("thruster-boot", 0x0800_2000, 0x0800_2800, 0x0801_1000, 58 * 1024, stack=0x2000_7000)
MASTER = Board("master-boot", 0x0800_2000, 0x0800_3000, 0x0804_0000, 238 * 1024, stack=0x2001_F000)
BOARDS = pytest.mark.parametrize("board", [THRUSTER, MASTER], ids=lambda board: board.image)
# embassy-boot's state: the magic word (eight bytes of it) that marks an update for the swap.
SWAP_MAGIC = bytes([0xF0] * 8)
# g431_hw::iwdg::BOOT_TRIAL: /32, 2125 counts, at least 2 s at the fastest LSI.
TRIAL_PR, TRIAL_RLR = 3, 2124


def application(board, seed, stack_pointer):
    """A made-up image linked at ACTIVE: its vector table (the initial stack pointer, the reset handler past the
    vector table, a branch to itself), then bytes `seed` picks."""
    rng = random.Random(seed)
    body = bytearray(rng.getrandbits(8) for _ in range(board.active_bytes))
    struct.pack_into("<II", body, 0, stack_pointer, board.reset_handler | 1)
    struct.pack_into("<H", body, board.reset_handler - board.active, 0xE7FE)  # b .
    return bytes(body)


def chip_with(board, active, dfu=None, state=b""):
    chip = Stm32g4(image(board.image))
    for address, data in [(board.active, active), (board.dfu, dfu or b""), (board.state, state)]:
        chip.flash[address - FLASH_BASE : address - FLASH_BASE + len(data)] = data
    chip.power_on()
    return chip


def flash(chip, address, length):
    return bytes(chip.flash[address - FLASH_BASE : address - FLASH_BASE + length])


def run_to_the_application(board, chip, seconds):
    chip.run_until(
        lambda: chip.core.pc == board.reset_handler, seconds=seconds, what="the application's reset handler"
    )
    assert chip.core.fault is None
    assert chip.resets == [], "no reset on the way"


@BOARDS
def test_the_bootloader_starts_the_image_in_active_with_its_vector_table_and_the_trial_watchdog(board):
    app = application(board, 1, stack_pointer=board.stack - 0x100)
    chip = chip_with(board, app)
    run_to_the_application(board, chip, seconds=0.01)
    assert chip.core.vtor == board.active
    assert chip.core.uc.reg_read(arm.UC_ARM_REG_MSP) == board.stack - 0x100
    assert chip.iwdg.running
    assert (chip.iwdg.regs.get(PR), chip.iwdg.regs.get(RLR)) == (TRIAL_PR, TRIAL_RLR)
    assert chip.flash_interface.erases == 0 and chip.flash_interface.programs == 0, "nothing to swap, nothing written"
    assert flash(chip, board.active, board.active_bytes) == app
    # The image finds the chip as the reset left it: the clocks on HSI16, the reset flags not cleared.
    assert chip.rcc.sysclk_hz() == 16_000_000
    # Left alone, the trial watchdog resets the chip after its 2.1 s at 32 kHz.
    chip.run_for(2.2)
    assert [kind for _, kind in chip.resets] == ["watchdog"]


@BOARDS
def test_an_image_marked_updated_is_swapped_in_and_the_old_one_kept_in_dfu_one_page_up(board, figures):
    old = application(board, 2, stack_pointer=board.stack)
    new = application(board, 3, stack_pointer=board.stack - 0x1000)
    chip = chip_with(board, old, dfu=new, state=SWAP_MAGIC)
    start = chip.core.cycles
    run_to_the_application(board, chip, seconds=15)
    assert chip.core.uc.reg_read(arm.UC_ARM_REG_MSP) == board.stack - 0x1000, "the new image's stack pointer"
    assert flash(chip, board.active, board.active_bytes) == new
    assert flash(chip, board.dfu + PAGE, board.active_bytes) == old
    # Every page both ways, one erase and 256 double words a page, and a progress word after each page.
    steps = 2 * board.pages
    assert chip.flash_interface.erases == steps
    assert chip.flash_interface.programs == steps * 257
    state = flash(chip, board.state, 2 * PAGE)
    assert state[:8] == SWAP_MAGIC, "on trial until the image marks itself booted"
    assert state[16 : 16 + steps * 8] == bytes(steps * 8), "every step's progress word written"
    # The bootloader waits for every operation, in either bank: their typical times (system.py) added up. (The
    # model stalls the core only for those in the bank it runs from; in bank 2 it polls BSY, which the model
    # clears at once.)
    work = (chip.flash_interface.erases * ERASE_US + chip.flash_interface.programs * PROGRAM_US) / 1e6
    stalled = (chip.core.cycles - start) / chip.core.hz
    figures[f"{board.image} swap of {board.pages} pages"] = f"{work:.2f} s of flash work ({stalled:.2f} s stalled)"
    # It never marks itself booted: the trial watchdog resets, and the bootloader swaps the old image back.
    chip.run_until(lambda: chip.resets, seconds=2.5, what="the trial watchdog's reset")
    chip.resets.clear()
    run_to_the_application(board, chip, seconds=15)
    assert flash(chip, board.active, board.active_bytes) == old
    assert flash(chip, board.dfu, board.active_bytes) == new
    assert chip.core.uc.reg_read(arm.UC_ARM_REG_MSP) == board.stack, "the old image's stack pointer"

