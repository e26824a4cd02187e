"""An STM32G4 (the thruster's G431RB or the master's G474RE, whichever the image is linked for): the core, its
memories and the peripherals the project's images use, at their RM0440 Table 4 addresses, with the three resets the
images tell apart (RM0440 7.1: power-on, system, independent watchdog)."""

import random
import struct

from elftools.elf.elffile import ELFFile

from . import adc, dma, fdcan, i2c, iwdg, timers, uart
from .core import FLASH_BASE, FLASH_SIZE_ADDRESS, G431RB, G474RE, REGION, SRAM_BASE, UID_ADDRESS, Core, Stop
from .defmt import Log, Rtt, Table
from .gpio import Exti, Gpio
from .nvic import Nvic
from .peripheral import Peripheral
from .system import BORRSTF, IWDGRSTF, PINRSTF, SFTRSTF, Crc, Dbgmcu, Flash, Pwr, Rcc, Rtc, Syscfg, Tamp

# A made-up unique device id (RM0440 48.1): the X/Y wafer coordinates, wafer number and lot number.
UID = bytes.fromhex("2a0031000e50434b38363820")
STACK_PAINT = 0xCD
# The bottom of RAM the images keep for their post-mortem record (g431_hw::memory::CRASH; test_crash checks the
# length against it), which no stack within its budget reaches: the paint, a measuring aid the silicon does not
# have, leaves it as a reset leaves RAM, and the high-water mark is read above it (and above the black box).
CRASH_REGION = 192
# On the master's G474, its black box above the record (g431_hw::memory::BLACK_BOX; test_black_box checks the
# length against it), kept as the record is.
BLACK_BOX = 64 * 1024


def kept_ram(part):
    """The bytes at the bottom of `part`'s RAM the images keep over a reset (g431_hw::images::kept_ram)."""
    return CRASH_REGION + (BLACK_BOX if part.sram_size == 128 * 1024 else 0)


class Image:
    """An ELF the firmware build produced: its loadable segments, symbols and defmt table."""

    def __init__(self, path):
        self.path = str(path)
        with open(path, "rb") as f:
            elf = ELFFile(f)
            self.segments = []
            for segment in elf.iter_segments():
                if segment["p_type"] == "PT_LOAD" and segment["p_filesz"]:
                    self.segments.append((segment["p_paddr"], segment.data()))
            self.symbols = {}
            for symbol in elf.get_section_by_name(".symtab").iter_symbols():
                if symbol.name and not symbol.name.startswith("{"):
                    self.symbols.setdefault(symbol.name, symbol["st_value"])
            text = elf.get_section_by_name(".text")
            self.text = (text["sh_addr"], text.data())
            # Where the image starts: the flash's first word for an image the chip starts itself, the ACTIVE
            # partition for one a bootloader starts (g431_hw::memory).
            self.vector_table = elf.get_section_by_name(".vector_table")["sh_addr"]
            self.defmt = Table(elf)
        # The chip its layout is for: the master's partitions reach past the G431's 128 KiB (g431_hw::memory).
        self.part = G474RE if self.symbols.get("__bootloader_dfu_end", 0) > G431RB.flash_size else G431RB

    def symbol(self, name):
        return self.symbols[name]


