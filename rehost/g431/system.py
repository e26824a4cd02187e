"""Clocks, power, flash, and the small system blocks: RCC (RM0440 7.4), PWR (6.4), FLASH (3.7), SYSCFG (9.1),
DBGMCU (47.16) and TAMP's backup registers (38.6)."""

from unicorn import UC_HOOK_MEM_READ

from .core import FLASH_BASE, NMI
from .peripheral import Peripheral, bit, field

# RCC register offsets (RM0440 7.4.1-7.4.29).
CR, ICSCR, CFGR, PLLCFGR, CIER, CIFR, CICR = 0x00, 0x04, 0x08, 0x0C, 0x18, 0x1C, 0x20
AHB1ENR, AHB2ENR, APB1ENR1, APB1ENR2, APB2ENR = 0x48, 0x4C, 0x58, 0x5C, 0x60
CCIPR, BDCR, CSR, CRRCR, CCIPR2 = 0x88, 0x90, 0x94, 0x98, 0x9C

HSE_HZ = 24_000_000  # the NUCLEO-G431RB's crystal (UM2505 6.7.1, X3)
HSI_HZ = 16_000_000

# RM0440 6.1.5 (range 1 boost mode) and 7.2.7 (the system clock switch): before SYSCLK switches to a clock above
# 80 MHz the AHB prescaler divides by 2, and it goes back to /1 no sooner than 1 us after the switch.
FAST_SYSCLK_HZ = 80_000_000
SETTLE_S = 1e-6
# Range 1 normal mode (R1MODE = 1) takes HCLK up to 150 MHz, boost mode up to 170 MHz (6.1.5; DS12589 general
# operating conditions, f_HCLK).
NORMAL_MODE_MAX_HZ = 150_000_000
PWR_CR5, R1MODE = 0x80, 1 << 8  # PWR_CR5.R1MODE = 0: range 1 boost mode (6.4.19)


def hpre_divisor(cfgr):
    """RCC_CFGR.HPRE (bits 7:4, 7.4.3): 0xxx is /1, then 1000-1111 are /2, /4, /8, /16, /64, /128, /256, /512."""
    hpre = field(cfgr, 4, 4)
    return 1 if hpre < 8 else (2, 4, 8, 16, 64, 128, 256, 512)[hpre - 8]


def ppre_divisor(cfgr, bus):
    """RCC_CFGR.PPRE1 (bits 10:8) or PPRE2 (13:11), 7.4.3: 0xx is /1, then 100-111 are /2, /4, /8, /16."""
    ppre = field(cfgr, 8 if bus == 1 else 11, 3)
    return 1 if ppre < 4 else 2 << (ppre - 4)

# RCC_CSR reset flags (7.4.28).
CSR_LSION, CSR_LSIRDY, CSR_RMVF = 1 << 0, 1 << 1, 1 << 23
BDCR_LSERDY, BDCR_LSECSSD = 1 << 1, 1 << 6
PINRSTF, BORRSTF, SFTRSTF, IWDGRSTF = 1 << 26, 1 << 27, 1 << 28, 1 << 29
RESET_FLAGS = 0xFF << 24


