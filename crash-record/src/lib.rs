//! A board's post-mortem record: what stopped it (a panic, a HardFault, an NMI, an interrupt it never enables, the
//! watchdog's bite), where (the stacked PC, LR, xPSR and SP, the fault status registers, a panic's source line),
//! when (uptime), what it ran (target and version) and the last events before, kept across the reset that follows
//! and read at the next start. The images write it; `lbv decode crash` reads it, with the ELF's symbols.
//!
//! It lives in the region [`REGION_LEN`] bytes long at the bottom of RAM (`g431_hw::memory::CRASH`): the record
//! ([`LEN`] bytes), then the [`Ring`] of the last events, which a running image keeps there so that a watchdog
//! reset, which runs no handler, still finds them. Neither the bootloader nor the start-up code writes there, and
//! a stack reaches it only once it has used all but the last bytes of its room. Everything here is a pure function
//! of that region's bytes ([`Region`]): the binding only finds its address.
//!
//! The record, 128 bytes, little-endian, [`FORMAT`] 1:
//!
//! | bytes | field |
//! |---|---|
//! | 0-3 | magic `LBVC` |
//! | 4 | format, 1 |
//! | 5 | [`Kind`] |
//! | 6 | target: the update file's target byte (1 a SeaBotix thruster, 2 a Legacy one, 3 the master) |
//! | 7 | flags: bit 0, the board has told it since |
//! | 8-11 | the running image's version (major, minor, patch u16) |
//! | 12-27 | the stacked PC, LR, xPSR, and SP before the exception ([`Frame`]; 0 where there is none) |
//! | 28-43 | CFSR, HFSR, MMFAR, BFAR ([`FaultStatus`]) |
//! | 44-47 | RCC_CSR as the start after it read it: why the chip reset |
//! | 48-51 | uptime at the stop, ms |
//! | 52-55 | a panic's source file: the address of its path in the image's flash (0: not a panic's) |
//! | 56-59 | a panic's line |
//! | 60-61 | a panic's source path's length |
//! | 62-63 | the exception number active at the stop (IPSR) |
//! | 64 | events held, 0-7 |
//! | 65-67 | 0 |
//! | 68-123 | 7 events, oldest first ([`Event`], 8 bytes each) |
//! | 124-127 | CRC-32 (zlib's) of bytes 0-123 |
//!
//! A panic's file is an address, not the path: the path is in the ELF the image was built from, and formatting or
//! copying it would keep every panic site's location in the image. A record that fails any check is refused with an
//! [`Error`]; a power-on start clears the region without reading it, so noise is never taken for a record.

#![no_std]

#[cfg(test)]
extern crate std;

use core::fmt;

/// The record's length in bytes.
pub const LEN: usize = 128;
/// The ring's length in bytes.
pub const RING_LEN: usize = 64;
/// The region: the record, then the ring.
pub const REGION_LEN: usize = LEN + RING_LEN;
const _: () = assert!(core::mem::size_of::<Region>() == REGION_LEN && core::mem::align_of::<Region>() == 1);
/// The events a record and the ring hold.
pub const EVENTS: usize = 7;
/// The record's format.
pub const FORMAT: u8 = 1;

const MAGIC: [u8; 4] = *b"LBVC";
const RING_MAGIC: [u8; 4] = *b"LBVE";
/// Where the CRC starts.
const CRC_AT: usize = LEN - 4;
const EVENTS_AT: usize = 68;

/// What stopped the board.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Kind {
    /// A panic: an overflow check, a bound, an `unwrap` the lints let through in a dependency.
    Panic = 1,
    /// A HardFault (and the faults escalated to it; flip-link turns a stack overflow into one).
    HardFault = 2,
    /// A non-maskable interrupt that is not a flash ECC error the image lets pass.
    Nmi = 3,
    /// An interrupt the image never enables.
    StrayInterrupt = 4,
    /// The watchdog reset the chip: no handler ran, so the record has no registers, only the events.
    Watchdog = 5,
}

impl Kind {
    const fn from_byte(byte: u8) -> Option<Self> {
        match byte {
            1 => Some(Self::Panic),
            2 => Some(Self::HardFault),
            3 => Some(Self::Nmi),
            4 => Some(Self::StrayInterrupt),
            5 => Some(Self::Watchdog),
            _ => None,
        }
    }

    /// Its name, for a person.
    pub const fn name(self) -> &'static str {
        match self {
            Self::Panic => "panic",
            Self::HardFault => "HardFault",
            Self::Nmi => "NMI",
            Self::StrayInterrupt => "stray interrupt",
            Self::Watchdog => "watchdog reset",
        }
    }
}

