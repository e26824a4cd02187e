"""A master image on its bench: modelled thrusters behind a TCA9548A on its thruster bus, the battery's CAN
frames, and a ground station on the virtual COM port speaking MAVLink through pymavlink."""

import struct

from pymavlink.dialects.v20 import common as mavlink

from conftest import Stm32g4, image

# MAVLink FTP's opcodes and replies (ArduPilot's numbering), and a reply's room for data.
FTP_TERMINATE, FTP_OPEN_RO, FTP_READ, FTP_CREATE, FTP_WRITE = 1, 4, 5, 6, 7
FTP_ACK, FTP_NAK = 128, 129
FTP_DATA = 239
MUX_ADDRESS = 0x70  # TCA9548A with A0-A2 low (TI SCPS207, 8.6.1)
THRUSTER_BUS = 2  # I2C2: `BusConfig`'s bus 1, the second of the three (lbv_master_fw::config)


class Thruster:
    """A thruster's I2C slave: keeps each order written to it and answers reads with `status`."""

    def __init__(self, status):
        self.status = bytes(status)
        self.orders = []
        self.reads = 0
        self._written = bytearray()
        self._reading = False
        self._index = 0

    def start(self, address, read):
        self._reading = read
        self._index = 0
        self._written = bytearray()
        if read:
            self.reads += 1
        return True

    def write(self, byte):
        self._written.append(byte)
        return True

    def read(self):
        byte = self.status[self._index] if self._index < len(self.status) else 0xFF
        self._index += 1
        return byte

    def stop(self):
        if not self._reading and self._written:
            self.orders.append(bytes(self._written))
            self._written = bytearray()


class Mux:
    """The TCA9548A: one control byte, bit n connects downstream channel n (TI SCPS207, 8.5)."""

    def __init__(self, channels):
        self.control = 0
        self.channels = channels  # channel -> {address: device}
        self.selections = []

    def start(self, address, read):
        return True

    def write(self, byte):
        self.control = byte
        self.selections.append(byte)
        return True

    def read(self):
        return self.control

    def get(self, address):
        """The device that answers `address` on the bus: the mux itself, or one on a connected channel."""
        if address == MUX_ADDRESS:
            return self
        found = [devices[address] for channel, devices in self.channels.items()
                 if self.control >> channel & 1 and address in devices]
        return found[0] if len(found) == 1 else None


class Ground:
    """A ground station on the VCP: pymavlink's encoder and parser, MAVLink 2."""

    def __init__(self, chip):
        self.chip = chip
        self.mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.mav.robust_parsing = True
        self._parsed = 0
        self.messages = []

    def send(self, message):
        self.chip.lpuart.send(message.pack(self.mav))

    def poll(self):
        data = bytes(self.chip.lpuart.sent[self._parsed:])
        self._parsed = len(self.chip.lpuart.sent)
        for message in self.mav.parse_buffer(data) or []:
            self.messages.append(message)
        return self.messages

    def of(self, kind):
        return [m for m in self.poll() if m.get_type() == kind]

    def wait(self, kind, seconds, check=lambda message: True):
        found = []
        self.chip.run_until(lambda: any(check(m) for m in self.of(kind)), seconds, f"a {kind}")
        found = [m for m in self.of(kind) if check(m)]
        return found[-1]


def start(name, expected, family="SeaBotix", thrusters=6, seed=1):
    """A booted master with `thrusters` modelled thrusters on mux channels 0.. of I2C2."""
    chip = Stm32g4(image(name), seed=seed)
    channels = {n: {address_of(expected, family): Thruster(expected["statuses"][family])} for n in range(thrusters)}
    mux = Mux(channels)
    if thrusters > 1:
        chip.i2c[THRUSTER_BUS].devices = mux
    else:
        chip.i2c[THRUSTER_BUS].devices = channels[0]
    chip.run_until(chip.idle, seconds=0.2, what=f"{name} reaching idle")
    return chip, mux, Ground(chip)


def address_of(expected, family):
    return {"SeaBotix": 0x29, "Legacy": 0x2A}[family]


class Ftp:
    """An operator's MAVLink FTP client on the modelled VCP, one request at a time. As a ground station's client
    does, it sends a request again, with the same sequence number, when no reply comes within `RESEND_S`; `resent`
    counts the requests it had to send again."""

    RESEND_S = 0.5
    TRIES = 3

    def __init__(self, chip, ground):
        self.chip, self.ground, self.seq, self.resent = chip, ground, 0, 0

    def reply(self, opcode, session=0, offset=0, data=b""):
        """The reply's payload to one request, ACK or NAK."""
        self.seq += 1
        seq = self.seq
        header = struct.pack("<HBBBBBBI", seq, session, opcode, len(data), 0, 0, 0, offset)
        payload = (header + data).ljust(251, b"\0")

        def answered():
            replies = self.ground.of("FILE_TRANSFER_PROTOCOL")
            return [m for m in replies if struct.unpack_from("<H", bytes(m.payload))[0] == seq + 1]

        for attempt in range(self.TRIES):
            self.ground.send(mavlink.MAVLink_file_transfer_protocol_message(0, 1, 1, list(payload)))
            end = self.chip.core.cycles + int(self.RESEND_S * self.chip.core.hz)
            self.chip.core.run(until_cycle=end, until=answered)
            if answered():
                break
            self.resent += 1
        else:
            raise AssertionError(f"opcode {opcode} at {offset}: no reply to {self.TRIES} tries")
        return bytes(answered()[-1].payload)

    def request(self, opcode, session=0, offset=0, data=b""):
        """One request that must be ACKed: the session its reply names."""
        reply = self.reply(opcode, session, offset, data)
        assert reply[3] == FTP_ACK, f"opcode {opcode}: NAK {reply[12]}"
        return reply[2]

    def put(self, path, file):
        session = self.request(FTP_CREATE, data=path.encode())
        for offset in range(0, len(file), FTP_DATA):
            self.request(FTP_WRITE, session, offset, file[offset : offset + FTP_DATA])
        self.request(FTP_TERMINATE, session)

    def get(self, path, size=80):
        """The file at `path`, read `size` bytes at a time until EndOfFile; `None` when it cannot be opened (the
        NAK's code then in `self.refused`)."""
        opened = self.reply(FTP_OPEN_RO, data=path.encode())
        if opened[3] != FTP_ACK:
            self.refused = opened[12]
            return None
        session, length = opened[2], struct.unpack_from("<I", opened, 12)[0]
        data = b""
        while True:
            reply = self.reply(FTP_READ, session, len(data), bytes(size))
            if reply[3] == FTP_NAK:
                break
            data += reply[12 : 12 + reply[4]]
        self.request(FTP_TERMINATE, session)
        assert len(data) == length, (len(data), length)
        return data
