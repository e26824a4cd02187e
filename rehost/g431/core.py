"""The Cortex-M4 core of an STM32G431 on the Unicorn engine: memory, time, and the exception model Unicorn lacks.

Unicorn runs Thumb-2 code but has no NVIC: exception entry and return are done here, by the rules of the ARMv7-M
Architecture Reference Manual (B1.5.6 exception entry, B1.5.8 exception return, B1.5.7 stack alignment). Time
advances with instructions, one per cycle at 170 MHz (`Core.hz`); the count comes from a block hook that counts each
translated block's Thumb instructions once (a halfword whose top five bits are 0b11101, 0b11110 or 0b11111 starts a
32-bit instruction, A5.1).

Peripherals are objects with `read(offset)` / `write(offset, value)` on 32-bit registers, placed at their RM0440
Table 4 base addresses (`Core.attach`), and schedule their own events on the core's clock (`Core.at`).
"""

import ctypes
import heapq
import struct

from unicorn import (
    UC_ARCH_ARM,
    UC_HOOK_BLOCK,
    UC_HOOK_CODE,
    UC_HOOK_INSN_INVALID,
    UC_HOOK_INTR,
    UC_HOOK_MEM_INVALID,
    UC_MEM_WRITE_PROT,
    UC_MODE_MCLASS,
    UC_MODE_THUMB,
    UC_PROT_ALL,
    UC_PROT_READ,
    UC_PROT_EXEC,
    Uc,
    UcError,
)
from unicorn import arm_const as arm
# The binding's C library and its callback signatures, for the hot paths (`Registers`, the block hook and the MMIO
# callbacks): unicorn is pinned (requirements.txt, 2.1.4), and its Python layers around a call cost more than the call.
from unicorn.unicorn_py3.unicorn import HOOK_CODE_CFUNC, MMIO_READ_CFUNC, MMIO_WRITE_CFUNC, uc_hook_h, uclib

FLASH_BASE = 0x0800_0000
SRAM_BASE = 0x2000_0000
# System memory: the unique device id (RM0440 48.1, UID_BASE 0x1FFF_7590) and the flash size (48.2, 0x1FFF_75E0).
SYSTEM_BASE = 0x1FFF_0000
SYSTEM_SIZE = 0x8000
UID_ADDRESS = 0x1FFF_7590
FLASH_SIZE_ADDRESS = 0x1FFF_75E0

# Exception numbers (ARMv7-M B1.5.2).
RESET, NMI, HARD_FAULT, SVCALL, PENDSV, SYSTICK = 1, 2, 3, 11, 14, 15
IRQ0 = 16

# EXC_RETURN values (B1.5.8): to thread mode on the main stack, with or without an FP frame, or to handler mode.
EXC_RETURN_THREAD = 0xFFFF_FFF9
EXC_RETURN_THREAD_FP = 0xFFFF_FFE9
EXC_RETURN_HANDLER = 0xFFFF_FFF1
EXC_RETURN_HANDLER_FP = 0xFFFF_FFE1

CONTROL_FPCA = 1 << 2

# Thumb encodings the core must see (ARMv7-M A7.7): WFE and SEV (hint instructions), UDF and BKPT.
WFE = 0xBF20
WFI = 0xBF30
SEV = 0xBF40


# The granularity of the peripheral map: the smallest block placed on its own (ADC1 and the ADC12 common registers
# share a 1 KiB page, RM0440 Table 4 and 21.6).
REGION = 0x100

# The granularity at which code rewritten in memory is forgotten: a flash page (RM0440 3.3.1).
CODE_PAGE_BITS = 11

# What a spinning loop must leave unchanged from one pass to the next.
# xPSR's IT state: IT[1:0] at bits 26:25, IT[7:2] at bits 15:10 (ARMv7-M B1.4.2).
ITSTATE = 0x0600_FC00
SPIN_REGISTERS = [getattr(arm, f"UC_ARM_REG_R{n}") for n in range(13)] + [arm.UC_ARM_REG_SP, arm.UC_ARM_REG_XPSR]