/// The registers the exception stacked: where the code was.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Frame {
    pub pc: u32,
    pub lr: u32,
    pub xpsr: u32,
    /// The stack pointer before the exception stacked its frame.
    pub sp: u32,
}

/// The fault status registers (ARMv7-M B3.2.15-B3.2.18): why a fault was taken, and the address it was about.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FaultStatus {
    pub cfsr: u32,
    pub hfsr: u32,
    pub mmfar: u32,
    pub bfar: u32,
}

/// A panic's location: its source path's address and length in the image's flash, and its line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PanicAt {
    pub file: u32,
    pub file_len: u16,
    pub line: u32,
}

/// What happened: a code and its argument.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum What {
    /// The image started; the argument is why the chip reset (RCC_CSR's top byte: its reset flags).
    Started(u8),
    Armed,
    /// Disarmed; the argument is why (the vehicle's reason code).
    Disarmed(u8),
    /// A thruster (by slot) stopped answering.
    ThrusterLost(u8),
    /// It answers again.
    ThrusterBack(u8),
    /// The operator's heartbeats stopped.
    OperatorLost,
    OperatorBack,
    /// An update applied to a target (a thruster slot, 200 and 201 a family, 255 the master).
    UpdateApplied(u8),
    /// A thruster's orders stopped coming for longer than its link timeout.
    OrdersLost,
    /// A thruster latched a fault: its FAULT bits.
    FaultLatched(u16),
    /// A code this format does not know (a newer image's), kept as it came.
    Other {
        code: u16,
        arg: u16,
    },
}

impl What {
    /// Its code and argument.
    pub const fn to_parts(self) -> (u16, u16) {
        match self {
            Self::Started(cause) => (1, cause as u16),
            Self::Armed => (2, 0),
            Self::Disarmed(why) => (3, why as u16),
            Self::ThrusterLost(slot) => (4, slot as u16),
            Self::ThrusterBack(slot) => (5, slot as u16),
            Self::OperatorLost => (6, 0),
            Self::OperatorBack => (7, 0),
            Self::UpdateApplied(target) => (8, target as u16),
            Self::OrdersLost => (9, 0),
            Self::FaultLatched(bits) => (10, bits),
            Self::Other { code, arg } => (code, arg),
        }
    }

    /// The event a code and argument stand for.
    pub const fn from_parts(code: u16, arg: u16) -> Self {
        let byte = arg as u8;
        match code {
            1 => Self::Started(byte),
            2 => Self::Armed,
            3 => Self::Disarmed(byte),
            4 => Self::ThrusterLost(byte),
            5 => Self::ThrusterBack(byte),
            6 => Self::OperatorLost,
            7 => Self::OperatorBack,
            8 => Self::UpdateApplied(byte),
            9 => Self::OrdersLost,
            10 => Self::FaultLatched(arg),
            _ => Self::Other { code, arg },
        }
    }
}

impl fmt::Display for What {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::Started(flags) => write!(f, "started (reset flags {flags:#04x}, RCC_CSR's top byte)"),
            Self::Armed => f.write_str("armed"),
            Self::Disarmed(why) => write!(f, "disarmed (reason {why})"),
            Self::ThrusterLost(slot) => write!(f, "T{} lost", u16::from(slot) + 1),
            Self::ThrusterBack(slot) => write!(f, "T{} back", u16::from(slot) + 1),
            Self::OperatorLost => f.write_str("the operator's heartbeats lost"),
            Self::OperatorBack => f.write_str("the operator's heartbeats back"),
            Self::UpdateApplied(target) => write!(f, "update applied to target {target}"),
            Self::OrdersLost => f.write_str("orders lost"),
            Self::FaultLatched(bits) => write!(f, "fault latched (FAULT {bits:#06x})"),
            Self::Other { code, arg } => write!(f, "event {code} ({arg:#06x})"),
        }
    }
}

/// An event and when it happened (ms since its image started).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Event {
    pub at_ms: u32,
    pub what: What,
}

impl Event {
    const NONE: Event = Event {
        at_ms: 0,
        what: What::Other { code: 0, arg: 0 },
    };

    fn to_bytes(self) -> [u8; 8] {
        let (code, arg) = self.what.to_parts();
        let [a0, a1, a2, a3] = self.at_ms.to_le_bytes();
        let [c0, c1] = code.to_le_bytes();
        let [g0, g1] = arg.to_le_bytes();
        [a0, a1, a2, a3, c0, c1, g0, g1]
    }