class Rcc(Peripheral):
    # CR: HSION and HSIRDY after reset; ICSCR: HSITRIM = 64 (HSICAL, the factory's, reads 0 here); CFGR: HSI16
    # selected (SW = SWS = 01); PLLCFGR: PLLN = 16; AHB1ENR: FLASHEN; APB1ENR1: RTCAPBEN (7.4).
    resets = {CR: 0x0000_0500, ICSCR: 0x4000_0000, CFGR: 0x0000_0005, PLLCFGR: 0x0000_1000, AHB1ENR: 0x0000_0100,
              APB1ENR1: 0x0000_0400}
    # ICSCR.HSICAL, the factory's; every flag of CIFR (7.4).
    read_only = {ICSCR: 0x00FF_0000, CIFR: 0xFFFF_FFFF}

    def __init__(self, chip, name, base):
        super().__init__(chip, name, base)
        self.hse_starts = True  # a test sets False: the crystal never oscillates
        # Every CFGR write, in order: (cycle, SWS, SYSCLK in Hz, HPRE, PPRE1, PPRE2 as divisors, R1MODE).
        self.cfgr_log = []
        self._fast_switch = None  # the cycle SYSCLK last switched above 80 MHz at AHB /2

    def reset(self, flags=PINRSTF, power_on=False):
        # The reset flags accumulate until RMVF clears them; the backup domain control (BDCR) survives all but a
        # power-on (RM0440 7.4.27, 7.4.28).
        csr = 0 if power_on else self.regs.get(CSR, 0) & RESET_FLAGS
        bdcr = 0 if power_on else self.regs.get(BDCR, 0)
        super().reset()
        self.regs[CSR] = csr | flags
        self.regs[BDCR] = bdcr
        self.cfgr_log = []
        self._fast_switch = None

    def write(self, offset, value):
        self.writes.add(offset)
        if offset == CR:
            ready = 0
            if bit(value, 8):
                ready |= 1 << 10  # HSIRDY follows HSION
            if bit(value, 16) and self.hse_starts:
                ready |= 1 << 17  # HSERDY follows HSEON when the crystal starts
            if bit(value, 24):
                if self._pll_locks():
                    ready |= 1 << 25  # PLLRDY follows PLLON when the PLL's input and VCO are in range
            self.regs[CR] = (value & ~((1 << 10) | (1 << 17) | (1 << 25))) | ready
        elif offset == CFGR:
            sw = value & 3
            old = self.regs.get(CFGR, 5)
            sws = sw if self._source_ready(sw) else field(old, 2, 2)
            clocked = self.chip.clocked()
            for peripheral in clocked:
                peripheral.clock_changing()
            self.regs[CFGR] = (value & ~0xC) | (sws << 2)
            self._check_switch(old, self.regs[CFGR])
            for peripheral in clocked:
                peripheral.clock_changed()
        elif offset == CSR:
            old = self.regs.get(CSR, 0)
            new = (old & RESET_FLAGS) | (value & ~RESET_FLAGS & ~CSR_LSIRDY)
            if value & CSR_RMVF:
                new &= ~RESET_FLAGS
            if value & CSR_LSION:
                new |= CSR_LSIRDY
            self.regs[CSR] = new & ~CSR_RMVF
        elif offset == CRRCR:
            # HSI48RDY follows HSI48ON; HSI48CAL is the factory's (7.4).
            self.regs[CRRCR] = (self.regs.get(CRRCR, 0) & 0xFF80) | (value & ~0xFF82) | (bit(value, 0) << 1)
        elif offset == BDCR:
            # LSERDY follows LSEON (bit 0 -> 1), LSECSSD is the hardware's; the backup domain is kept over resets
            # other than power-on.
            kept = self.regs.get(BDCR, 0) & BDCR_LSECSSD
            self.regs[BDCR] = (value & ~(BDCR_LSERDY | BDCR_LSECSSD)) | kept | (bit(value, 0) << 1)
        elif offset == CICR:
            # Each bit written 1 clears the CIFR flag in its place; nothing is kept (7.4).
            self.regs[CIFR] = self.regs.get(CIFR, 0) & ~value
        else:
            self.store(offset, value)

    def _source_ready(self, sw):
        cr = self.regs.get(CR, 0)
        return {1: bit(cr, 10), 2: bit(cr, 17), 3: bit(cr, 25)}.get(sw, 0)

    def pll_input_hz(self):
        pllcfgr = self.regs.get(PLLCFGR, 0)
        source = pllcfgr & 3
        return {2: HSI_HZ, 3: HSE_HZ if self.hse_starts else 0}.get(source, 0)

    def _pll_locks(self):
        # RM0440 7.2.4 and DS12589 Table 43: VCO input 2.66-16 MHz, VCO output 96-344 MHz.
        pllcfgr = self.regs.get(PLLCFGR, 0)
        m = field(pllcfgr, 4, 4) + 1
        n = field(pllcfgr, 8, 7)
        vin = self.pll_input_hz() / m
        return 2_660_000 <= vin <= 16_000_000 and 96e6 <= vin * n <= 344e6

    def _source_hz(self, sws):
        if sws == 3:
            pllcfgr = self.regs[PLLCFGR]
            m, n, r = field(pllcfgr, 4, 4) + 1, field(pllcfgr, 8, 7), 2 * (field(pllcfgr, 25, 2) + 1)
            return self.pll_input_hz() * n // (m * r)
        return HSE_HZ if sws == 2 else HSI_HZ

    def sysclk_hz(self):
        return self._source_hz(field(self.regs.get(CFGR, 5), 2, 2))

    # The clock tree below SYSCLK (7.2, "Clock tree"): HCLK = SYSCLK / HPRE, PCLKx = HCLK / PPREx, and each bus's
    # timers at PCLKx when PPREx is /1, else at 2 x PCLKx (7.2, "Timer clock").
    def hclk_hz(self):
        return self.sysclk_hz() // hpre_divisor(self.regs.get(CFGR, 5))

    def pclk_hz(self, bus):
        return self.hclk_hz() // ppre_divisor(self.regs.get(CFGR, 5), bus)

    def timer_hz(self, bus):
        divisor = ppre_divisor(self.regs.get(CFGR, 5), bus)
        return self.hclk_hz() // divisor * (1 if divisor == 1 else 2)

    def _check_switch(self, old, new):
        """RM0440's order for a switch above 80 MHz: SYSCLK switched with HPRE at /2 (6.1.5 step 1, 7.2.7), and
        HPRE back to /1 no sooner than 1 us later (6.1.5 step 5). Checked while range 1 boost mode is entered or
        held (PWR_CR5.R1MODE = 0), the only mode the 170 MHz images run in; in normal mode, HCLK above 150 MHz
        fails."""
        core = self.chip.core
        boost = not self.chip.pwr.regs.get(PWR_CR5, R1MODE) & R1MODE
        sws, hz, hpre = field(new, 2, 2), self.sysclk_hz(), hpre_divisor(new)
        self.cfgr_log.append((core.cycles, sws, hz, hpre, ppre_divisor(new, 1), ppre_divisor(new, 2), not boost))
        if not boost and self.hclk_hz() > NORMAL_MODE_MAX_HZ:
            core.fail(f"HCLK {self.hclk_hz() / 1e6:g} MHz in range 1 normal mode (PWR_CR5.R1MODE = 1): RM0440 6.1.5 "
                      "takes it to 150 MHz; above that, boost mode")
            return
        if not boost or hz <= FAST_SYSCLK_HZ:
            return
        if sws != field(old, 2, 2):
            if hpre == 1:
                core.fail(f"SYSCLK switched to {hz / 1e6:g} MHz with the AHB prescaler at /1 in range 1 boost mode: "
                          "RM0440 6.1.5 divides HCLK by 2 before the switch")
                return
            self._fast_switch = core.cycles
        elif hpre_divisor(old) > 1 and hpre == 1 and self._fast_switch is not None:
            waited = (core.cycles - self._fast_switch) / core.hz
            if waited < SETTLE_S:
                core.fail(f"AHB prescaler /2 -> /1 {waited * 1e9:.0f} ns after SYSCLK switched to {hz / 1e6:g} MHz: "
                          "RM0440 6.1.5 waits at least 1 us first")

    def pll_p_hz(self):
        """The PLL's P output (7.4.4): the VCO over PLLPDIV, or over 7 or 17 (PLLP) when PLLPDIV is 0; 0 unless
        PLLPEN is set and the PLL locked."""
        pllcfgr = self.regs.get(PLLCFGR, 0)
        if not bit(pllcfgr, 16) or not bit(self.regs.get(CR, 0), 25):
            return 0
        m, n = field(pllcfgr, 4, 4) + 1, field(pllcfgr, 8, 7)
        pdiv = field(pllcfgr, 27, 5) or (17 if bit(pllcfgr, 17) else 7)
        return self.pll_input_hz() * n // (m * pdiv)

    def adc12_kernel_hz(self):
        """The ADC12 kernel clock, CCIPR.ADC12SEL (7.4.26): 00 none, 01 PLL P, 10 SYSCLK, 11 reserved."""
        return {1: self.pll_p_hz(), 2: self.sysclk_hz()}.get(field(self.regs.get(CCIPR, 0), 28, 2), 0)


