"""DMA1's channels follow the part (RM0440 12.3.2): six on the G431 (category 2), eight on the G474 (categories 3
and 4), channels 7 and 8 interrupting on DMA1_CH7 and DMA1_CH8 (RM0440 Table 97: 17 and 96). No image is needed."""

import pytest

from conftest import Blank
from g431 import dma
from g431.chip import Stm32g4
from g431.core import G431RB, G474RE, IRQ0, Stop

DMA1, DMAMUX1 = 0x4002_0000, 0x4002_0800


def test_channels_7_and_8_are_refused_on_the_g431():
    for channel in (7, 8):
        chip = Stm32g4(Blank(G431RB))
        chip.core.bus_write(DMA1 + dma.ccr(channel), 4, 0)
        with pytest.raises(Stop, match="has 6 channels"):
            chip.run_for(0.0001)


def test_channels_7_and_8_are_modelled_on_the_g474():
    chip = Stm32g4(Blank(G474RE))
    for channel, irq in ((7, 17), (8, 96)):
        chip.nvic.enabled.add(IRQ0 + irq)
        # DMAMUX channel n - 1 routes I2C3_RX (request 20) to DMA1 channel n; one byte from I2C3's RXDR to RAM.
        chip.core.bus_write(DMAMUX1 + 4 * (channel - 1), 4, dma.REQUESTS["I2C3_RX"])
        base = DMA1 + dma.ccr(channel)
        chip.core.bus_write(base + 4, 4, 1)  # CNDTR
        chip.core.bus_write(base + 8, 4, 0x4000_7824)  # CPAR: I2C3_RXDR
        chip.core.bus_write(base + 12, 4, 0x2000_0000)  # CMAR
        chip.core.bus_write(base, 4, 1 << 1 | 1 << 7 | 1)  # TCIE, MINC, EN
        assert chip.dma1.request("I2C3_RX")
        assert chip.dma1.remaining(channel) == 0
        assert chip.dma1.regs[dma.ISR] >> 4 * (channel - 1) & 0b0011 == 0b0011  # GIF, TCIF
        assert IRQ0 + irq in chip.nvic.pending, f"DMA1_CH{channel}"
        chip.core.bus_write(DMA1 + dma.IFCR, 4, 0xF << 4 * (channel - 1))
        chip.core.bus_write(base, 4, 0)
        chip.core.bus_write(DMAMUX1 + 4 * (channel - 1), 4, 0)
    assert chip.core.fault is None, chip.core.fault