    fn from_bytes(bytes: [u8; 8]) -> Self {
        let [a0, a1, a2, a3, c0, c1, g0, g1] = bytes;
        Self {
            at_ms: u32::from_le_bytes([a0, a1, a2, a3]),
            what: What::from_parts(u16::from_le_bytes([c0, c1]), u16::from_le_bytes([g0, g1])),
        }
    }
}

/// Why bytes are not a record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// Not [`LEN`] bytes.
    Length(usize),
    /// Not a record's magic: nothing was recorded.
    Magic,
    /// A format this reader does not know.
    Format(u8),
    /// The CRC does not match: torn, or noise.
    Checksum,
    /// A kind that is not one ([`Kind`]).
    Kind(u8),
    /// More events held than there is room for.
    Events(u8),
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::Length(len) => write!(f, "{len} bytes, not a record's {LEN}"),
            Self::Magic => f.write_str("no record (not its magic)"),
            Self::Format(format) => write!(f, "format {format}, not {FORMAT}"),
            Self::Checksum => f.write_str("its CRC does not match: torn or not a record"),
            Self::Kind(kind) => write!(f, "kind {kind} is none"),
            Self::Events(held) => write!(f, "{held} events held, more than {EVENTS}"),
        }
    }
}

/// A post-mortem record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Record {
    pub kind: Kind,
    /// The update file's target byte: 1 a SeaBotix thruster, 2 a Legacy one, 3 the master.
    pub target: u8,
    /// The board has told it since (a STATUSTEXT, or the master has fetched it).
    pub told: bool,
    /// The running image's version as its image info holds it.
    pub version: [u8; 4],
    pub frame: Frame,
    pub faults: FaultStatus,
    /// RCC_CSR as the start after the stop read it (0 until then).
    pub reset_cause: u32,
    pub uptime_ms: u32,
    /// The exception number active at the stop (IPSR: 3 HardFault, 2 NMI, 16 + n interrupt n; 0 thread mode).
    pub exception: u16,
    pub panic: Option<PanicAt>,
    /// The last events before the stop, oldest first; `held` of them.
    pub events: [Event; EVENTS],
    pub held: u8,
}

impl Record {
    /// The events it holds, oldest first.
    pub fn events(&self) -> &[Event] {
        self.events.get(..usize::from(self.held)).unwrap_or(&self.events)
    }

    /// Its bytes.
    pub fn encode(&self) -> [u8; LEN] {
        let mut bytes = [0; LEN];
        let mut put = |at: usize, value: &[u8]| {
            if let Some(slot) = bytes.get_mut(at..at + value.len()) {
                slot.copy_from_slice(value);
            }
        };
        put(0, &MAGIC);
        put(4, &[FORMAT, self.kind as u8, self.target, u8::from(self.told)]);
        put(8, &self.version);
        let words = [
            self.frame.pc,
            self.frame.lr,
            self.frame.xpsr,
            self.frame.sp,
            self.faults.cfsr,
            self.faults.hfsr,
            self.faults.mmfar,
            self.faults.bfar,
            self.reset_cause,
            self.uptime_ms,
        ];
        for (n, word) in words.iter().enumerate() {
            put(12 + 4 * n, &word.to_le_bytes());
        }
        let panic = self.panic.unwrap_or(PanicAt {
            file: 0,
            file_len: 0,
            line: 0,
        });
        put(52, &panic.file.to_le_bytes());
        put(56, &panic.line.to_le_bytes());
        put(60, &panic.file_len.to_le_bytes());
        put(62, &self.exception.to_le_bytes());
        put(64, &[self.held.min(EVENTS as u8)]);
        for (n, event) in self.events().iter().enumerate() {
            put(EVENTS_AT + 8 * n, &event.to_bytes());
        }
        let crc = crc32(bytes.get(..CRC_AT).unwrap_or_default());
        if let Some(slot) = bytes.get_mut(CRC_AT..) {
            slot.copy_from_slice(&crc.to_le_bytes());
        }
        bytes
    }

