"""The master image polls its thrusters through the TCA9548A, reads the battery's CAN frames, talks MAVLink on
its virtual COM port, and keeps a parameter in flash over a reset (and, on a flash set to one bank, says so and
keeps none)."""

import cantools
import pytest

from conftest import ROOT, rehost
from g431.system import OPTR
from master import Ground, mavlink, start

BAT_DBC = cantools.database.load_file(str(ROOT / "lbv" / "dbc" / "bat.dbc"))
# FLASH_OPTR's DBANK (RM0440 3.7.8): the G474's flash in two banks of 2 KiB pages.
DBANK = 1 << 22
# The first byte of the bus extension's frames (tmc-proto's `ext::EXT_MT`), which no IDS order opens with.
EXT_MT = 0x80


def test_every_thruster_is_polled_through_the_mux_with_tmc_protos_orders(expected):
    chip, mux, _ = start("lbv-master-fw", expected)
    chip.run_for(1.0)
    thrusters = [devices[0x29] for devices in mux.channels.values()]
    for channel, thruster in enumerate(thrusters):
        # Besides its orders, the master asks each thruster what it runs (an extension command) before it may arm.
        orders = [w for w in thruster.orders if w[0] != EXT_MT]
        asked = [w for w in thruster.orders if w[0] == EXT_MT]
        assert 1 <= len(asked) <= 5, f"thruster on channel {channel}: {[w.hex() for w in asked]}"
        # 50 polls a second each (`PollConfig`), every order the disarmed vehicle's zero, byte for byte.
        assert len(orders) >= 40, f"thruster on channel {channel}: {len(orders)} orders in 1 s"
        assert thruster.reads >= 40
        for order in set(orders):
            decoded = rehost("order", "seabotix", order.hex())
            assert decoded == {"step": 0, "canonical": True}, (order.hex(), decoded)
    # Each poll selects exactly one channel.
    assert set(mux.selections) == {1 << n for n in range(6)}


def test_a_missing_thruster_is_not_acknowledged_and_the_others_go_on(expected):
    chip, mux, _ = start("lbv-master-fw", expected)
    del mux.channels[3][0x29]
    chip.run_for(1.0)
    for channel, devices in mux.channels.items():
        if channel != 3:
            assert len(devices[0x29].orders) >= 40
    nacked = [t for t in chip.i2c[2].transfers if t[0] == 0x29 and t[3] is False]
    assert nacked, "the missing thruster's address was never sent"


def test_heartbeats_reach_pymavlink(expected):
    chip, _, ground = start("lbv-master-fw", expected)
    # LPUART1 at the console's rate, within the 1 % a UART tolerates (from LPUART1_BRR, RM0440 38.5.7).
    baud = expected["images"]["lbv-master-fw"]["console_baud"]
    assert abs(chip.lpuart.baud() - baud) < 0.01 * baud, chip.lpuart.baud()
    chip.run_for(2.0)
    heartbeats = ground.of("HEARTBEAT")
    assert len(heartbeats) >= 2
    beat = heartbeats[-1]
    assert beat.type == mavlink.MAV_TYPE_SUBMARINE
    assert beat.get_srcSystem() == 1
    # Every byte on the wire was part of a frame pymavlink accepted (CRC and length).
    assert ground.mav.total_receive_errors == 0


def test_a_battery_frame_on_can_reaches_the_console(expected):
    chip, _, ground = start("lbv-master-fw", expected)
    info = BAT_DBC.get_message_by_name("BAT_INFO")
    data = info.encode({"Voltage": 25.2, "Current": 1.5, "Charge": 80, "Temperature": 21.5})
    for _ in range(5):
        assert chip.fdcan.receive(info.frame_id, data)
        chip.run_for(0.1)
    status = ground.wait("SYS_STATUS", 2.0, lambda m: m.voltage_battery != 0xFFFF)
    assert status.voltage_battery == 25_200
    assert status.battery_remaining == 80


def test_a_battery_status_word_is_reported_bit_by_bit(expected):
    chip, _, ground = start("lbv-master-fw", expected)
    status = BAT_DBC.get_message_by_name("BAT_STATUS")
    # The seed's example word 172: HSM_PG, HSM, V12motor and V12board on.
    bits = {signal.name: 0 for signal in status.signals} | {"HSM_PG": 1, "HSM": 1, "V12motor": 1, "V12board": 1}
    data = status.encode(bits)
    assert int.from_bytes(data[:2], "little") == 172
    assert chip.fdcan.receive(status.frame_id, data)
    ground.wait("STATUSTEXT", 2.0, lambda m: m.text.startswith("BAT V12board=1"))
    texts = [m.text for m in ground.of("STATUSTEXT") if m.text.startswith("BAT ")]
    for text in ("BAT V12motor=1 12 V motor regulator on", "BAT V12motor_F=0 normal", "BAT V12board_F=0 normal"):
        assert text in texts, texts


def test_on_one_flash_bank_the_master_says_so_and_writes_nothing(expected):
    # The option bytes set to one bank (RM0440 3.7.8, FLASH_OPTR.DBANK, bit 22 clear), loaded at the power-on.
    chip, _, _ = start("lbv-master-fw", expected)
    chip.flash_interface.resets[OPTR] &= ~DBANK
    chip.power_on()
    chip.run_until(chip.idle, seconds=0.2, what="idle on one bank")
    ground = Ground(chip)
    ground.wait("STATUSTEXT", 1.0, lambda m: m.text == "Settings and updates refused: flash not dual-bank")
    work = (chip.flash_interface.programs, chip.flash_interface.erases)
    ground.send(mavlink.MAVLink_param_set_message(1, 1, b"LBV_GAIN", 40.0, mavlink.MAV_PARAM_TYPE_REAL32))
    ack = ground.wait("PARAM_VALUE", 1.0, lambda m: m.param_id == "LBV_GAIN")
    assert ack.param_value == pytest.approx(40.0), "in force until the next start"
    ground.wait("STATUSTEXT", 1.0, lambda m: m.text == "Settings not saved: flash not dual-bank")
    chip.run_for(0.2)
    assert (chip.flash_interface.programs, chip.flash_interface.erases) == work, "nothing written"


def test_a_parameter_set_is_kept_in_flash_over_a_power_cycle(expected):
    chip, _, ground = start("lbv-master-fw", expected)
    programs = chip.flash_interface.programs
    ground.send(mavlink.MAVLink_param_set_message(1, 1, b"LBV_GAIN", 40.0, mavlink.MAV_PARAM_TYPE_REAL32))
    ack = ground.wait("PARAM_VALUE", 1.0, lambda m: m.param_id == "LBV_GAIN")
    assert ack.param_value == pytest.approx(40.0)
    chip.run_until(lambda: chip.flash_interface.programs > programs, 1.0, "the setting written to flash")
    chip.run_for(0.2)
    chip.power_on()
    chip.run_until(chip.idle, seconds=0.2, what="idle after the power cycle")
    ground = Ground(chip)
    ground.send(mavlink.MAVLink_param_request_read_message(1, 1, b"LBV_GAIN", -1))
    value = ground.wait("PARAM_VALUE", 1.0, lambda m: m.param_id == "LBV_GAIN")
    assert value.param_value == pytest.approx(40.0)