class Stm32g4:
    """The chip with `image` in its flash, started as the image expects: from its vector table. With `application`
    (an image linked into ACTIVE) beside a bootloader `image`, both are in the flash as a board flashed with both
    holds them: the chip starts the bootloader, and the log read is the application's (the bootloader logs
    nothing)."""

    def __init__(self, image, seed=1, application=None):
        self.image = image if isinstance(image, Image) else Image(image)
        self.part = self.image.part
        self.random = random.Random(seed)
        self.core = Core(self.part)
        core = self.core
        core.flash_store = self._cpu_flash_store
        core.service = self._service
        self.flash = bytearray(b"\xff" * self.part.flash_size)
        images = [self.image] if application is None else [self.image, application]
        for each in images:
            for address, data in each.segments:
                self.flash[address - FLASH_BASE : address - FLASH_BASE + len(data)] = data
        system = bytearray(0x8000)
        system[UID_ADDRESS - 0x1FFF_0000 : UID_ADDRESS - 0x1FFF_0000 + 12] = UID
        system[FLASH_SIZE_ADDRESS - 0x1FFF_0000 : FLASH_SIZE_ADDRESS - 0x1FFF_0000 + 2] = struct.pack("<H", self.part.flash_size // 1024)
        core.uc.mem_write(0x1FFF_0000, bytes(system))
        for each in images:
            core.hook_sev(*each.text)

        self.peripherals = []
        self._lines = {}
        add = self._add
        self.nvic = add(Nvic, "SCS", 0xE000_E000, size=0x1000)
        core.nvic = self.nvic
        add(Peripheral, "ITM", 0xE000_0000, size=0x1000)
        add(Peripheral, "DWT", 0xE000_1000, size=0x1000)
        self.dbgmcu = add(Dbgmcu, "DBGMCU", 0xE004_2000)
        self.rcc = add(Rcc, "RCC", 0x4002_1000)
        self.pwr = add(Pwr, "PWR", 0x4000_7000)
        self.flash_interface = add(Flash, "FLASH", 0x4002_2000)
        self.syscfg = add(Syscfg, "SYSCFG", 0x4001_0000)
        self.exti = add(Exti, "EXTI", 0x4001_0400)
        self.tamp = add(Tamp, "TAMP", 0x4000_2400)
        self.rtc = add(Rtc, "RTC", 0x4000_2800)
        self.crc = add(Crc, "CRC", 0x4002_3000)
        self.gpio = {}
        for n, letter in enumerate("ABCDEFG"):
            self.gpio[letter] = add(Gpio, f"GPIO{letter}", 0x4800_0000 + 0x400 * n, letter=letter)
        self.dmamux = add(dma.Dmamux, "DMAMUX1", 0x4002_0800)
        self.dma1 = add(dma.Dma, "DMA1", 0x4002_0000)
        self.tim1 = add(timers.Tim1, "TIM1", 0x4001_2C00)
        self.tim15 = add(timers.Tim15, "TIM15", 0x4001_4000)
        core.on_lockup = lambda: self.syscfg.lockup_breaks() and self.tim1.system_break()
        self.i2c = {
            1: add(i2c.I2c, "I2C1", 0x4000_5400, number=1),
            2: add(i2c.I2c, "I2C2", 0x4000_5800, number=2),
            3: add(i2c.I2c, "I2C3", 0x4000_7800, number=3),
        }
        self.adc1 = add(adc.Adc, "ADC1", 0x5000_0000, size=0x100)
        self.adc_common = add(adc.AdcCommon, "ADC12_COMMON", 0x5000_0300, size=0x100)
        self.iwdg = add(iwdg.Iwdg, "IWDG", 0x4000_3000)
        self.fdcan = add(fdcan.Fdcan, "FDCAN1", 0x4000_6400)
        self.fdcan_ram = add(fdcan.MessageRam, "FDCAN SRAM", 0x4000_A400, size=0x400)
        self.fdcan.ram = self.fdcan_ram
        self.lpuart = add(uart.Lpuart, "LPUART1", 0x4000_8000)

        logging = images[-1]
        self.log = Log(logging.defmt)
        rtt = logging.symbols.get("_SEGGER_RTT")
        self.rtt = Rtt(core, rtt, self.log) if rtt else None
        self.resets = []  # (cycle, kind) of every reset after the first power-on
        self._reset_request = None
        self.power_on()

    def _add(self, kind, name, base, size=0x400, **extra):
        peripheral = kind(self, name, base, **extra)
        self.core.attach(base, peripheral, size)
        self.peripherals.append(peripheral)
        return peripheral

    def irq(self, source, irq, level):
        """A peripheral's interrupt line; lines several peripherals share (TIM1_BRK_TIM15) are their OR."""
        holders = self._lines.setdefault(irq, set())
        before = bool(holders)
        if level:
            holders.add(source.name)
        else:
            holders.discard(source.name)
        if bool(holders) != before:
            self.nvic.line(irq, bool(holders))

    def clocked(self):
        """The models that count a clock RCC_CFGR divides, told before and after each write to it."""
        return [self.tim15]

    def peripheral_at(self, address):
        found = self.core._regions.get(address & ~(REGION - 1))
        if found is None:
            raise KeyError(f"no peripheral at {address:#010x}")
        return found

    def peek(self, address):
        """A register's value as the model holds it, without the side effects of a read."""
        base, peripheral = self.peripheral_at(address)
        return peripheral.reg(address - base)

    # Memories --------------------------------------------------------------------------------------------------
    def flash_word(self, address):
        offset = address - FLASH_BASE
        return struct.unpack_from("<I", self.flash, offset)[0]

    def flash_program(self, address, first, second):
        offset = address - FLASH_BASE
        struct.pack_into("<II", self.flash, offset, first, second)
        self.core.write_flash(address, struct.pack("<II", first, second))
        self.core.code_written(address, 8)

    def flash_erase(self, address):
        offset = address - FLASH_BASE
        page = 2048
        self.flash[offset : offset + page] = b"\xff" * page
        self.core.write_flash(address, b"\xff" * page)
        self.core.code_written(address, page)

    def _cpu_flash_store(self, address, size, value):
        if size != 4:
            self.flash_interface.regs[0x10] = self.flash_interface.regs.get(0x10, 0) | (1 << 6)  # SIZERR
            return
        self.flash_interface.store(address, value)

    def stack_high_water(self):
        """Bytes of stack ever used: flip-link puts the stack below the statics, growing down to RAM's start."""
        top = self.image.symbol("_stack_start")
        bottom = SRAM_BASE + kept_ram(self.part)
        data = bytes(self.core.uc.mem_read(bottom, top - bottom))
        for offset, value in enumerate(data):
            if value != STACK_PAINT:
                return top - bottom - offset
        return 0

    # Resets ----------------------------------------------------------------------------------------------------
    def power_on(self):
        """Power applied: every register at its reset value, the backup domain cleared, RAM holding noise."""
        self.core.halt(False)  # no debugger's halt survives the power
        self._reset_peripherals(power_on=True, flags=BORRSTF | PINRSTF)
        # A byte a draw, the top eight bits of a 32-bit word, as `getrandbits(8)` takes them: drawn in one call.
        size = self.part.sram_size
        noise = self.random.getrandbits(32 * size).to_bytes(4 * size, "little")[3::4]
        self.core.uc.mem_write(SRAM_BASE, noise)
        self._paint_stack()
        self.core.write_flash(FLASH_BASE, bytes(self.flash))
        self.core.code_written(FLASH_BASE, len(self.flash))
        self._start()

    def _start(self):
        # An application image (linked into ACTIVE) starts as its bootloader starts it, with VTOR at its vector
        # table: the bootloader itself is not loaded here.
        self.core.reset(vector_table=self.image.vector_table)

    def _paint_stack(self):
        top = self.image.symbols.get("_stack_start", SRAM_BASE)
        bottom = SRAM_BASE + kept_ram(self.part)
        if top > bottom:
            self.core.uc.mem_write(bottom, bytes([STACK_PAINT]) * (top - bottom))

    def request_reset(self, kind):
        """A system reset (AIRCR.SYSRESETREQ) or the watchdog's: taken as soon as the core stops."""
        self._reset_request = kind
        self.core.request_stop()

    def _service(self):
        if self.rtt is not None:
            self.rtt.drain()
        if self._reset_request is not None:
            kind, self._reset_request = self._reset_request, None
            flags = {"software": SFTRSTF | PINRSTF, "watchdog": IWDGRSTF | PINRSTF}[kind]
            self.resets.append((self.core.cycles, kind))
            self._reset_peripherals(power_on=False, flags=flags)
            self._paint_stack()
            self._start()
            self.debug_changed()
            return True
        return False

    def _reset_peripherals(self, power_on, flags):
        # RAM keeps its contents over a system reset (RM0440 2.3.1); the backup domain over all but power-on.
        self.core.drop_events()
        self._lines = {}
        for peripheral in self.peripherals:
            if isinstance(peripheral, Rcc):
                peripheral.reset(flags=flags, power_on=power_on)
            elif isinstance(peripheral, Tamp):
                peripheral.reset(power_on=power_on)
            else:
                peripheral.reset()
        self._reset_request = None

    # Running ---------------------------------------------------------------------------------------------------
    def halt(self):
        """A debugger halts the core: no instruction runs and no exception is taken while time goes on; the blocks
        whose DBGMCU freeze bit is set stop with it (RM0440 47.16; TIM1 28.3 and IWDG 42.3, "Debug mode")."""
        self.core.halt(True)
        self.debug_changed()

    def resume(self):
        self.core.halt(False)
        self.debug_changed()

    def debug_changed(self):
        """The halt or DBGMCU's freeze bits changed: each modelled block stops or counts on. A freeze bit set for a
        block with no freeze modelled stops the run at a halt."""
        halted = self.core.halted
        freezes, others = self.dbgmcu.freezes()
        self.tim1.debug_freeze(halted and freezes["TIM1"])
        self.iwdg.debug_freeze(halted and freezes["IWDG"])
        if halted and any(others):
            self.core.fail("DBGMCU freeze bits APB1FZR1 {:#x}, APB1FZR2 {:#x}, APB2FZR {:#x} set at a halt: no model "
                           "stops those blocks".format(*others))

    def run_for(self, seconds, **kwargs):
        self.core.run(until_cycle=self.core.cycles + int(seconds * self.core.hz), **kwargs)

    def run_until(self, predicate, seconds, what):
        """Runs until `predicate()` holds; fails if `seconds` of modelled time pass first."""
        end = self.core.cycles + int(seconds * self.core.hz)
        self.core.run(until_cycle=end, until=predicate)
        if not predicate():
            raise Stop(f"{what}: not within {seconds} s (log: {self.log_text()[-600:]})")

    def log_text(self):
        return "\n".join(f"{level}: {text}" for level, text in self.log.lines)

    def idle(self):
        """The thread-mode executor sleeps in WFE with no exception active or pending."""
        return self.core.sleeping and not self.core.active and not self.nvic.ready