# PWR (6.4): CR1 0x00, SR1 0x10, SR2 0x14 (VOSF, REGLPF), CR5 0x80 (R1MODE).
class Pwr(Peripheral):
    resets = {0x00: 0x0000_0200, 0x80: 0x0000_0100}
    read_only = {0x10: 0xFFFF_FFFF, 0x14: 0xFFFF_FFFF}  # the status registers (6.4)


# FLASH (3.7): ACR 0x00, KEYR 0x08, SR 0x10, CR 0x14, ECCR 0x18, OPTR 0x20.
ACR, KEYR, SR, FCR, ECCR, OPTR = 0x00, 0x08, 0x10, 0x14, 0x18, 0x20
KEY1, KEY2 = 0x4567_0123, 0xCDEF_89AB
SR_EOP, SR_PROGERR, SR_PGSERR, SR_BSY = 1 << 0, 1 << 3, 1 << 7, 1 << 16
CR_PG, CR_PER, CR_BKER, CR_STRT, CR_EOPIE = 1 << 0, 1 << 1, 1 << 11, 1 << 16, 1 << 24
CR_OPTLOCK, CR_LOCK = 1 << 30, 1 << 31
# FLASH_ECCR (3.7.7): ADDR_ECC (bits 18:0), BK_ECC (21), SYSF_ECC (22), ECCCIE (24), ECCC (30) and ECCD (31), the two
# flags cleared by writing 1.
ECC_ADDRESS, ECC_BANK2, ECCC, ECCD = 0x7_FFFF, 1 << 21, 1 << 30, 1 << 31
FLASH_IRQ = 4  # RM0440 Table 97
PAGE = 2048