class Part:
    """What tells the two chips apart here: their memories, DBGMCU's device id (RM0440 47.16.1) and the user option
    bytes' production value (RM0440 3.4.1: 0xFFEF_F8AA, DBANK = 1), which on the G474 selects its dual-bank mode: two
    banks of 2 KiB pages, bank 2 at 0x0804_0000 (RM0440 3.3.1, Table 7); and the channels of each DMA (RM0440
    12.3.2: six in category 2 devices, the G431, eight in categories 3 and 4, the G474)."""

    def __init__(self, name, flash_kib, sram_kib, dev_id, dual_bank, dma_channels):
        self.name = name
        self.flash_size = flash_kib * 1024
        self.sram_size = sram_kib * 1024
        self.dev_id = dev_id
        self.optr = 0xFFEF_F8AA
        # In dual-bank mode, where bank 2 starts; None with one bank.
        self.bank2 = FLASH_BASE + self.flash_size // 2 if dual_bank else None
        self.dma_channels = dma_channels


G431RB = Part("STM32G431RB", flash_kib=128, sram_kib=32, dev_id=0x468, dual_bank=False, dma_channels=6)
G474RE = Part("STM32G474RE", flash_kib=512, sram_kib=128, dev_id=0x469, dual_bank=True, dma_channels=8)


class Stop(Exception):
    """The run ended: a fault the test did not expect, a reset, or the time or instruction limit."""


def halfwords(code: bytes):
    """The Thumb instructions of a block, as (first halfword, second halfword or None)."""
    i = 0
    while i + 1 < len(code):
        first = code[i] | code[i + 1] << 8
        if first >> 11 in (0b11101, 0b11110, 0b11111) and i + 3 < len(code):
            yield first, code[i + 2] | code[i + 3] << 8
            i += 4
        else:
            yield first, None
            i += 2


def stores_nothing(code: bytes) -> bool:
    """Whether every instruction of a block is one of the few that neither store nor call (ARMv7-M A5.2, A5.3):
    the loops that wait on a flag (`ldr`, `lsls`/`tst`, a conditional branch) and the idle loops (`nop`, `b`).
    Anything else answers False, so a block is only ever wrongly taken for one that has effects."""
    for first, second in halfwords(code):
        if second is None:
            if (first == 0xBF00 or 0x0000 <= first < 0x4400 or 0x4500 <= first < 0x4700
                    or 0x4800 <= first < 0x5000 or 0x6800 <= first < 0x7000 or 0x7800 <= first < 0x8000
                    or 0x8800 <= first < 0x9000 or 0xB100 <= first < 0xB400 or 0xB900 <= first < 0xBC00
                    or 0xD000 <= first < 0xDE00 or 0xE000 <= first < 0xE800):
                continue
            return False
        if first & 0xFFF0 in (0xF8D0, 0xF890, 0xF8B0):  # LDR.W, LDRB.W, LDRH.W with a 12-bit offset
            continue
        if first & 0xF800 == 0xF000 and second & 0xD000 == 0x8000 and (first >> 6) & 0xF < 0xE:  # B<c>.W
            continue
        if first & 0xFA00 == 0xF000 and not second & 0x8000:  # data processing, modified immediate
            continue
        return False
    return True


def thumb_instructions(code: bytes) -> int:
    """How many Thumb instructions a block of code holds."""
    return max(sum(1 for _ in halfwords(code)), 1)


class Registers:
    """The core's registers, every one used here 32 bits wide, read and written through Unicorn's C API: the
    binding's `reg_read` and `reg_write` spend some 3 us in Python on each, 36 us on a `reg_read_batch` of the spin
    registers, and the spin check and the exception model use many."""

    def __init__(self, uc):
        self._uch = uc._uch
        self._value = ctypes.c_uint32()
        self._ref = ctypes.byref(self._value)
        count = len(SPIN_REGISTERS)
        self._spin_ids = (ctypes.c_int * count)(*SPIN_REGISTERS)
        self._spin_values = (ctypes.c_uint32 * count)()
        base = ctypes.addressof(self._spin_values)
        self._spin_refs = (ctypes.c_void_p * count)(*(base + 4 * i for i in range(count)))
        self._spin_count = count

    def read(self, register):
        status = uclib.uc_reg_read(self._uch, register, self._ref)
        if status:
            raise UcError(status, register)
        return self._value.value

    def write(self, register, value):
        self._value.value = value & 0xFFFF_FFFF
        status = uclib.uc_reg_write(self._uch, register, self._ref)
        if status:
            raise UcError(status, register)

    def spin_state(self):
        """`SPIN_REGISTERS`' values, as bytes to compare."""
        status = uclib.uc_reg_read_batch(self._uch, self._spin_ids, self._spin_refs, self._spin_count)
        if status:
            raise UcError(status)
        return bytes(self._spin_values)


