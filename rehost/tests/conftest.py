"""Shared set-up: where the images are, what they must leave in the registers (`rehost expected`), and a way to
boot one under the models."""

import json
import os
import pathlib
import struct
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "rehost"))

from g431.chip import Stm32g4, Image  # noqa: E402
from g431.core import FLASH_BASE, SRAM_BASE  # noqa: E402

IMAGES = pathlib.Path(os.environ.get("REHOST_IMAGES", ROOT / "target" / "images"))
REHOST = os.environ.get("REHOST_BIN", str(ROOT / "target" / "debug" / "rehost"))

THRUSTERS = ["thruster-fw", "thruster-fw-legacy", "thruster-fw-brushed", "thruster-fw-motorless", "thruster-fw-bringup"]
MASTERS = ["lbv-master-fw", "lbv-master-fw-devkit", "lbv-master-fw-acceptance"]
ALL = THRUSTERS + MASTERS

# Instructions an image may take from reset to its executors' idle: ten times the most any takes (about 120 000).
BOOT_INSTRUCTIONS = 1_200_000

_images = {}


def image(name):
    """An image, parsed once per run."""
    if name not in _images:
        path = IMAGES / name
        if not path.exists():
            pytest.fail(f"{path} is missing: ./test.sh builds every image before this run")
        _images[name] = Image(path)
    return _images[name]


def rehost(*args, input=None):
    return json.loads(subprocess.run([REHOST, *args], check=True, capture_output=True, text=True, input=input).stdout)


def sign(seed, payload):
    """`payload` signed with the secret key `seed` (hex), as `lbv image sign` signs it (`rehost sign`): its padded
    length, signature, ticket and the key's public half, as bytes."""
    signed = rehost("sign", seed, input=payload.hex())
    return {key: value if key == "payload_len" else bytes.fromhex(value) for key, value in signed.items()}


@pytest.fixture(scope="session")
def expected():
    return rehost("expected")


class Blank(Image):
    """No image: a vector table and an idle loop (WFE, then a branch back to it) in erased flash, enough for a chip to
    be built and reset, and to sleep while a test drives its peripherals."""

    IDLE = struct.pack("<HH", 0xBF20, 0xE7FD)  # wfe; b.n back to the wfe (ARMv7-M A7.7.158, A7.7.12)

    def __init__(self, part):
        self.path = f"(no image, {part.name})"
        self.part = part
        self.segments = [(FLASH_BASE, struct.pack("<II", SRAM_BASE + part.sram_size, FLASH_BASE + 0x9) + self.IDLE)]
        self.symbols = {}
        self.text = (FLASH_BASE + 8, self.IDLE)
        self.vector_table = FLASH_BASE
        self.defmt = None


def boot(name, **options):
    """A chip running `name`, brought to its first idle (both executors waiting, nothing pending)."""
    chip = Stm32g4(image(name), **options)
    chip.run_until(chip.idle, seconds=0.05, what=f"{name} reaching idle")
    return chip


FIGURES = {}


@pytest.fixture(scope="session")
def figures():
    """Measured figures, printed after the results."""
    return FIGURES


def pytest_terminal_summary(terminalreporter):
    if FIGURES:
        width = max(len(key) for key in FIGURES)
        terminalreporter.section("figures (modelled time: one instruction per cycle at 170 MHz)")
        for key, value in sorted(FIGURES.items()):
            terminalreporter.write_line(f"{key:<{width}}  {value}")