# DS12589 Table 41 (flash memory characteristics): 64-bit programming 81.7 us typical, page erase 22 ms typical.
PROGRAM_US = 82
ERASE_US = 22_000


class Flash(Peripheral):
    """The flash interface: the G431's one bank of 2 KiB pages, or the G474's two in dual-bank mode (PNB counts
    the pages of the bank BKER picks), programmed 64 bits at a time (RM0440 3.3.7, 3.3.8).

    The CPU's stores into flash arrive here (`store`): with PG set they fill a double word, which is programmed
    when its second word is written; a write to a word that is not erased sets PROGERR. Each operation takes the
    datasheet's typical time. While one runs in the bank the code runs from (bank 1 for every image here), the core
    stalls, since it fetches from that bank (3.3.7): the clock advances with no instruction run. One in the other
    bank runs beside the code (3.3.8, read-while-write) with SR.BSY set until it ends; its end sets EOP and raises
    the FLASH interrupt when EOPIE is set, as the async driver waits for it. Starting another operation while BSY is
    set is what every procedure of 3.3.7 forbids: the run stops there.

    `operations` lists every erase and program as (first cycle, last cycle, "erase" or "program", address).

    ECC (3.3.4, "Error code correction"): a test makes a double word read back with two bit errors
    (`inject_ecc_double`). Its next read, a fetch or a load, sets ECCR.ECCD with the address (ADDR_ECC, and BK_ECC in
    bank 2 of a dual-bank part) unless ECCC or ECCD already holds one, and raises the NMI; with SYSCFG_CFGR2.ECCL set
    it is also a system break source of TIM1 until ECCD is cleared. The read itself returns what the flash holds.
    """

    # ECCR: the failing address, its bank and whether it is system flash (3.7.7).
    read_only = {ECCR: 0x0067_FFFF}

    def __init__(self, chip, name, base):
        # CR: LOCK and OPTLOCK after reset (3.7.6).
        self.resets = {ACR: 0x0000_0600, FCR: CR_LOCK | CR_OPTLOCK, OPTR: chip.part.optr}
        super().__init__(chip, name, base)
        self.keys = []
        self.pending = {}  # address of a double word -> first word
        self.erases = 0
        self.programs = 0
        self.operations = []
        self.ecc_errors = []  # (cycle, address) of every ECC double error read
        self._ecc_hooks = {}  # double word -> the Unicorn read hook watching it

    def reset(self, flags=None):
        super().reset()
        self.keys = []
        self.pending = {}
        # An injected error stays in the cells over a reset: its watches are kept.

    def _busy(self, what):
        if self.regs.get(SR, 0) & SR_BSY:
            self.chip.core.fail(f"{what} while the flash is busy (SR.BSY): RM0440 3.3.7 waits for BSY to clear first")
            return True
        return False

    def write(self, offset, value):
        self.writes.add(offset)
        if offset == KEYR:
            self.keys.append(value)
            if self.keys[-2:] == [KEY1, KEY2]:
                self.regs[FCR] = self.regs.get(FCR, 0) & ~CR_LOCK
        elif offset == SR:
            self.regs[SR] = self.regs.get(SR, 0) & ~(value & 0xC3FB)  # rc_w1 flags
            if not self.regs[SR] & SR_EOP:
                self.chip.irq(self, FLASH_IRQ, False)
        elif offset == FCR:
            if self.regs.get(FCR, 0) & CR_LOCK:
                self.regs[SR] = self.regs.get(SR, 0) | SR_PGSERR
                return
            self.regs[FCR] = value
            if value & CR_STRT and value & CR_PER:
                bank2 = self.chip.part.bank2
                address = FLASH_BASE + field(value, 3, 7) * PAGE
                if bank2 is not None and value & CR_BKER:
                    address += bank2 - FLASH_BASE
                self.regs[FCR] = value & ~CR_STRT
                if self._busy(f"a page erase at {address:#010x}"):
                    return
                self.chip.flash_erase(address)
                self.erases += 1
                self._done(address, ERASE_US, "erase")
        elif offset == ACR:
            self.regs[ACR] = value
        elif offset == ECCR:
            old = self.regs.get(ECCR, 0)
            kept = self.read_only[ECCR] | ECCC | ECCD  # (Flash.store is the CPU's stores into flash)
            self.regs[ECCR] = (old & kept & ~(value & (ECCC | ECCD))) | (value & ~kept)  # ECCC, ECCD: rc_w1
            if old & ECCD and not self.regs[ECCR] & ECCD:
                self.chip.tim1.release_system_break("ecc")
        else:
            self.store(offset, value)

    def inject_ecc_double(self, address):
        """The double word at `address` reads with two bit errors (a test's hook): its next read, as an instruction
        fetch or a data load, is an ECC double error (3.3.4)."""
        double = address & ~7
        core = self.chip.core
        core.fetch_watch[double] = lambda: self._ecc_double(double)

        def load(uc, access, where, size, value, data):
            self._ecc_double(double)

        self._ecc_hooks[double] = core.uc.hook_add(UC_HOOK_MEM_READ, load, begin=double, end=double + 7)

    def _ecc_double(self, double):
        core = self.chip.core
        core.fetch_watch.pop(double, None)
        hook = self._ecc_hooks.pop(double, None)
        if hook is None:
            return
        core.at(core.cycles, lambda: core.uc.hook_del(hook))  # not from inside the hook itself
        self.ecc_errors.append((core.cycles, double))
        eccr = self.regs.get(ECCR, 0)
        if not eccr & (ECCC | ECCD):
            # The failing address is kept until the flags are cleared (3.7.7): by bank in dual-bank mode.
            bank2 = self.chip.part.bank2
            if bank2 is not None and double >= bank2:
                where = ECC_BANK2 | (double - bank2)
            else:
                where = double - FLASH_BASE
            eccr = (eccr & ~(ECC_ADDRESS | ECC_BANK2)) | where
        self.regs[ECCR] = eccr | ECCD
        # "When ECCD is set, an NMI is generated" (3.7.7, ECCD); and ECCL makes it a system break (9.2.5).
        self.chip.nvic.set_pending(NMI)
        if self.chip.syscfg.ecc_breaks():
            self.chip.tim1.system_break("ecc")
        core.request_stop()

    def store(self, address, value):
        """A CPU store of a word into flash; returns the word the flash holds afterwards."""
        cr = self.regs.get(FCR, 0)
        if not cr & CR_PG or cr & CR_LOCK:
            self.regs[SR] = self.regs.get(SR, 0) | SR_PGSERR
            return None
        double = address & ~7
        if address & 4 == 0:
            self.pending = {double: value}
            return None
        first = self.pending.pop(double, None)
        if first is None:
            self.regs[SR] = self.regs.get(SR, 0) | SR_PGSERR
            return None
        if self.chip.flash_word(double) != 0xFFFF_FFFF or self.chip.flash_word(double + 4) != 0xFFFF_FFFF:
            self.regs[SR] = self.regs.get(SR, 0) | SR_PROGERR
            return None
        if self._busy(f"a double word programmed at {double:#010x}"):
            return None
        self.chip.flash_program(double, first, value)
        self.programs += 1
        self._done(double, PROGRAM_US, "program")
        return value

    def _done(self, address, us, kind):
        """An operation at `address` that takes `us`: the core stalls for it when it runs from that bank, or BSY is
        set until it ends; at its end EOP is set, and with EOPIE the FLASH interrupt raised (cleared with EOP)."""
        core = self.chip.core
        start, cycles = core.cycles, core.hz * us // 1_000_000
        self.operations.append((start, start + cycles, kind, address))
        bank2 = self.chip.part.bank2
        if bank2 is None or address < bank2:
            core.stall(cycles)
            self._end()
        else:
            self.regs[SR] = self.regs.get(SR, 0) | SR_BSY
            core.at(start + cycles, self._end)

    def _end(self):
        self.regs[SR] = (self.regs.get(SR, 0) & ~SR_BSY) | SR_EOP
        if self.regs.get(FCR, 0) & CR_EOPIE:
            self.chip.irq(self, FLASH_IRQ, True)

    def latency(self):
        return self.regs.get(ACR, 0) & 0xF


