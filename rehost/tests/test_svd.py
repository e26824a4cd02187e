"""The models against a register database nobody here wrote: the STM32G4's SVD, as stm32-rs's `stm32g4` crate carries
it (`svd.py`). For the G431 and the G474 as `chip.py` builds them, every register a model implements holds the SVD's
reset value after power-on, and takes a write as the SVD gives its fields' access: read-only bits keep their value,
rc_w1 flags clear on a 1 and rc_w0 flags on a 0, set-only bits ignore a 0, and a write-only register keeps nothing a
read returns. No image is needed: the chip is built around an erased flash, and nothing runs."""

import pytest

import svd
from conftest import ROOT, Blank
from g431 import adc, dma, fdcan, gpio, i2c, iwdg, system, timers, uart
from g431.chip import Stm32g4
from g431.core import G431RB, G474RE

PARTS = {G431RB.name: G431RB, G474RE.name: G474RE}


def _channels(model, *offsets):
    """The registers of each of the part's DMA channels (RM0440 12.3.2: six on the G431, eight on the G474)."""
    return [dma.ccr(n) - dma.ccr(1) + offset for n in range(1, model.chip.part.dma_channels + 1) for offset in offsets]


# The registers each model implements: its reset values and the registers its code names (a function of the model
# where they depend on the part). A model's other registers only hold what is written (RTC's, CRC's and the ADC12
# common registers all do): they are counted, not checked.
IMPLEMENTED = {
    system.Rcc: [system.CR, system.ICSCR, system.CFGR, system.PLLCFGR, system.CIER, system.CIFR, system.CICR,
                 system.AHB1ENR, system.AHB2ENR, system.APB1ENR1, system.APB1ENR2, system.APB2ENR, system.CCIPR,
                 system.BDCR, system.CSR, system.CRRCR, system.CCIPR2],
    system.Pwr: [0x00, 0x14, 0x80],  # CR1, SR2, CR5
    system.Flash: [system.ACR, system.KEYR, system.SR, system.FCR, system.ECCR, system.OPTR],
    system.Syscfg: [0x08, 0x0C, 0x10, 0x14, 0x1C],  # EXTICR1-4 (EXTI's port selection), CFGR2
    system.Dbgmcu: [0x00, 0x04, 0x08, 0x0C, 0x10],
    system.Tamp: list(range(0x100, 0x180, 4)),  # BKP0R-BKP31R
    gpio.Exti: [gpio.IMR1, gpio.EMR1, gpio.RTSR1, gpio.FTSR1, gpio.SWIER1, gpio.PR1, 0x20],  # and IMR2
    gpio.Gpio: [gpio.MODER, gpio.OTYPER, gpio.OSPEEDR, gpio.PUPDR, gpio.IDR, gpio.ODR, gpio.BSRR, gpio.LCKR, gpio.AFRL,
                gpio.AFRH, gpio.BRR],
    dma.Dmamux: lambda model: [4 * n for n in range(model.chip.part.dma_channels)],
    dma.Dma: lambda model: [dma.ISR, dma.IFCR] + _channels(model, 0x08, 0x0C, 0x10, 0x14),  # CCRx-CMARx
    timers.Tim1: [timers.CR1, timers.CR2, timers.SMCR, timers.DIER, timers.SR, timers.EGR, timers.CCMR1, timers.CCMR2,
                  timers.CCER, timers.CNT, timers.PSC, timers.ARR, timers.RCR, timers.CCR1, timers.CCR2, timers.CCR3,
                  timers.CCR4, timers.BDTR, timers.AF1, timers.AF2],
    timers.Tim15: [timers.CR1, timers.DIER, timers.SR, timers.EGR, timers.CNT, timers.PSC, timers.ARR, timers.CCR1,
                   timers.CCR2],
    i2c.I2c: [i2c.CR1, i2c.CR2, i2c.OAR1, i2c.OAR2, i2c.TIMINGR, i2c.TIMEOUTR, i2c.ISR, i2c.ICR, i2c.PECR, i2c.RXDR,
              i2c.TXDR],
    adc.Adc: [adc.ISR, adc.IER, adc.CR, adc.CFGR, adc.CFGR2, adc.SMPR1, adc.SMPR2, adc.SQR1, adc.SQR2, adc.SQR3,
              adc.SQR4, adc.DR, adc.JSQR, *adc.JDR],
    iwdg.Iwdg: [iwdg.KR, iwdg.PR, iwdg.RLR, iwdg.SR, iwdg.WINR],
    fdcan.Fdcan: [fdcan.CREL, fdcan.ENDN, fdcan.CCCR, fdcan.NBTP, fdcan.PSR, fdcan.IR, fdcan.IE, fdcan.ILS, fdcan.ILE,
                  fdcan.RXGFC, fdcan.RXF0S, fdcan.RXF0A, fdcan.TXFQS, fdcan.TXBAR, fdcan.TXBTO],
    uart.Lpuart: [uart.CR1, uart.CR2, uart.CR3, uart.BRR, uart.RQR, uart.ISR, uart.ICR, uart.RDR, uart.TDR,
                  uart.PRESC],
}
# Not in the SVD: the core's system control space, ITM and DWT (ARMv7-M's), and FDCAN's message RAM.
NOT_IN_SVD = {"SCS", "ITM", "DWT", "FDCAN SRAM"}