    /// The record `bytes` hold, checked: magic, format, CRC, kind and events.
    pub fn decode(bytes: &[u8]) -> Result<Self, Error> {
        let bytes: &[u8; LEN] = bytes.try_into().map_err(|_| Error::Length(bytes.len()))?;
        let word = |at: usize| {
            let mut four = [0; 4];
            if let Some(slot) = bytes.get(at..at + 4) {
                four.copy_from_slice(slot);
            }
            u32::from_le_bytes(four)
        };
        let half = |at: usize| (word(at) & 0xFFFF) as u16;
        let byte = |at: usize| bytes.get(at).copied().unwrap_or(0);
        if bytes.get(..4) != Some(&MAGIC[..]) {
            return Err(Error::Magic);
        }
        if byte(4) != FORMAT {
            return Err(Error::Format(byte(4)));
        }
        if crc32(bytes.get(..CRC_AT).unwrap_or_default()) != word(CRC_AT) {
            return Err(Error::Checksum);
        }
        let kind = Kind::from_byte(byte(5)).ok_or(Error::Kind(byte(5)))?;
        let held = byte(64);
        if usize::from(held) > EVENTS {
            return Err(Error::Events(held));
        }
        let mut events = [Event::NONE; EVENTS];
        for (n, event) in events.iter_mut().enumerate().take(usize::from(held)) {
            let at = EVENTS_AT + 8 * n;
            let mut eight = [0; 8];
            if let Some(slot) = bytes.get(at..at + 8) {
                eight.copy_from_slice(slot);
            }
            *event = Event::from_bytes(eight);
        }
        let file = word(52);
        Ok(Self {
            kind,
            target: byte(6),
            told: byte(7) & 1 == 1,
            version: word(8).to_le_bytes(),
            frame: Frame {
                pc: word(12),
                lr: word(16),
                xpsr: word(20),
                sp: word(24),
            },
            faults: FaultStatus {
                cfsr: word(28),
                hfsr: word(32),
                mmfar: word(36),
                bfar: word(40),
            },
            reset_cause: word(44),
            uptime_ms: word(48),
            exception: half(62),
            panic: (file != 0).then(|| PanicAt {
                file,
                file_len: half(60),
                line: word(56),
            }),
            events,
            held,
        })
    }
}

/// The ring of the last [`EVENTS`] events a running image keeps in the region: magic `LBVE`, the slot the next
/// event goes in, how many it holds, a zero byte, then the events. Bytes that are not a ring (after a power-on, or
/// torn) read as an empty one, and the next event starts it again.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ring([u8; RING_LEN]);

impl Ring {
    /// An empty ring.
    pub const fn new() -> Self {
        let mut bytes = [0; RING_LEN];
        bytes[0] = RING_MAGIC[0];
        bytes[1] = RING_MAGIC[1];
        bytes[2] = RING_MAGIC[2];
        bytes[3] = RING_MAGIC[3];
        Self(bytes)
    }

    /// The ring `bytes` hold, whatever they are.
    pub const fn from_bytes(bytes: [u8; RING_LEN]) -> Self {
        Self(bytes)
    }

    pub const fn bytes(&self) -> &[u8; RING_LEN] {
        &self.0
    }

    /// Where the next event goes and how many it holds; `None` if these bytes are not a ring.
    fn state(&self) -> Option<(usize, usize)> {
        let [m0, m1, m2, m3, next, held, ..] = self.0;
        let (next, held) = (usize::from(next), usize::from(held));
        ([m0, m1, m2, m3] == RING_MAGIC && next < EVENTS && held <= EVENTS).then_some((next, held))
    }

    /// Add `event`, in place of the oldest once it is full.
    pub fn push(&mut self, event: Event) {
        let (next, held) = self.state().unwrap_or_else(|| {
            *self = Self::new();
            (0, 0)
        });
        let at = 8 + 8 * next;
        if let Some(slot) = self.0.get_mut(at..at + 8) {
            slot.copy_from_slice(&event.to_bytes());
        }
        if let Some([next_slot, held_slot]) = self.0.get_mut(4..6) {
            *next_slot = ((next + 1) % EVENTS) as u8;
            *held_slot = (held + 1).min(EVENTS) as u8;
        }
    }

    /// Its events, oldest first, and how many.
    pub fn events(&self) -> ([Event; EVENTS], u8) {
        let mut events = [Event::NONE; EVENTS];
        let Some((next, held)) = self.state() else {
            return (events, 0);
        };
        let first = (next + EVENTS - held) % EVENTS;
        for (n, event) in events.iter_mut().enumerate().take(held) {
            let at = 8 + 8 * ((first + n) % EVENTS);
            let mut eight = [0; 8];
            if let Some(slot) = self.0.get(at..at + 8) {
                eight.copy_from_slice(slot);
            }
            *event = Event::from_bytes(eight);
        }
        (events, held as u8)
    }
}

impl Default for Ring {
    fn default() -> Self {
        Self::new()
    }
}

/// What stopped the board, as its handler saw it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Stop {
    pub kind: Kind,
    pub frame: Frame,
    pub faults: FaultStatus,
    pub exception: u16,
    pub panic: Option<PanicAt>,
    pub uptime_ms: u32,
}

