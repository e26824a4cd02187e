"""The thruster's bootloader (thruster-boot) under the models: it starts the image in ACTIVE with that image's vector
table, stack pointer and reset handler, starts the trial watchdog first, and swaps in an image marked updated in
DFU through the flash interface's programming sequence, byte for byte as embassy-boot's swap does on the host
(thruster-boot's tests)."""

import random
import struct

from unicorn import arm_const as arm

from conftest import image
from g431.chip import G431
from g431.core import FLASH_BASE
from g431.iwdg import PR, RLR

# g431_hw::memory::THRUSTER_PARTITIONS.
STATE, ACTIVE, DFU = 0x0800_2000, 0x0800_2800, 0x0801_1000
PAGE = 2048
ACTIVE_BYTES = 58 * 1024
# embassy-boot's state: the magic word (eight bytes of it) that marks an update for the swap.
SWAP_MAGIC = bytes([0xF0] * 8)
# g431_hw::iwdg::BOOT_TRIAL: /32, 2125 counts, at least 2 s at the fastest LSI.
TRIAL_PR, TRIAL_RLR = 3, 2124
RESET_HANDLER = ACTIVE + 0x200


def application(seed, stack_pointer):
    """A made-up image linked at ACTIVE: its vector table (the initial stack pointer, the reset handler past the
    vector table, a branch to itself), then bytes `seed` picks."""
    rng = random.Random(seed)
    body = bytearray(rng.getrandbits(8) for _ in range(ACTIVE_BYTES))
    struct.pack_into("<II", body, 0, stack_pointer, RESET_HANDLER | 1)
    struct.pack_into("<H", body, RESET_HANDLER - ACTIVE, 0xE7FE)  # b .
    return bytes(body)


def chip_with(active, dfu=None, state=b""):
    chip = G431(image("thruster-boot"))
    for address, data in [(ACTIVE, active), (DFU, dfu or b""), (STATE, state)]:
        chip.flash[address - FLASH_BASE : address - FLASH_BASE + len(data)] = data
    chip.power_on()
    return chip


def flash(chip, address, length):
    return bytes(chip.flash[address - FLASH_BASE : address - FLASH_BASE + length])


def run_to_the_application(chip, seconds):
    chip.run_until(lambda: chip.core.pc == RESET_HANDLER, seconds=seconds, what="the application's reset handler")
    assert chip.core.fault is None
    assert chip.resets == [], "no reset on the way"


def test_the_bootloader_starts_the_image_in_active_with_its_vector_table_and_the_trial_watchdog():
    app = application(1, stack_pointer=0x2000_6F00)
    chip = chip_with(app)
    run_to_the_application(chip, seconds=0.01)
    assert chip.core.vtor == ACTIVE
    assert chip.core.uc.reg_read(arm.UC_ARM_REG_MSP) == 0x2000_6F00
    assert chip.iwdg.running
    assert (chip.iwdg.regs.get(PR), chip.iwdg.regs.get(RLR)) == (TRIAL_PR, TRIAL_RLR)
    assert chip.flash_interface.erases == 0 and chip.flash_interface.programs == 0, "nothing to swap, nothing written"
    assert flash(chip, ACTIVE, ACTIVE_BYTES) == app
    # The image finds the chip as the reset left it: the clocks on HSI16, the reset flags not cleared.
    assert chip.rcc.sysclk_hz() == 16_000_000
    # Left alone, the trial watchdog resets the chip after its 2.1 s at 32 kHz.
    chip.run_for(2.2)
    assert [kind for _, kind in chip.resets] == ["watchdog"]


def test_an_image_marked_updated_is_swapped_in_and_the_old_one_kept_in_dfu_one_page_up(figures):
    old, new = application(2, stack_pointer=0x2000_7000), application(3, stack_pointer=0x2000_6000)
    chip = chip_with(old, dfu=new, state=SWAP_MAGIC)
    start = chip.core.cycles
    run_to_the_application(chip, seconds=5)
    assert chip.core.uc.reg_read(arm.UC_ARM_REG_MSP) == 0x2000_6000, "the new image's stack pointer"
    assert flash(chip, ACTIVE, ACTIVE_BYTES) == new
    assert flash(chip, DFU + PAGE, ACTIVE_BYTES) == old
    # 29 pages each way, one erase and 256 double words a page, and a progress word after each page.
    assert chip.flash_interface.erases == 58
    assert chip.flash_interface.programs == 58 * 257
    state = flash(chip, STATE, PAGE)
    assert state[:8] == SWAP_MAGIC, "on trial until the image marks itself booted"
    assert state[16 : 16 + 58 * 8] == bytes(58 * 8), "every step's progress word written"
    figures["thruster-boot swap (modelled flash timing)"] = f"{(chip.core.cycles - start) / chip.core.hz:.2f} s"
    # It never marks itself booted: the trial watchdog resets, and the bootloader swaps the old image back.
    chip.run_until(lambda: chip.resets, seconds=2.5, what="the trial watchdog's reset")
    chip.resets.clear()
    run_to_the_application(chip, seconds=5)
    assert flash(chip, ACTIVE, ACTIVE_BYTES) == old
    assert flash(chip, DFU, ACTIVE_BYTES) == new
    assert chip.core.uc.reg_read(arm.UC_ARM_REG_MSP) == 0x2000_7000, "the old image's stack pointer"