# Reset values the SVD cannot give, or gives wrong; the mask is of the bits still compared. (RCC_CSR's reset flags
# are the reset's cause: compared after a power-on, BORRSTF and PINRSTF, the SVD's 0x0C00_0000.)
RESET_EXCEPTIONS = {
    # The SVD's 0x0000_0063 is the STM32L4's (MSI fields in bits 0-7, reserved here) and leaves HSION clear, though
    # its own RCC_CFGR reset (SWS = 01) has the core running from HSI16: HSION and HSIRDY are set after reset
    # (RM0440 7.2, 7.4.1). The rest is compared.
    ("RCC", system.CR): 0xFFFF_FA00,
    # DEV_ID and REV_ID are the part's (RM0440 47.16.1); the SVD says 0.
    ("DBGMCU", 0x00): 0,
    # Loaded from the option bytes at reset (RM0440 3.4.1, 3.7.8): the model holds their production value, the SVD
    # 0xF000_0000, no value a part has.
    ("FLASH", system.OPTR): 0,
}

# Where the SVD gives flags as plain read-write, what RM0440 says of them (the bits that clear on a 1): FLASH_SR's
# EOP, OPERR, PROGERR, WRPERR, PGAERR, SIZERR, PGSERR, MISERR, FASTERR, RDERR and OPTVERR (3.7.5), every flag of
# FDCAN_IR (44.4).
RC_W1 = {
    ("FLASH", system.SR): 0xC3FB,
    ("FLASH", system.ECCR): system.ECCC | system.ECCD,  # RM0440 3.7.7: ECCC and ECCD
    ("FDCAN1", fdcan.IR): 0x00FF_FFFF,
}
# Likewise the flags RM0440 clears on a 0 where the SVD gives them read-write: TIM1_SR's IDXF, DIRF, IERRF and TERRF
# (bits 20-23, the encoder's index, direction, index error and transition error flags, 28.6.5).
RC_W0 = {
    ("TIM1", timers.SR): 0x00F0_0000,
}
# Registers that clear the flags of another, bit for bit: (clear register, flag register).
CLEARS = {
    "RCC": (system.CICR, system.CIFR),  # RM0440 7.4
    "DMA1": (dma.IFCR, dma.ISR),  # RM0440 12.6.2
    "I2C": (i2c.ICR, i2c.ISR),  # RM0440 37.7.8
    "LPUART1": (uart.ICR, uart.ISR),  # RM0440 38.7
}
# Set-only bits the models act on at once: the hardware clears them once done, a model as it acts.
AT_ONCE = {
    ("I2C", i2c.CR2): i2c.START | i2c.STOP,
    ("ADC1", adc.CR): adc.ADCAL | adc.ADSTART | adc.ADDIS | adc.ADSTP | adc.JADSTART | adc.JADSTP,
}


def device_of(part):
    return part.name[:9].lower()  # STM32G431RB -> stm32g431, the crate's device module


@pytest.fixture(scope="module")
def devices(figures):
    source, version = svd.crate_source(ROOT)
    figures["svd: the register database"] = f"{svd.CRATE} {version}"
    return {name: svd.Device(source, device_of(part)) for name, part in PARTS.items()}


def model_registers(chip, device):
    """(model, SVD peripheral name, {offset: [SVD register, ...]}, implemented offsets) for each model the SVD has."""
    found = []
    for model in chip.peripherals:
        if model.name not in NOT_IN_SVD:
            name, registers = device.peripheral(model.base)
            implemented = IMPLEMENTED.get(type(model), [])
            found.append((model, name, registers, implemented(model) if callable(implemented) else implemented))
    return found


def fresh(chip, model):
    """The model after a power-on, every GPIO port clocked (a port takes no write without its clock)."""
    chip.power_on()
    chip.rcc.write(system.AHB2ENR, 0x7F)
    return chip.peripheral_at(model.base)[1]


def family(name):
    return "I2C" if name.startswith("I2C") else name


@pytest.mark.parametrize("part", PARTS)
def test_reset_values_are_the_svds(part, devices, figures):
    device = devices[part]
    chip = Stm32g4(Blank(PARTS[part]))
    wrong, checked, left, excepted = [], 0, 0, set()
    for model, name, registers, implemented in model_registers(chip, device):
        left += len(set(registers) - set(implemented))
        for offset in implemented:
            if offset not in registers:
                wrong.append(f"{model.name} {offset:#05x}: no such register in the SVD")
                continue
            if (name, offset) in RESET_EXCEPTIONS:
                excepted.add((name, offset))
            mask = RESET_EXCEPTIONS.get((name, offset), 0xFFFF_FFFF)
            checked += 1
            for register in registers[offset]:
                value = model.reg(offset)
                if (value ^ register.reset) & mask:
                    wrong.append(f"{model.name}_{register.name.upper()} ({offset:#05x}): {value:#010x}, the SVD "
                                 f"{register.reset:#010x}")
    figures[f"svd {part}: registers checked against the SVD, not implemented"] = f"{checked}, {left}"
    assert excepted == set(RESET_EXCEPTIONS), "an exception that no longer applies"
    assert not wrong, "\n".join(wrong)