/// The image that runs: its target kind and version, as the record keeps them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Image {
    pub target: u8,
    pub version: [u8; 4],
}

/// How the chip last reset, from RCC_CSR (RM0440 7.4.30).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ResetCause(pub u32);

impl ResetCause {
    /// BORRSTF (bit 27): a power-on or brown-out reset; RAM holds noise.
    pub const fn power_on(self) -> bool {
        self.0 & (1 << 27) != 0
    }

    /// IWDGRSTF (bit 29) or WWDGRSTF (bit 30).
    pub const fn watchdog(self) -> bool {
        self.0 & (0b11 << 29) != 0
    }
}

/// The region at the bottom of RAM: the record, then the ring. Any bytes are a region (its functions check what
/// they read), so the binding may take the RAM there as one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(C)]
pub struct Region {
    pub record: [u8; LEN],
    pub ring: [u8; RING_LEN],
}

impl Region {
    /// A region holding nothing.
    pub const fn new() -> Self {
        Self {
            record: [0; LEN],
            ring: [0; RING_LEN],
        }
    }

    /// At the start, before anything else writes here: after a power-on the region is cleared unread (it holds
    /// noise); otherwise the record left by the stop before is kept, with why the chip reset, and a watchdog reset
    /// that left none makes one from the ring. Then the ring says the image started. The record there, if any.
    pub fn start(&mut self, cause: ResetCause, image: Image) -> Option<Record> {
        if cause.power_on() {
            *self = Self::new();
        }
        let ring = Ring::from_bytes(self.ring);
        let record = match Record::decode(&self.record) {
            Ok(record) => Some(record),
            Err(_) if cause.watchdog() => {
                let (events, held) = ring.events();
                Some(Record {
                    kind: Kind::Watchdog,
                    target: image.target,
                    told: false,
                    version: image.version,
                    frame: Frame::default(),
                    faults: FaultStatus::default(),
                    reset_cause: 0,
                    uptime_ms: events.get(usize::from(held).wrapping_sub(1)).map_or(0, |e| e.at_ms),
                    exception: 0,
                    panic: None,
                    events,
                    held,
                })
            }
            Err(_) => None,
        };
        let record = record.map(|mut record| {
            if record.reset_cause == 0 {
                record.reset_cause = cause.0;
            }
            self.record = record.encode();
            record
        });
        self.note(Event {
            at_ms: 0,
            what: What::Started((cause.0 >> 24) as u8),
        });
        record
    }

    /// Note an event in the ring.
    pub fn note(&mut self, event: Event) {
        let mut ring = Ring::from_bytes(self.ring);
        ring.push(event);
        self.ring = *ring.bytes();
    }

    /// Record `stop` of `image`, with the ring's events, in place of a record from before this start. One from this
    /// run (its reset cause not set yet) stays: a fault taken while stopping, such as the one the panic handler's
    /// undefined instruction raises, keeps the stop that began it.
    pub fn record(&mut self, stop: Stop, image: Image) {
        if self.read().is_some_and(|record| record.reset_cause == 0) {
            return;
        }
        let (events, held) = Ring::from_bytes(self.ring).events();
        let record = Record {
            kind: stop.kind,
            target: image.target,
            told: false,
            version: image.version,
            frame: stop.frame,
            faults: stop.faults,
            reset_cause: 0,
            uptime_ms: stop.uptime_ms,
            exception: stop.exception,
            panic: stop.panic,
            events,
            held,
        };
        self.record = record.encode();
    }

    /// The record held, if any.
    pub fn read(&self) -> Option<Record> {
        Record::decode(&self.record).ok()
    }

    /// Mark the record held as told.
    pub fn mark_told(&mut self) {
        if let Ok(mut record) = Record::decode(&self.record) {
            record.told = true;
            self.record = record.encode();
        }
    }

    /// Forget the record held (the ring goes on).
    pub fn clear(&mut self) {
        self.record = [0; LEN];
    }
}

impl Default for Region {
    fn default() -> Self {
        Self::new()
    }
}

/// CRC-32 as zlib computes it (reflected polynomial 0xEDB88320, initial value and final XOR all ones), bitwise.
pub fn crc32(bytes: &[u8]) -> u32 {
    !bytes.iter().fold(!0u32, |crc, byte| {
        (0..8).fold(crc ^ u32::from(*byte), |crc, _| {
            if crc & 1 == 1 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            }
        })
    })
}

#[cfg(feature = "cortex-m")]
pub mod cortex_m;

#[cfg(test)]
mod tests;