# SYSCFG_CFGR2 (RM0440 9.2.5): CLL connects the core's LOCKUP output to TIM1's system break, ECCL a flash ECC double
# error; with SPL and PVDL, each is set by software and cleared only by a system reset.
CFGR2, CFGR2_CLL, CFGR2_ECCL, CFGR2_LOCKS = 0x1C, 1 << 0, 1 << 3, 0xF


class Syscfg(Peripheral):
    def write(self, offset, value):
        if offset == CFGR2:
            value |= self.regs.get(CFGR2, 0) & CFGR2_LOCKS  # the lock bits hold until a reset
        super().write(offset, value)

    def lockup_breaks(self):
        return bool(self.regs.get(CFGR2, 0) & CFGR2_CLL)

    def ecc_breaks(self):
        return bool(self.regs.get(CFGR2, 0) & CFGR2_ECCL)


# DBGMCU (47.16.4-47.16.7): IDCODE 0x00 (revision 0x2001 and the part's DEV_ID, RM0440 47.16.1), CR 0x04,
# APB1FZR1 0x08, APB1FZR2 0x0C, APB2FZR 0x10. While the core is halted, a block whose DBG_x_STOP bit is set stops.
APB1FZR1, APB1FZR2, APB2FZR = 0x08, 0x0C, 0x10
DBG_IWDG_STOP = 1 << 12  # DBGMCU_APB1FZR1
DBG_TIM1_STOP = 1 << 11  # DBGMCU_APB2FZR


