"""A thruster image on its bench: its analog inputs at a working point, the bus master the tests play, and the
hall sensors of a turning rotor."""

from conftest import Stm32g4, image

# Analog inputs by the function g431_hw::images gives them.
WATER, NTC, VBUS = "water sensor", ("motor NTC", "power-stage NTC"), "supply voltage"
CURRENTS = ("phase A current", "phase B current", "phase C current")


def channels(spec):
    return {pin["function"]: pin["adc1_in"] for pin in spec["pins"] if pin["mode"] == "analog"}


def set_analog(chip, spec, water="dry", ntc="ntc_25c", current="current_zero", vbus="vbus_24v"):
    points = spec["analog"]
    for function, channel in channels(spec).items():
        if function == WATER:
            chip.adc1.inputs[channel] = points[water]
        elif function in NTC:
            chip.adc1.inputs[channel] = points[ntc]
        elif function in CURRENTS:
            chip.adc1.inputs[channel] = points[current]
        elif function == VBUS:
            chip.adc1.inputs[channel] = points[vbus]


def start(name, expected, **analog):
    spec = expected["images"][name]
    chip = Stm32g4(image(name))
    set_analog(chip, spec, **analog)
    if spec["forward"]:
        set_halls(chip, spec["forward"][0]["hall"])  # a rotor at rest in a valid sector: 111 would be a hall fault
    chip.run_until(chip.idle, seconds=0.05, what=f"{name} reaching idle")
    chip.run_for(0.01)  # its first samples: the faults need three in a row (`Thresholds::latch_samples`)
    return chip, spec


def exchange(chip, spec, order):
    """The modelled master writes `order`, then reads a status (two transfers, as the master image does)."""
    i2c = chip.i2c[3]
    written = i2c.master_transfer(spec["address"], bytes(order))
    chip.run_until(lambda: written.done, seconds=0.05, what="the order written")
    assert written.error is None, written.error
    length = 7 if spec["family"] == "SeaBotix" else 4
    read = i2c.master_transfer(spec["address"], read_length=length)
    chip.run_until(lambda: read.done, seconds=0.05, what="the status read")
    assert read.error is None, read.error
    return bytes(read.read), written, read




# What each of the IHM08M1's switches does for a phase's drive: (high, low).
SWITCHES = {"pwm": ("pwm", "pwm"), "low": ("off", "on"), "float": ("off", "off")}


def switches(chip, spec):
    """Each phase's two switches as the gate driver sees its inputs, {"A": (high, low), ...}: "on", "off" or "pwm".
    The L6398's HIN is active high with an internal pull-down, its LIN active low with a pull-up (its datasheet,
    table 8), so an input the chip leaves undriven holds its switch off."""
    seen = {}
    for pin in spec["pins"]:
        words = pin["function"].split()
        if len(words) != 3 or words[0] != "phase" or words[2] not in ("high", "low"):
            continue
        driven = chip.gpio[pin["port"]].output(pin["pin"])
        high = words[2] == "high"
        if driven is None:
            state = "off"
        elif driven == "pwm":
            state = "pwm"
        else:
            state = "on" if driven == (1 if high else 0) else "off"
        pair = seen.setdefault(words[1], ["off", "off"])
        pair[0 if high else 1] = state
    return {phase: tuple(pair) for phase, pair in seen.items()}


def all_off(chip, spec):
    return switches(chip, spec) == {phase: ("off", "off") for phase in "ABC"}


def set_halls(chip, bits):
    """Drives the three hall lines to a state (bit 0 is H1)."""
    for n, (port, pin) in enumerate((("A", 15), ("B", 3), ("B", 10))):
        chip.gpio[port].drive(pin, bits >> n & 1)


def set_shunts(chip, spec, amps):
    """The IHM08M1's three shunt stages with `amps` flowing into the motor through the switching phase and out
    through the phase held low (docs/hardware.md, "Current sensing"): each stage reads its phase's current while
    the phase's low switch conducts and the offset otherwise, the switches taken from TIM1's outputs and, for a
    switching pair, its counter at the sampling instant (the dead time not modelled)."""
    offset = spec["analog"]["current_zero"]
    counts = amps * 1000 / spec["analog"]["current_milliamps_per_count"]
    channel_of = channels(spec)
    for phase, function in enumerate(CURRENTS):
        def reading(seconds, phase=phase):
            drive = switches(chip, spec)["ABC"[phase]]
            if drive == ("off", "on"):
                return offset + counts  # held low: the motor's current returns through this shunt
            if drive == ("pwm", "pwm"):
                high = chip.tim1.reference_at(phase, round(seconds * chip.core.hz))
                return offset if high else offset - counts  # recirculating through the low switch
            return offset
        chip.adc1.inputs[channel_of[function]] = reading