class Core:
    hz = 170_000_000

    def __init__(self, part):
        self.part = part
        self.uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        self.uc.ctl_set_cpu_model(arm.UC_CPU_ARM_CORTEX_M4)
        self.registers = Registers(self.uc)
        self.cycles = 0
        self.instructions = 0
        self.on_lockup = None  # what the chip does with the LOCKUP output
        self._events = []  # (cycle, sequence, callback)
        self._due = None
        self._sequence = 0
        self._block_sizes = {}
        self._code_pages = {}  # 2 KiB page -> the blocks translated from it (keys of _block_sizes)
        self._stop_at = 0
        self._stop_reason = None
        self._attention = False
        self._last_block = None
        self._repeats = 0
        self._last_registers = None
        self._spin = 0
        self.changing_read = False  # a peripheral read whose value changes with time or has a side effect
        self.spun = 0  # instructions skipped over in spin loops
        self._regions = {}  # base (aligned to REGION) -> peripheral
        self.nvic = None  # set by the board: pending, enabled, priorities
        self.event = False  # the event register WFE waits on (B1.5.18)
        self.sleeping = False
        self.halted = False  # stopped by a debugger (`halt`): no instruction runs, time passes
        # Double-word addresses -> callback(), called once when code is fetched from there (a block covering it runs).
        self.fetch_watch = {}
        self.active = []  # exception numbers being handled, innermost last
        self.fault = None  # why the core faulted, if it did
        self.flash_store = None  # (address, size, value): the flash interface takes CPU stores into flash
        self.service = lambda: False  # the chip's work between runs (resets, draining the log); True: look again

        # The flash array is a buffer here that Unicorn maps: what the flash interface programs and erases is copied
        # in (`write_flash`), where a `mem_write` into memory mapped read-only takes some 15 us (Unicorn maps it
        # writable and back).
        self._flash = ctypes.create_string_buffer(part.flash_size)
        self.uc.mem_map_ptr(FLASH_BASE, part.flash_size, UC_PROT_READ | UC_PROT_EXEC, ctypes.addressof(self._flash))
        # RAM too, for the run loop's look at the log's control block after every stop (`ram`, read in place).
        self._ram = ctypes.create_string_buffer(part.sram_size)
        self.ram = memoryview(self._ram).cast("B")
        self.uc.mem_map_ptr(SRAM_BASE, part.sram_size, UC_PROT_ALL, ctypes.addressof(self._ram))
        self.uc.mem_map(SYSTEM_BASE, SYSTEM_SIZE, UC_PROT_READ)
        # The block hook runs for every block, the peripherals' callbacks for every access: added through the C API,
        # without the binding's two Python wrappers around each call (a third of the block hook's cost). Unicorn
        # keeps only their addresses: `_callbacks` keeps them alive. An MMIO range's user data is its base.
        self._hook_error = None  # what a callback raised, for `_execute` to raise
        self._callbacks = (HOOK_CODE_CFUNC(self._on_block), MMIO_READ_CFUNC(self._mmio_read),
                           MMIO_WRITE_CFUNC(self._mmio_write))
        block, read, write = self._callbacks
        status = uclib.uc_hook_add(self.uc._uch, ctypes.byref(uc_hook_h()), UC_HOOK_BLOCK, block, None, 1, 0)
        for base, size in ((0x4000_0000, 0x24000), (0x4800_0000, 0x2000), (0x5000_0000, 0x2000), (0xE000_0000, 0x10_0000)):
            status = status or uclib.uc_mmio_map(self.uc._uch, base, size, read, base, write, base)
        if status:
            raise UcError(status)
        self.uc.hook_add(UC_HOOK_INTR, self._on_interrupt)
        self.uc.hook_add(UC_HOOK_INSN_INVALID, self._on_invalid)
        self.uc.hook_add(UC_HOOK_MEM_INVALID, self._on_bad_access)

    # Memory and peripherals ------------------------------------------------------------------------------------
    def attach(self, base, peripheral, size=0x400):
        for offset in range(0, size, REGION):
            self._regions[base + offset] = (base, peripheral)

    def _mmio_read(self, _uc, offset, size, base):
        try:
            return self._access(base + offset, size, None)
        except BaseException as error:
            self._callback_failed(error)
            return 0

    def _mmio_write(self, _uc, offset, size, value, base):
        try:
            self._access(base + offset, size, value)
        except BaseException as error:
            self._callback_failed(error)

    def _callback_failed(self, error):
        """A callback from Unicorn raised: an exception must not escape into C, so the first is kept, the run stops
        and `_execute` raises it."""
        if self._hook_error is None:
            self._hook_error = error
        self.uc.emu_stop()

    def _access(self, address, size, value):
        key = address & ~(REGION - 1)
        found = self._regions.get(key)
        if found is None:
            self.fail(f"access to {address:#010x}, where no peripheral is modelled")
            return 0
        base, peripheral = found
        register = (address - base) & ~3
        if size == 4 and not address & 3:
            # A whole register, most accesses: no shift, no merge.
            if value is None:
                return peripheral.read(register) & 0xFFFF_FFFF
            peripheral.write(register, value & 0xFFFF_FFFF)
            return 0
        shift = (address & 3) * 8
        mask = ((1 << (size * 8)) - 1) << shift
        if value is None:
            return (peripheral.read(register) & mask) >> shift
        if size == 4:
            peripheral.write(register, value & 0xFFFF_FFFF)
        else:
            # A narrow write: the rest of the register keeps its value (RM0440 2.2: byte and half-word accesses).
            old = peripheral.read(register) if peripheral.narrow_merge else 0
            peripheral.write(register, (old & ~mask) | ((value << shift) & mask))
        return 0

    def bus_read(self, address, size):
        """A read by a bus master other than the core (DMA): a peripheral register or memory."""
        if 0x4000_0000 <= address < 0x6000_0000:
            return self._access(address, size, None)
        return int.from_bytes(self.uc.mem_read(address, size), "little")

    def bus_write(self, address, size, value):
        if 0x4000_0000 <= address < 0x6000_0000:
            self._access(address, size, value)
        else:
            self.uc.mem_write(address, (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little"))

    def write_flash(self, address, data):
        """New contents of the flash array, as `mem_write` would put them: translated code is left as it was (see
        `code_written`)."""
        if not FLASH_BASE <= address <= address + len(data) <= FLASH_BASE + self.part.flash_size:
            raise ValueError(f"{len(data)} bytes at {address:#010x}: not in the flash")
        ctypes.memmove(ctypes.addressof(self._flash) + address - FLASH_BASE, data, len(data))

    def read32(self, address):
        return struct.unpack("<I", self.uc.mem_read(address, 4))[0]

    def write32(self, address, value):
        self.uc.mem_write(address, struct.pack("<I", value & 0xFFFF_FFFF))

    # Time ------------------------------------------------------------------------------------------------------
    def at(self, cycle, callback):
        """Calls `callback()` once the core's clock reaches `cycle`, at once if it has passed it already; either
        way `now()` reads `cycle` meanwhile, so what a model times from it keeps its place."""
        self._sequence += 1
        heapq.heappush(self._events, (cycle, self._sequence, callback))
        if cycle < self._stop_at:
            self._stop_at = cycle

    def after_us(self, us, callback):
        self.at(self.cycles + int(us * self.hz / 1_000_000), callback)

    def drop_events(self):
        """A reset: every scheduled peripheral event is forgotten."""
        self._events.clear()

    @property
    def seconds(self):
        return self.cycles / self.hz

    def _fire_due(self):
        while self._events and self._events[0][0] <= self.cycles:
            due, _, callback = heapq.heappop(self._events)
            self._due = due
            try:
                callback()
            finally:
                self._due = None

    def now(self):
        """The cycle an event's callback was due at, while it runs (the core reaches events at the end of a block
        of instructions, a few dozen cycles late at most); else the core's cycle count. Hardware that runs by itself
        (a timer's edges, the ADC's conversions) times what it does from this."""
        return self.cycles if self._due is None else self._due

    # Execution -------------------------------------------------------------------------------------------------
    def reset(self, vector_table=FLASH_BASE):
        self.vtor = vector_table
        self.active.clear()
        self.sleeping = False
        self.event = False
        self.fault = None
        # A spin seen before the reset (a run that stopped on it) is not the new start's.
        self._spin = 0
        self._repeats = 0
        self._last_block = None
        self._last_registers = None
        msp = self.read32(vector_table)
        pc = self.read32(vector_table + 4)
        self.registers.write(arm.UC_ARM_REG_MSP, msp)
        self.registers.write(arm.UC_ARM_REG_SP, msp)
        self.registers.write(arm.UC_ARM_REG_LR, 0xFFFF_FFFF)
        self.registers.write(arm.UC_ARM_REG_CONTROL, 0)
        self.registers.write(arm.UC_ARM_REG_PRIMASK, 0)
        self.registers.write(arm.UC_ARM_REG_BASEPRI, 0)
        self.registers.write(arm.UC_ARM_REG_XPSR, 1 << 24)
        self.pc = pc & ~1

    def run(self, until_cycle=None, until=None, max_instructions=None):
        """Runs until the clock reaches `until_cycle`, or `until()` holds, or the instruction limit is reached."""
        limit = None if max_instructions is None else self.instructions + max_instructions
        while True:
            if until is not None and until():
                return
            if until_cycle is not None and self.cycles >= until_cycle:
                return
            if limit is not None and self.instructions >= limit:
                raise Stop(f"{max_instructions} instructions without reaching the goal, at pc {self.pc:#010x}")
            if self.service():
                continue
            if self.fault is not None:
                raise Stop(self.fault)
            self._fire_due()
            if self.halted:
                # Halted (ARMv7-M C1.4, halting debug): nothing runs and no exception is taken, but the clock goes on
                # and the peripherals with it.
                if self._events and (until_cycle is None or self._events[0][0] <= until_cycle):
                    self.cycles = max(self.cycles, self._events[0][0])
                elif until_cycle is not None:
                    self.cycles = until_cycle
                else:
                    raise Stop(f"halted at {self.pc:#010x} with nothing scheduled")
                continue
            if self._take_exception():
                continue
            horizon = self._events[0][0] if self._events else self.cycles + self.hz
            if until_cycle is not None:
                horizon = min(horizon, until_cycle)
            if self._spin:
                # Spinning: the same instructions run until the next event; count them without running them.
                target = horizon
                if limit is not None:
                    target = min(target, self.cycles + (limit - self.instructions))
                skipped = max(target - self.cycles, 0)
                self.cycles += skipped
                self.instructions += skipped
                self.spun += skipped
                self._spin = 0
                self._repeats = 0
                continue
            if self.sleeping:
                # Asleep in WFE: nothing runs until the next event. The clock jumps there.
                if self._events and (until_cycle is None or self._events[0][0] <= until_cycle):
                    self.cycles = max(self.cycles, self._events[0][0])
                elif until_cycle is not None:
                    self.cycles = until_cycle
                else:
                    raise Stop(f"asleep at {self.pc:#010x} with nothing scheduled to wake it")
                continue
            self._stop_at = horizon
            if limit is not None:
                self._stop_at = min(self._stop_at, self.cycles + (limit - self.instructions))
            self._execute()

    def _execute(self):
        self._stop_reason = None
        self._hook_error = None
        try:
            self.uc.emu_start(self.pc | 1, 0xFFFF_FFFF)
        except UcError as error:
            if self._stop_reason is None and self.fault is None:
                self.raise_fault(f"the core stopped at {self.registers.read(arm.UC_ARM_REG_PC):#010x}: {error}")
                return
        if self._hook_error is not None:
            raise self._hook_error
        self.pc = self.registers.read(arm.UC_ARM_REG_PC)
        reason = self._stop_reason
        if reason is not None:
            reason()

    def _stop(self, reason=None):
        self._stop_reason = reason
        self.uc.emu_stop()

    def _on_block(self, _uc, address, size, _data):
        try:
            known = self._block_sizes.get((address, size))
            if known is None:
                code = bytes(self.uc.mem_read(address, size)) if size else b""
                known = (thumb_instructions(code) if size else 1, bool(size) and stores_nothing(code))
                self._block_sizes[(address, size)] = known
                for page in range(address >> CODE_PAGE_BITS, ((address + max(size, 1) - 1) >> CODE_PAGE_BITS) + 1):
                    self._code_pages.setdefault(page, set()).add((address, size))
            count, pure = known
            if self.fetch_watch:
                for double in [d for d in self.fetch_watch if address <= d + 7 and d < address + max(size, 1)]:
                    self.fetch_watch.pop(double)()
            self.cycles += count
            self.instructions += count
            # A block that jumps to itself with the same registers, stores nothing and reads only registers that
            # cannot change before the next event (`changing_read`) spins until that event: the run loop lets the
            # clock jump there. (A delay loop counts a register down: not a spin.)
            if pure and address == self._last_block and not self.changing_read:
                registers = self.registers.spin_state()
                if registers == self._last_registers:
                    self._repeats += 1
                    if self._repeats >= 3:
                        self._spin = count
                        self._stop()
                        return
                else:
                    self._repeats = 0
                self._last_registers = registers
            elif self._last_registers is not None:  # (else there is nothing to forget: no repeat counted)
                self._repeats = 0
                self._last_registers = None
            self._last_block = address
            self.changing_read = False
            # (`nvic.ready` first: most blocks run with nothing pending, and it spares them the call.)
            nvic = self.nvic
            if (self._attention or self.cycles >= self._stop_at
                    or (nvic is not None and nvic.ready and nvic.wants_attention())) and not self.in_it_block():
                self._attention = False
                self._stop()
        except BaseException as error:
            self._callback_failed(error)

    def in_it_block(self):
        """Whether the next instruction is inside an IT block (xPSR's ITSTATE, bits 26:25 and 15:10, ARMv7-M
        B1.4.2). The run stops only outside one: Unicorn starts again from a PC without the IT state it was in, so
        the block's remaining instructions would run unconditionally (an exception taken after the LPUART1
        handler's ITT made it call through a register it should have skipped). The silicon takes an exception
        inside an IT block and stacks ITSTATE; here it comes at most four instructions later."""
        return bool(self.registers.read(arm.UC_ARM_REG_XPSR) & ITSTATE)

    def code_written(self, address, length):
        """Memory was rewritten (flash programmed or erased): code translated from it before is forgotten, Unicorn's
        translation and the counts here, so that what runs there next is what the memory now holds."""
        first, last = address >> CODE_PAGE_BITS, (address + max(length, 1) - 1) >> CODE_PAGE_BITS
        for page in range(first, last + 1):
            blocks = self._code_pages.pop(page, None)
            if blocks:
                for key in blocks:
                    self._block_sizes.pop(key, None)
                self.uc.ctl_remove_cache(page << CODE_PAGE_BITS, (page + 1) << CODE_PAGE_BITS)

    def request_stop(self):
        """Stop at the next block, where the state is whole: a peripheral changed something the run loop must see.

        Never stop from inside a memory callback: Unicorn would resume at the instruction that made the access and
        run it a second time."""
        self._attention = True

    def halt(self, halted=True):
        """A debugger halts the core (DHCSR.C_HALT, ARMv7-M C1.6.2) or lets it run again."""
        self.halted = halted
        self._spin = 0
        self._repeats = 0

    def stall(self, cycles):
        """The core waits (a flash erase from the bank it runs from): time passes, no instruction runs."""
        self.cycles += cycles
        self.request_stop()

    # Hints: WFE, WFI, SEV -------------------------------------------------------------------------------------
    def hook_sev(self, code_start, code):
        """SEV is a NOP to Unicorn: hook every halfword-aligned SEV encoding in the code so the event is seen."""
        for i in range(0, len(code) - 1, 2):
            if code[i] | code[i + 1] << 8 == SEV:
                address = code_start + i
                self.uc.hook_add(UC_HOOK_CODE, self._on_sev, begin=address, end=address)

    def _on_sev(self, uc, address, size, _data):
        self.event = True

    def _on_invalid(self, uc, _data=None):
        # Returning False ends emu_start with an error that `_execute` expects; the reason says what to do.
        pc = self.registers.read(arm.UC_ARM_REG_PC)
        here = struct.unpack("<H", uc.mem_read(pc, 2))[0]
        before = struct.unpack("<H", uc.mem_read(pc - 2, 2))[0]
        if here >> 8 != 0xDE and before == WFE:
            # Unicorn reports WFE with PC already past it.
            self._stop_reason = lambda: self._wfe(pc)
            return False
        # UDF and everything else undefined: a UsageFault, escalated to HardFault (no handler enabled, B1.5.4).
        self._stop_reason = lambda: self.enter_fault(f"undefined instruction {here:#06x} at {pc:#010x}", pc)
        return False

    def _wfe(self, pc):
        self.pc = pc
        if self.event:
            self.event = False
        else:
            self.sleeping = True

    def _on_interrupt(self, uc, intno, _data):
        pc = self.registers.read(arm.UC_ARM_REG_PC)
        if intno == 8 and pc & 0xF000_0000 == 0xF000_0000:
            # A handler returned: Unicorn leaves the EXC_RETURN value in PC (B1.5.8).
            self._stop(lambda: self._exception_return(pc | 1))
        elif intno == 7:
            self._stop(lambda: self.enter_fault(f"breakpoint at {pc:#010x}", pc))
        else:
            self._stop(lambda: self.enter_fault(f"CPU exception {intno} at {pc:#010x}", pc))

    def _on_bad_access(self, uc, access, address, size, value, _data):
        pc = self.registers.read(arm.UC_ARM_REG_PC)
        if access == UC_MEM_WRITE_PROT and FLASH_BASE <= address < FLASH_BASE + self.part.flash_size and self.flash_store:
            # A store into flash goes to the flash interface's programming sequence (RM0440 3.3.7).
            self.flash_store(address, size, value & 0xFFFF_FFFF)
            return True
        self._stop_reason = lambda: self.enter_fault(f"bus fault: access to {address:#010x} at {pc:#010x}", pc)
        return False

    def fail(self, why):
        """A modelled peripheral saw what real silicon would not allow; the run stops there."""
        self.raise_fault(why)
        self.request_stop()

    def raise_fault(self, why):
        if self.fault is None:
            self.fault = why

    # Exceptions (ARMv7-M B1.5) --------------------------------------------------------------------------------
    def execution_priority(self):
        """The current priority: the active exceptions', PRIMASK's and BASEPRI's (B1.5.4)."""
        priority = 256
        for number in self.active:
            priority = min(priority, self.nvic.priority(number))
        if self.registers.read(arm.UC_ARM_REG_PRIMASK) & 1:
            priority = min(priority, 0)
        basepri = self.registers.read(arm.UC_ARM_REG_BASEPRI) & 0xFF
        if basepri:
            priority = min(priority, basepri)
        return priority

    def _take_exception(self):
        if self.nvic is None:
            return False
        number = self.nvic.highest_pending()
        if number is None:
            return False
        priority = self.nvic.priority(number)
        if priority >= self.execution_priority() and number not in (NMI, HARD_FAULT):
            return False
        self.nvic.activate(number)
        self._enter(number)
        return True

    def enter_fault(self, why, pc):
        """A fault the image may handle: HardFault, unless one is already active (a lockup, B1.5.15: the core stops
        and raises its LOCKUP output, which the chip may route on: `on_lockup`)."""
        self.last_fault = why
        if HARD_FAULT in self.active or NMI in self.active:
            if self.on_lockup is not None:
                self.on_lockup()
            self.raise_fault(f"lockup: {why}")
            return
        self.pc = pc
        self._enter(HARD_FAULT)

    def pend(self, number):
        """Sets an exception pending (NMI, HardFault) from a test."""
        self.nvic.set_pending(number)

    def _enter(self, number):
        uc, registers = self.uc, self.registers
        self.sleeping = False
        self.event = True  # exception entry is a WFE wake-up event (B1.5.18)
        control = registers.read(arm.UC_ARM_REG_CONTROL)
        fp = bool(control & CONTROL_FPCA)
        sp = registers.read(arm.UC_ARM_REG_SP)
        words = 26 if fp else 8
        frame = (sp - words * 4) & ~7
        aligned = (sp - words * 4) & 4
        xpsr = registers.read(arm.UC_ARM_REG_XPSR) & ~(1 << 9)
        if aligned:
            xpsr |= 1 << 9
        regs = [registers.read(r) for r in (arm.UC_ARM_REG_R0, arm.UC_ARM_REG_R1, arm.UC_ARM_REG_R2,
                                            arm.UC_ARM_REG_R3, arm.UC_ARM_REG_R12, arm.UC_ARM_REG_LR)]
        data = struct.pack("<8I", *regs, self.pc | 0, xpsr | (1 << 24))
        saved_fp = None
        if fp:
            saved_fp = [registers.read(arm.UC_ARM_REG_S0 + i) for i in range(16)]
            fpscr = registers.read(arm.UC_ARM_REG_FPSCR)
            data += struct.pack("<16I", *saved_fp) + struct.pack("<II", fpscr, 0)
        if frame < SRAM_BASE:
            self.raise_fault(f"stack overflow: an exception frame at {frame:#010x}, below RAM")
            return
        uc.mem_write(frame, data)
        registers.write(arm.UC_ARM_REG_SP, frame)
        registers.write(arm.UC_ARM_REG_MSP, frame)
        in_handler = bool(self.active[:-1]) if self.active and self.active[-1] == number else bool(self.active)
        if number not in self.active:
            self.active.append(number)
        if in_handler:
            exc_return = EXC_RETURN_HANDLER_FP if fp else EXC_RETURN_HANDLER
        else:
            exc_return = EXC_RETURN_THREAD_FP if fp else EXC_RETURN_THREAD
        registers.write(arm.UC_ARM_REG_LR, exc_return)
        registers.write(arm.UC_ARM_REG_CONTROL, control & ~CONTROL_FPCA)
        registers.write(arm.UC_ARM_REG_IPSR, number)
        vector = self.read32(self.vtor + 4 * number)
        self.pc = vector & ~1

    def _exception_return(self, exc_return):
        uc, registers = self.uc, self.registers
        if not self.active:
            self.raise_fault(f"exception return {exc_return:#010x} with no exception active")
            return
        number = self.active.pop()
        self.nvic.deactivate(number)
        self.event = True
        fp = not exc_return & 0x10
        frame = registers.read(arm.UC_ARM_REG_SP)
        words = 26 if fp else 8
        values = struct.unpack(f"<{words}I", uc.mem_read(frame, words * 4))
        for register, value in zip((arm.UC_ARM_REG_R0, arm.UC_ARM_REG_R1, arm.UC_ARM_REG_R2, arm.UC_ARM_REG_R3,
                                    arm.UC_ARM_REG_R12, arm.UC_ARM_REG_LR), values):
            registers.write(register, value)
        pc, xpsr = values[6], values[7]
        if fp:
            for i in range(16):
                registers.write(arm.UC_ARM_REG_S0 + i, values[8 + i])
            registers.write(arm.UC_ARM_REG_FPSCR, values[24])
        sp = frame + words * 4 + (4 if xpsr & (1 << 9) else 0)
        registers.write(arm.UC_ARM_REG_SP, sp)
        registers.write(arm.UC_ARM_REG_MSP, sp)
        control = registers.read(arm.UC_ARM_REG_CONTROL)
        registers.write(arm.UC_ARM_REG_CONTROL, control | CONTROL_FPCA if fp else control & ~CONTROL_FPCA)
        registers.write(arm.UC_ARM_REG_XPSR, xpsr & ~(1 << 9))
        registers.write(arm.UC_ARM_REG_IPSR, self.active[-1] if self.active else 0)
        self.pc = pc & ~1