class Dbgmcu(Peripheral):
    read_only = {0x00: 0xFFFF_FFFF}

    def __init__(self, chip, name, base):
        self.resets = {0x00: 0x2001_6000 | chip.part.dev_id}
        super().__init__(chip, name, base)

    def write(self, offset, value):
        super().write(offset, value)
        self.chip.debug_changed()  # a debugger may write the freeze bits while the core is halted

    def freezes(self):
        """The blocks a halt stops now, {"TIM1": bool, "IWDG": bool}, and the other freeze bits that are set."""
        apb1, apb2 = self.regs.get(APB1FZR1, 0), self.regs.get(APB2FZR, 0)
        others = (apb1 & ~DBG_IWDG_STOP, self.regs.get(APB1FZR2, 0), apb2 & ~DBG_TIM1_STOP)
        return {"TIM1": bool(apb2 & DBG_TIM1_STOP), "IWDG": bool(apb1 & DBG_IWDG_STOP)}, others


# TAMP (38.6): the backup registers BKPxR from 0x100, kept over every reset but a power-on (backup domain).
class Tamp(Peripheral):
    def reset(self, power_on=False):
        backup = {k: v for k, v in self.regs.items() if k >= 0x100}
        super().reset()
        if not power_on:
            self.regs.update(backup)


class Rtc(Peripheral):
    pass


class Crc(Peripheral):
    pass