def _access(register, name, offset):
    """The register's bits by access: read-only, clear on 1, clear on 0, set on 1 (the SVD, then RM0440)."""
    ro = register.read_only
    w1c = register.one_to_clear | RC_W1.get((name, offset), 0)
    return ro & ~w1c, w1c, register.zero_to_clear | RC_W0.get((name, offset), 0), register.one_to_set


def _neutral(value, w1c, w0c, w1s):
    """A write that changes nothing a write may change: the value read, no flag cleared, no bit set."""
    return (value & ~w1c & ~w1s) | w0c


@pytest.mark.parametrize("part", PARTS)
def test_field_access_is_the_svds(part, devices, figures):
    device = devices[part]
    wrong, checks, seen = [], 0, set()
    chip = Stm32g4(Blank(PARTS[part]))
    for model, name, registers, implemented in model_registers(chip, device):
        for offset in implemented:
            if offset not in registers:
                continue  # the reset test tells
            register = registers[offset][0]
            label = f"{model.name}_{register.name.upper()} ({offset:#05x})"
            ro, w1c, w0c, w1s = _access(register, name, offset)
            seen.update(key for key in (*RC_W1, *RC_W0, *AT_ONCE) if key in ((name, offset), (family(name), offset)))
            if ro:
                # Every read-only bit written inverted, the rest as read: none moves.
                peripheral = fresh(chip, model)
                before = peripheral.reg(offset)
                peripheral.write(offset, _neutral(before, w1c, w0c, w1s) ^ ro)
                checks += 1
                if (peripheral.reg(offset) ^ before) & ro:
                    wrong.append(f"{label}: read-only bits {ro:#010x} went {before & ro:#x} -> "
                                 f"{peripheral.reg(offset) & ro:#x}")
            if not register.is_readable:
                peripheral = fresh(chip, model)
                peripheral.write(offset, register.writable)
                checks += 1
                if peripheral.reg(offset):
                    wrong.append(f"{label}: write-only, reads {peripheral.reg(offset):#x} after a write")
            for flags, kind, keep, clear in ((w1c, "rc_w1", 0, w1c), (w0c, "rc_w0", w0c, 0)):
                if not flags or not register.is_readable:
                    continue  # a write-only clear register's flags are another's (CLEARS)
                peripheral = fresh(chip, model)
                peripheral.regs[offset] = peripheral.reg(offset) | flags
                peripheral.write(offset, _neutral(peripheral.reg(offset), w1c, w0c, w1s))
                checks += 1
                if peripheral.reg(offset) & flags != flags:
                    wrong.append(f"{label}: {kind} flags {flags:#x} cleared by writing {keep:#x} to them")
                peripheral.write(offset, (_neutral(peripheral.reg(offset), w1c, w0c, w1s) & ~flags) | clear)
                checks += 1
                if peripheral.reg(offset) & flags:
                    wrong.append(f"{label}: {kind} flags {peripheral.reg(offset) & flags:#x} not cleared")
            for n in range(32):
                flag = 1 << n
                if not w1s & flag or AT_ONCE.get((family(name), offset), 0) & flag:
                    continue
                peripheral = fresh(chip, model)
                peripheral.regs[offset] = peripheral.reg(offset) | flag
                peripheral.write(offset, _neutral(peripheral.reg(offset), w1c, w0c, w1s))
                checks += 1
                if not peripheral.reg(offset) & flag:
                    wrong.append(f"{label}: set-only bit {n} cleared by writing 0")
        if family(name) in CLEARS:
            seen.add(family(name))
            clear, flags = CLEARS[family(name)]
            mask = registers[clear][0].writable & registers[flags][0].readable
            peripheral = fresh(chip, model)
            peripheral.regs[flags] = peripheral.reg(flags) | mask
            before = peripheral.reg(flags)
            peripheral.write(clear, 0)
            checks += 1
            if peripheral.reg(flags) != before:
                wrong.append(f"{model.name} {clear:#04x}: writing 0 changed {flags:#04x} to "
                             f"{peripheral.reg(flags):#x}")
            peripheral.write(clear, mask)
            checks += 1
            if peripheral.reg(flags) != before & ~mask:
                wrong.append(f"{model.name} {clear:#04x}: writing {mask:#x} left {flags:#04x} at "
                             f"{peripheral.reg(flags):#x}, not {before & ~mask:#x}")
    figures[f"svd {part}: access checks"] = checks
    assert seen == {*RC_W1, *RC_W0, *AT_ONCE, *CLEARS}, "a table entry that matches no register"
    assert not wrong, "\n".join(wrong)
