"""The image's defmt log, read from its RTT up-buffer in RAM as a probe would (SEGGER RTT control block, defmt's
rzCOBS frames), decoded with the format strings the ELF's `.defmt` symbols carry."""

import json
import re
import struct

LEVELS = ("trace", "debug", "info", "warn", "error", "println")


def rzcobs_decode(data: bytes) -> bytes:
    """defmt's rzCOBS: control bytes follow the bytes they describe, so a frame is decoded from its end."""
    out = []
    i = len(data) - 1
    while i >= 0:
        x = data[i]
        i -= 1
        if x == 0xFF:
            for _ in range(134):
                out.append(data[i] if i >= 0 else 0)
                i -= 1
        elif x & 0x80:
            out.append(0)
            for _ in range((x & 0x7F) + 7):
                out.append(data[i] if i >= 0 else 0)
                i -= 1
        else:
            for bit in range(6, -1, -1):
                if x >> bit & 1:
                    out.append(0)
                else:
                    out.append(data[i] if i >= 0 else 0)
                    i -= 1
    out.reverse()
    return bytes(out)


class Table:
    """The interned strings: a `.defmt` symbol's address is its index, its name a JSON description."""

    def __init__(self, elf):
        self.entries = {}
        section = None
        for index, candidate in enumerate(elf.iter_sections()):
            if candidate.name == ".defmt":
                section = index
        symbols = elf.get_section_by_name(".symtab")
        for symbol in symbols.iter_symbols():
            if symbol["st_shndx"] == section and symbol.name.startswith("{"):
                try:
                    self.entries[symbol["st_value"]] = json.loads(symbol.name)
                except ValueError:
                    pass


ARG = re.compile(r"\{(?:=([a-z0-9\[\]?;]+))?(?::([^}]*))?\}")


class Log:
    """Frames as they arrive: each line is (level, text)."""

    def __init__(self, table):
        self.table = table
        self.pending = bytearray()
        self.lines = []

    def feed(self, data):
        self.pending += data
        while b"\x00" in self.pending:
            end = self.pending.index(0)
            frame = bytes(self.pending[:end])
            del self.pending[: end + 1]
            if frame:
                self.lines.append(self.decode(rzcobs_decode(frame)))

    def decode(self, frame):
        if len(frame) < 2:
            return ("error", f"<short frame {frame.hex()}>")
        index = struct.unpack_from("<H", frame)[0]
        entry = self.table.entries.get(index)
        if entry is None:
            return ("error", f"<unknown string {index}>")
        tag = entry.get("tag", "")
        level = tag[len("defmt_"):] if tag.startswith("defmt_") else tag
        return (level, self.render(entry.get("data", ""), frame[2:]))

    def render(self, fmt, args, offset=0, nested=False):
        out, position = [], 0
        for match in ARG.finditer(fmt):
            out.append(fmt[position : match.start()])
            position = match.end()
            kind, hint = match.group(1), match.group(2) or ""
            value, offset = self._argument(kind, args, offset)
            if value is not None and hint.endswith("x") and value.lstrip("-").isdigit():
                value = f"{int(value):#x}" if "#" in hint else f"{int(value):x}"
            if value is None:
                out.append("…")
                text = "".join(out)
                return (text, None) if nested else text
            out.append(value)
        out.append(fmt[position:])
        text = "".join(out).replace("{{", "{").replace("}}", "}")
        return (text, offset) if nested else text

    def _argument(self, kind, args, offset):
        sizes = {"u8": "<B", "i8": "<b", "u16": "<H", "i16": "<h", "u32": "<I", "i32": "<i", "u64": "<Q",
                 "i64": "<q", "bool": "<B", "f32": "<f"}
        if kind in sizes:
            size = struct.calcsize(sizes[kind])
            if offset + size > len(args):
                return None, offset
            return str(struct.unpack_from(sizes[kind], args, offset)[0]), offset + size
        if kind in (None, "?"):
            # `{}`: the value's own format string comes first, by its index (defmt's Format encoding).
            if offset + 2 > len(args):
                return None, offset
            entry = self.table.entries.get(struct.unpack_from("<H", args, offset)[0])
            if entry is None:
                return None, offset
            text, after = self.render(entry.get("data", ""), args, offset + 2, nested=True)
            return (text, after) if after is not None else (None, offset)
        if kind == "str":
            if offset + 4 > len(args):
                return None, offset
            length = struct.unpack_from("<I", args, offset)[0]
            text = args[offset + 4 : offset + 4 + length]
            return text.decode("utf-8", "replace"), offset + 4 + length
        return None, offset


class Rtt:
    """The up-buffer 0 of the SEGGER RTT control block at `_SEGGER_RTT`, drained as a probe drains it."""

    def __init__(self, core, address, log):
        self.core = core
        self.address = address
        self.log = log

    def drain(self):
        uc = self.core.uc
        # Control block: 16-byte id, up and down buffer counts, then up buffer 0: name, buffer, size, write, read.
        # Until the start-up code has copied .data, RAM holds noise: read only a block that says what it is. (Read
        # in place, `Core.ram`: the run loop drains after every stop.)
        ram, offset = self.core.ram, self.address - 0x2000_0000
        if ram[offset : offset + 10] != b"SEGGER RTT":
            return
        _, buffer, size, write, read = struct.unpack_from("<5I", ram, offset + 24)
        if size == 0 or write == read or write >= size or read >= size:
            return
        if not 0x2000_0000 <= buffer <= 0x2000_0000 + self.core.part.sram_size - size:
            return
        if write > read:
            data = bytes(uc.mem_read(buffer + read, write - read))
        else:
            data = bytes(uc.mem_read(buffer + read, size - read)) + bytes(uc.mem_read(buffer, write))
        self.core.write32(self.address + 24 + 16, write)
        self.log.feed(data)
