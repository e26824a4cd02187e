//! An I2C bus: one master port, any number of devices, an optional TCA9548A, and the two lines themselves.
//!
//! - Time: every transfer is charged its bit times on the virtual clock (START, the address byte and its ACK, 9
//!   bits per data byte, STOP) at the bus's bit rate, plus any clock stretching.
//! - Devices: a [`Device`] answers at once from the simulation (a scripted thruster, a sensor); a [`Target`] is
//!   the slave port of firmware running on the same clock, which takes each transfer as it would from its I2C
//!   peripheral: it is addressed once the address byte is in and acknowledged, SCL is stretched until it answers
//!   (one that does not answer within the master's timeout times the master out, as embassy-stm32 does), and its
//!   answer returns only once the data bytes have moved. Simplified: an answer to a transfer the master has given
//!   up on returns at once as if the bytes had moved (the firmware cannot tell; on the chip its peripheral would
//!   meet whatever the master does next).
//! - Addresses nobody acknowledges (absent, unpowered, behind an unselected multiplexer channel) NACK.
//! - Several slaves at one address (mux channels enabled together, each with a slave of the same family): SDA and
//!   SCL are open-drain, wired-AND (UM10204 3.1.1), so every powered slave that hears the transfer takes part, and
//!   the transfer counts as a collision ([`Stats::collisions`]). A write reaches each of them, each through its own
//!   [`Tamper`]. An ACK, of the address or of a data byte, is there when at least one of them drives it (3.1.6): a
//!   slave that does not acknowledge, or loses power on the way, is hidden behind the others, its copy torn or
//!   missing while the master sees success; the master sees a NACK only at the first byte none of them
//!   acknowledges. SCL stays low until the last of them lets it go (3.1.9): the bytes move once every firmware port
//!   has answered and every stretching device is done, and one that does not answer within the timeout times the
//!   whole transfer out. A read gets the AND of what they all drive (one with nothing more to send, or unpowered,
//!   leaves 0xFF). Each firmware port is told whether its own bytes all moved. Simplified: the slaves are not
//!   clocked bit by bit, so each port's read counts as sent whatever the others drove (a peripheral that sees
//!   another's 0 where it sends a 1 and gives up is not modelled); a device answers at the START as it does alone;
//!   a slave holding SDA low, or a glitch at one port, fails the transfer for all of them.
//! - Power ([`Bus::set_powered`]): an unpowered slave's pins let SCL and SDA go, to the pull-ups (UM10204 3.1.1).
//!   A firmware port that loses power in the middle of a transfer tears it: in its address byte, the address is
//!   not acknowledged; while it stretches SCL or while the bytes move, the master clocks on against released lines,
//!   so the rest of a read is 0xFF and a write's next byte is not acknowledged (unless another slave that hears the
//!   transfer drives them, as above). A [`Device`] is not torn: its power counts from the next START.
//! - Faults: a device's bytes can be corrupted both ways ([`Tamper`]); a transfer to firmware can be torn by a
//!   glitch ([`Bus::disturb`]); a slave can hold SDA low for a number of SCL clocks, now ([`Bus::hold_sda`]) or
//!   from its next transfer ([`Bus::hold_sda_at_next_transfer`]), which fails every transfer until the master
//!   clocks it free on the lines ([`Scl`], [`Sda`]: open-drain pins as embedded-hal sees them, for the UM10204
//!   3.1.16 recovery).
//! - The master's CPU ([`Bus::set_master_cpu`]): a transfer under way when it stalls (a flash erase) waits for it,
//!   SCL held, and one that so lasts as long as the timeout or longer fails as a timeout.

use alloc::rc::Rc;
use alloc::vec;
use alloc::vec::Vec;
use core::cell::{Cell, RefCell};
use core::convert::Infallible;
use core::mem;
use core::pin::Pin;
use core::task::Poll;

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer, with_deadline};
use embedded_hal::digital::{self, InputPin, OutputPin};
use embedded_hal_async::i2c::{ErrorKind, ErrorType, I2c, NoAcknowledgeSource, Operation};

use crate::cpu::Cpu;

/// START (or repeated START), the address byte and its ACK bit.
const ADDRESS_BITS: u64 = 1 + 9;
/// STOP.
const STOP_BITS: u64 = 1;

/// A bus's speed and its master's patience.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timing {
    /// One bit time.
    pub bit: Duration,
    /// A transfer stalled this long (SCL held low) is abandoned by the master with a timeout.
    pub timeout: Duration,
}

impl Timing {
    /// A bus clocked at `frequency_hz` whose master gives up on a transfer after `timeout`.
    pub const fn new(frequency_hz: u32, timeout: Duration) -> Self {
        let hz = if frequency_hz == 0 { 1 } else { frequency_hz as u64 };
        Self {
            bit: Duration::from_micros(1_000_000 / hz),
            timeout,
        }
    }
}

/// How a device is wired: to the bus itself, or to a channel of the bus's TCA9548A.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Route {
    /// On the bus itself: it hears every transfer.
    Direct,
    /// Behind the multiplexer, on this channel (0..=7): it hears transfers only while its channel is selected.
    Mux(u8),
}

/// What a [`Device`] does with a transfer addressed to it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reply {
    /// Acknowledged; the data moved.
    Ack,
    /// The address was not acknowledged (a device that is there but does not answer).
    Nack,
    /// Acknowledged, then SCL held low this long before the data moved; as long as the master's timeout or longer,
    /// the master gives up.
    Stretch(Duration),
    /// The device went wrong mid-byte and holds SDA low until it has seen this many SCL clocks (`u32::MAX`: never):
    /// the master sees a bus error, and so does every transfer after it until the bus is clocked free.
    HoldSda(u32),
}

/// A device the simulation answers for at once: it gets every transfer to its address while it is reachable.
pub trait Device {
    /// Its 7-bit address.
    fn address(&self) -> u8;
    /// The master writes `bytes`.
    fn write(&mut self, bytes: &[u8]) -> Reply;
    /// The master reads `buffer.len()` bytes: fill them (what is left unfilled reads as sent).
    fn read(&mut self, buffer: &mut [u8]) -> Reply;
}

/// Corruption between a device and the master.
#[derive(Debug, Clone, Copy, Default)]
pub struct Tamper {
    /// Flip these bits of every byte the device sends (a noisy line).
    pub read_xor: u8,
    /// Flip these bits of the last byte the master writes to the device (a message's checksum arrives wrong).
    pub write_last_xor: u8,
    /// Rewrite every write before the device sees it.
    pub rewrite: Option<fn(&mut [u8])>,
    /// Rewrite every read before the master sees it (a controller that lays its reply out otherwise).
    pub rewrite_read: Option<fn(&mut [u8])>,
}

impl Tamper {
    /// Leaves everything as sent.
    pub const NONE: Tamper = Tamper {
        read_xor: 0,
        write_last_xor: 0,
        rewrite: None,
        rewrite_read: None,
    };

    fn write(&self, bytes: &mut [u8]) {
        if let Some(rewrite) = self.rewrite {
            rewrite(bytes);
        }
        if let Some(last) = bytes.last_mut() {
            *last ^= self.write_last_xor;
        }
    }

    fn read(&self, bytes: &mut [u8]) {
        if let Some(rewrite) = self.rewrite_read
            && !bytes.is_empty()
        {
            rewrite(bytes);
        }
        for byte in bytes {
            *byte ^= self.read_xor;
        }
    }
}

/// A device's handle on its bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceId(usize);

/// What the bus counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Bit times the bus was busy (transfers, and clock pulses on the pins).
    pub bits: u64,
    /// Transfers the master started (each operation of a transaction is one).
    pub transfers: u64,
    /// Transfers not acknowledged.
    pub nacks: u64,
    /// Transfers the master abandoned at its timeout.
    pub timeouts: u64,
    /// Of those, transfers its CPU's stall held past the timeout.
    pub stalled: u64,
    /// Transfers that failed on the bus: SDA held low (before or during the transfer), or a glitch.
    pub bus_errors: u64,
    /// Transfers that several slaves heard at once: their ACKs, and a read's bytes, meet wired-AND on SDA.
    pub collisions: u64,
    /// Firmware ports' copies of a transfer a power cut tore after they had acknowledged the address (one per port):
    /// its bits from the cut on read 1, and its next byte of a write is not acknowledged (the master sees that only
    /// when no other slave acknowledges it).
    pub torn: u64,
    /// SCL clock pulses made on the pins.
    pub pin_clocks: u64,
    /// STOP conditions made on the pins: one per recovery.
    pub pin_stops: u64,
}

/// One transfer as the master saw it, kept when the bus records ([`Bus::record`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Transfer {
    /// When it began.
    pub at: Instant,
    /// The 7-bit address.
    pub address: u8,
    /// The bytes written, or the bytes read.
    pub data: Data,
    /// Whether it went through.
    pub ok: bool,
}

/// The data of a [`Transfer`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Data {
    /// Written by the master, as it sent them.
    Write(Vec<u8>),
    /// Read by the master, as it received them.
    Read(Vec<u8>),
}

/// What the master asks of a [`Target`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request {
    /// The master writes.
    Write,
    /// The master reads.
    Read,
}

/// A [`Target`] was asked to answer a transfer that is not there (the master gave up on it, or it is the wrong
/// kind).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TargetError;

#[derive(Debug)]
enum Handoff {
    Write(Vec<u8>),
    Read,
}

#[derive(Debug)]
enum Answer {
    Written,
    Read(Vec<u8>),
    /// The transfer was torn: both ends saw a bus error.
    Torn,
    /// The port lost power: its pins let SCL and SDA go.
    Unpowered,
}

/// Where a firmware port's transfer stands.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
enum Stage {
    /// None under way: an answer now answers nothing.
    #[default]
    Idle,
    /// Addressed, SCL stretched until the firmware answers.
    Stretching,
    /// Answered: the bytes are moving.
    Moving,
}

/// The wires between the bus and one firmware slave port.
#[derive(Default)]
struct TargetLine {
    handoff: Signal<NoopRawMutex, Handoff>,
    answer: Signal<NoopRawMutex, Answer>,
    /// The master's word that the bytes have moved, or that the transfer ended without them.
    moved: Signal<NoopRawMutex, Result<(), TargetError>>,
    stage: Cell<Stage>,
    resets: Cell<u32>,
    /// The next transfer is torn by a glitch.
    disturbed: Cell<bool>,
}

impl TargetLine {
    /// Answer the transfer under way, unless a glitch tears it; true if its bytes are to move, false if the master
    /// had already given up on it.
    fn answer(&self, answer: Answer) -> Result<bool, TargetError> {
        if self.stage.get() != Stage::Stretching {
            return Ok(false);
        }
        self.stage.set(Stage::Moving);
        if self.disturbed.replace(false) {
            self.answer.signal(Answer::Torn);
            Err(TargetError)
        } else {
            self.answer.signal(answer);
            Ok(true)
        }
    }

    /// Answer, and wait until the bytes have moved.
    async fn answer_and_move(&self, answer: Answer) -> Result<(), TargetError> {
        if self.answer(answer)? {
            self.moved.wait().await
        } else {
            Ok(())
        }
    }

    /// The transfer is over: tell the firmware waiting for its bytes how it ended.
    fn end(&self, result: Result<(), TargetError>) {
        if self.stage.replace(Stage::Idle) == Stage::Moving {
            self.moved.signal(result);
        }
    }
}

/// A transfer to the firmware ports that acknowledged its address, from the address on: dropped before it ends (the
/// master's task stopped), it still ends for each, so no firmware waits for bytes that never come.
struct Addressed<'a> {
    lines: Vec<&'a TargetLine>,
    wire: &'a RefCell<Wire>,
}

impl Addressed<'_> {
    /// The transfer ended: whether each port's bytes all moved, in the order of `lines`.
    fn end(self, moved: impl IntoIterator<Item = bool>) {
        for (line, moved) in self.lines.iter().zip(moved) {
            line.end(if moved { Ok(()) } else { Err(TargetError) });
        }
    }
}

impl Drop for Addressed<'_> {
    fn drop(&mut self) {
        for line in &self.lines {
            line.end(Err(TargetError));
        }
        if let Ok(mut wire) = self.wire.try_borrow_mut() {
            wire.moving = None;
        }
    }
}

enum Endpoint {
    Device(Rc<RefCell<dyn Device>>),
    Target { address: u8, line: Rc<TargetLine> },
}

struct Slot {
    endpoint: Endpoint,
    route: Route,
    powered: bool,
    tamper: Tamper,
    /// A glitch at the next transfer that reaches it leaves it holding SDA low for this many SCL clocks.
    glitch: Option<u32>,
}

impl Slot {
    fn address(&self) -> u8 {
        match &self.endpoint {
            Endpoint::Device(device) => device.borrow().address(),
            Endpoint::Target { address, .. } => *address,
        }
    }
}

/// A slave that hears the master's transfer under way, and when it lost power, if it did during the transfer.
#[derive(Debug, Clone, Copy)]
struct Heard {
    slot: usize,
    cut: Option<Instant>,
}

/// The data bytes of a transfer moving between the master and firmware ports.
#[derive(Debug)]
struct Moving {
    slots: Vec<usize>,
    request: Request,
    since: Instant,
}

/// A TCA9548A: its address and its control register (one bit per channel).
#[derive(Debug, Clone, Copy)]
struct Mux {
    address: u8,
    control: u8,
}

struct Wire {
    timing: Timing,
    slots: Vec<Slot>,
    mux: Option<Mux>,
    /// SCL clocks a slave still needs before it releases SDA; None while SDA is free, `u32::MAX` never.
    sda_hold: Option<u32>,
    /// The master's pins: driving SCL low, driving SDA low.
    scl_low: bool,
    sda_low: bool,
    /// The slaves the master's transfer under way reached.
    busy_with: Vec<Heard>,
    /// The firmware ports whose data bytes are moving now, which way, and since when.
    moving: Option<Moving>,
    stats: Stats,
    log: Option<Vec<Transfer>>,
    /// The CPU the master runs on, when it can stall.
    master_cpu: Option<Cpu>,
}

impl Wire {
    fn reachable(&self, route: Route) -> bool {
        match route {
            Route::Direct => true,
            Route::Mux(channel) => self
                .mux
                .is_some_and(|mux| channel < 8 && mux.control & (1 << channel) != 0),
        }
    }

    /// When the slave at `slot` lost power during the transfer under way, if it did.
    fn cut_of(&self, slot: usize) -> Option<Instant> {
        self.busy_with
            .iter()
            .find(|heard| heard.slot == slot)
            .and_then(|heard| heard.cut)
    }

    fn sda_high(&self) -> bool {
        !self.sda_low && self.sda_hold.is_none()
    }

    /// Log the transfer, when recording (its bytes are copied only then).
    fn note(&mut self, address: u8, operation: &Operation<'_>, ok: bool) {
        if let Some(log) = self.log.as_mut() {
            let data = match operation {
                Operation::Write(bytes) => Data::Write(bytes.to_vec()),
                Operation::Read(buffer) => Data::Read(buffer.to_vec()),
            };
            log.push(Transfer {
                at: Instant::now(),
                address,
                data,
                ok,
            });
        }
    }
}

/// An I2C bus; clones are handles on the same bus.
#[derive(Clone)]
pub struct Bus(Rc<RefCell<Wire>>);

impl core::fmt::Debug for Bus {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Bus")
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

impl Bus {
    /// An idle bus with nothing on it.
    pub fn new(timing: Timing) -> Self {
        Self(Rc::new(RefCell::new(Wire {
            timing,
            slots: Vec::new(),
            mux: None,
            sda_hold: None,
            scl_low: false,
            sda_low: false,
            busy_with: Vec::new(),
            moving: None,
            stats: Stats::default(),
            log: None,
            master_cpu: None,
        })))
    }

    /// The master runs on `cpu`: a transfer its stall holds as long as the timeout or longer fails as a timeout.
    pub fn set_master_cpu(&self, cpu: &Cpu) {
        self.0.borrow_mut().master_cpu = Some(cpu.clone());
    }

    /// Its timing.
    pub fn timing(&self) -> Timing {
        self.0.borrow().timing
    }

    /// Fit a TCA9548A at `address`, all channels off.
    pub fn fit_mux(&self, address: u8) {
        self.0.borrow_mut().mux = Some(Mux { address, control: 0 });
    }

    /// The TCA9548A's control register, if one is fitted.
    pub fn mux_control(&self) -> Option<u8> {
        self.0.borrow().mux.map(|mux| mux.control)
    }

    /// Put a device on the bus.
    pub fn attach(&self, device: Rc<RefCell<dyn Device>>, route: Route) -> DeviceId {
        self.add(Endpoint::Device(device), route)
    }

    /// Put a firmware slave port at `address` on the bus; [`Bus::target`] hands out its port.
    pub fn attach_target(&self, address: u8, route: Route) -> DeviceId {
        self.add(
            Endpoint::Target {
                address,
                line: Rc::default(),
            },
            route,
        )
    }

    fn add(&self, endpoint: Endpoint, route: Route) -> DeviceId {
        let mut wire = self.0.borrow_mut();
        wire.slots.push(Slot {
            endpoint,
            route,
            powered: true,
            tamper: Tamper::NONE,
            glitch: None,
        });
        DeviceId(wire.slots.len() - 1)
    }

    /// The slave port of the firmware at `id`, fresh (a controller that boots starts with an idle peripheral);
    /// None if `id` is not a firmware port.
    pub fn target(&self, id: DeviceId) -> Option<Target> {
        let wire = self.0.borrow();
        match &wire.slots.get(id.0)?.endpoint {
            Endpoint::Target { line, .. } => {
                line.handoff.reset();
                line.moved.reset();
                Some(Target {
                    line: Rc::clone(line),
                    pending: None,
                })
            }
            Endpoint::Device(_) => None,
        }
    }

    /// How often the firmware at `id` re-initialised its slave port.
    pub fn target_resets(&self, id: DeviceId) -> u32 {
        match self.0.borrow().slots.get(id.0).map(|slot| &slot.endpoint) {
            Some(Endpoint::Target { line, .. }) => line.resets.get(),
            _ => 0,
        }
    }

    /// Tear the next transfer to the firmware at `id` with a glitch: its port reports an error, the master a bus
    /// error.
    pub fn disturb(&self, id: DeviceId) {
        if let Some(Endpoint::Target { line, .. }) = self.0.borrow().slots.get(id.0).map(|slot| &slot.endpoint) {
            line.disturbed.set(true);
        }
    }

    /// Power a device on or off: unpowered, it acknowledges nothing. A firmware port that loses power in the
    /// middle of a transfer tears it (see the module's documentation).
    pub fn set_powered(&self, id: DeviceId, powered: bool) {
        let mut wire = self.0.borrow_mut();
        let in_transfer = wire
            .busy_with
            .iter()
            .any(|heard| heard.slot == id.0 && heard.cut.is_none());
        let Some(slot) = wire.slots.get_mut(id.0) else {
            return;
        };
        let cut = slot.powered && !powered && in_transfer;
        slot.powered = powered;
        if cut {
            if let Endpoint::Target { line, .. } = &slot.endpoint {
                line.answer.signal(Answer::Unpowered);
            }
            let now = Instant::now();
            for heard in wire.busy_with.iter_mut().filter(|heard| heard.slot == id.0) {
                heard.cut = Some(now);
            }
        }
    }

    /// Corrupt what passes between the master and the device at `id` (or stop, with [`Tamper::NONE`]).
    pub fn tamper(&self, id: DeviceId, tamper: Tamper) {
        if let Some(slot) = self.0.borrow_mut().slots.get_mut(id.0) {
            slot.tamper = tamper;
        }
    }

    /// At the next transfer that reaches the device or firmware port at `id`, a glitch leaves it holding SDA low
    /// until it has seen `clocks` SCL clocks, as a device answering [`Reply::HoldSda`] does; the firmware never
    /// sees that transfer.
    pub fn hold_sda_at_next_transfer(&self, id: DeviceId, clocks: u32) {
        if let Some(slot) = self.0.borrow_mut().slots.get_mut(id.0) {
            slot.glitch = Some(clocks);
        }
    }

    /// A slave holds SDA low until it has seen `clocks` SCL clocks (`u32::MAX`: it never lets go; 0: it lets go).
    pub fn hold_sda(&self, clocks: u32) {
        self.0.borrow_mut().sda_hold = (clocks > 0).then_some(clocks);
    }

    /// Whether a slave holds SDA low.
    pub fn sda_held(&self) -> bool {
        self.0.borrow().sda_hold.is_some()
    }

    /// Keep a log of every transfer from now on (tests), or stop and drop it.
    pub fn record(&self, on: bool) {
        self.0.borrow_mut().log = on.then(Vec::new);
    }

    /// The transfers logged so far, taken out of the log.
    pub fn take_log(&self) -> Vec<Transfer> {
        self.0.borrow_mut().log.as_mut().map(mem::take).unwrap_or_default()
    }

    /// Whether the master's transfer under way is addressed to the device at `id`, alone or with others at its
    /// address (a fault that lands now lands mid-transfer).
    pub fn in_transfer_with(&self, id: DeviceId) -> bool {
        self.0.borrow().busy_with.iter().any(|heard| heard.slot == id.0)
    }

    /// Which way the data bytes of a transfer to the firmware port at `id` are moving now, if they are, and since
    /// when: it has acknowledged its address and answered (a power cut that lands now lands in the bytes).
    pub fn bytes_moving(&self, id: DeviceId) -> Option<(Request, Instant)> {
        self.0
            .borrow()
            .moving
            .as_ref()
            .and_then(|moving| moving.slots.contains(&id.0).then_some((moving.request, moving.since)))
    }

    /// What the bus counted so far.
    pub fn stats(&self) -> Stats {
        self.0.borrow().stats
    }

    /// The master's port: `embedded_hal_async::i2c::I2c`.
    pub fn master(&self) -> Master {
        Master(self.clone())
    }

    /// The master's SCL pin, as a GPIO for the bus recovery.
    pub fn scl(&self) -> Scl {
        Scl(self.clone())
    }

    /// The master's SDA pin, as a GPIO for the bus recovery.
    pub fn sda(&self) -> Sda {
        Sda(self.clone())
    }
}

/// The master's port on a [`Bus`].
#[derive(Debug, Clone)]
pub struct Master(Bus);

/// What one transfer does, decided at its start.
enum Plan {
    /// SDA is held low: no START.
    Stuck,
    /// Nobody acknowledges.
    Nack,
    /// Devices (or a glitch) answered at once, no firmware port beside them: their reply as the master meets it on
    /// the wires, and the bytes read (tampered).
    Device(Reply, Vec<u8>),
    /// The TCA9548A answered.
    Mux(Vec<u8>),
    /// Firmware must answer: the ports that hear it, and the devices that acknowledged beside them, if any.
    Targets(Vec<Hearer>, Option<DevicesBeside>),
}

/// A firmware port that hears a transfer: its place on the bus, its wires, and what corrupts its bytes.
struct Hearer {
    slot: usize,
    line: Rc<TargetLine>,
    tamper: Tamper,
}

/// The devices that acknowledged a transfer beside firmware ports: how long the slowest of them holds SCL after
/// the address, and the AND of the bytes they drive (a read's).
struct DevicesBeside {
    stretch: Duration,
    data: Vec<u8>,
}

impl DevicesBeside {
    /// What devices that replied `reply` with `data` add to a transfer to firmware ports; None if they did not
    /// acknowledge. A device holding SDA low is no part of it: it fails the transfer for everyone.
    fn from_reply(reply: Reply, data: Vec<u8>) -> Option<Self> {
        let stretch = match reply {
            Reply::Ack => Duration::from_ticks(0),
            Reply::Stretch(stretch) => stretch,
            Reply::Nack | Reply::HoldSda(_) => return None,
        };
        Some(Self { stretch, data })
    }
}

/// Two devices' replies to one transfer as the master meets them together on the wires: an ACK if either
/// acknowledges, SCL held as long as the longer stretch, the AND of the bytes they drive, and SDA held low as long as
/// the longer hold.
fn wired_and(first: (Reply, Vec<u8>), second: (Reply, Vec<u8>)) -> (Reply, Vec<u8>) {
    match (first, second) {
        ((Reply::HoldSda(one), _), (Reply::HoldSda(other), _)) => (Reply::HoldSda(one.max(other)), Vec::new()),
        ((Reply::HoldSda(clocks), _), _) | (_, (Reply::HoldSda(clocks), _)) => (Reply::HoldSda(clocks), Vec::new()),
        ((Reply::Nack, _), acknowledged) | (acknowledged, (Reply::Nack, _)) => acknowledged,
        ((Reply::Ack, one), (Reply::Ack, other)) => (Reply::Ack, and_bytes(&one, &other)),
        ((one_reply, one), (other_reply, other)) => {
            let stretch_of = |reply| match reply {
                Reply::Stretch(stretch) => stretch,
                _ => Duration::from_ticks(0),
            };
            let stretch = stretch_of(one_reply).max(stretch_of(other_reply));
            (Reply::Stretch(stretch), and_bytes(&one, &other))
        }
    }
}

/// What the master reads where two slaves drive `one` and `other` at once: a 0 from either wins. Where one has
/// stopped driving, the other's bytes come through.
fn and_bytes(one: &[u8], other: &[u8]) -> Vec<u8> {
    let length = one.len().max(other.len());
    let released = core::iter::repeat(&0xFF);
    one.iter()
        .chain(released.clone())
        .zip(other.iter().chain(released))
        .take(length)
        .map(|(one, other)| one & other)
        .collect()
}

/// Where a power cut at `cut` meets data that began to move at `from`, `bit` a bit time: the byte it lands in and
/// how many of that byte's 8 data bits had moved. A cut in a byte's ninth bit (its ACK) leaves that byte whole
/// and lands at the start of the next. None if the cut came before the data.
fn cut_into(from: Instant, cut: Instant, bit: Duration) -> Option<(usize, u32)> {
    let bits = cut.checked_duration_since(from)?.as_ticks() / bit.as_ticks().max(1);
    let (byte, into) = (bits / 9, bits % 9);
    let byte = usize::try_from(byte).unwrap_or(usize::MAX);
    Some(match into {
        8 => (byte.saturating_add(1), 0),
        into => (byte, u32::try_from(into).unwrap_or(0)),
    })
}

/// What a firmware port made of its part in a transfer, once SCL was let go.
enum Part {
    /// It answered: its bytes move (a read's, as it sent them).
    Moves(Option<Vec<u8>>),
    /// It lost power while it stretched SCL: it drives nothing and acknowledges nothing.
    Unpowered,
    /// A glitch tore it, or it answered the wrong kind of transfer: the bus fails for everyone.
    Broken,
}

impl Master {
    /// The stalls of the master's CPU so far, added up.
    fn stalled_total(&self) -> Option<Duration> {
        self.0.0.borrow().master_cpu.as_ref().map(Cpu::stalled_total)
    }

    /// Let the bus be busy for `bits` bit times (and `stretch` more).
    async fn charge(&self, bits: u64, stretch: Duration) {
        let bit = {
            let mut wire = self.0.0.borrow_mut();
            wire.stats.bits += bits;
            wire.timing.bit
        };
        let ticks = bit.as_ticks().saturating_mul(bits).saturating_add(stretch.as_ticks());
        Timer::after(Duration::from_ticks(ticks)).await;
    }

    /// Decide at the START what the transfer meets, handing a write to every device that hears it.
    fn plan(&self, address: u8, operation: &Operation<'_>) -> Plan {
        let mut wire = self.0.0.borrow_mut();
        wire.stats.transfers += 1;
        for heard in &mut wire.busy_with {
            heard.cut = None;
        }
        if wire.sda_hold.is_some() {
            return Plan::Stuck;
        }
        if let Some(mux) = wire.mux.as_mut()
            && mux.address == address
        {
            return Plan::Mux(match operation {
                Operation::Write(bytes) => {
                    if let Some(control) = bytes.last() {
                        mux.control = *control;
                    }
                    Vec::new()
                }
                Operation::Read(buffer) => vec![mux.control; buffer.len()],
            });
        }
        let hearing: Vec<usize> = (0..wire.slots.len())
            .filter(|&i| {
                wire.slots
                    .get(i)
                    .is_some_and(|slot| slot.powered && wire.reachable(slot.route) && slot.address() == address)
            })
            .collect();
        if hearing.len() > 1 {
            wire.stats.collisions += 1;
        }
        wire.busy_with = hearing.iter().map(|&slot| Heard { slot, cut: None }).collect();
        // A glitch at any slave that hears it holds SDA low for them all, until the longest hold is clocked out.
        let glitch = hearing
            .iter()
            .filter_map(|&i| wire.slots.get_mut(i)?.glitch.take())
            .max();
        if let Some(clocks) = glitch {
            return Plan::Device(Reply::HoldSda(clocks), Vec::new());
        }
        let mut devices: Option<(Reply, Vec<u8>)> = None;
        let mut targets = Vec::new();
        for &i in &hearing {
            let Some(slot) = wire.slots.get(i) else {
                continue;
            };
            match &slot.endpoint {
                Endpoint::Device(device) => {
                    let mut device = device.borrow_mut();
                    let (reply, mut data) = match operation {
                        Operation::Write(bytes) => {
                            let mut bytes = bytes.to_vec();
                            slot.tamper.write(&mut bytes);
                            (device.write(&bytes), Vec::new())
                        }
                        Operation::Read(buffer) => {
                            // A slave with nothing more to send leaves SDA high.
                            let mut data = vec![0xFF; buffer.len()];
                            (device.read(&mut data), data)
                        }
                    };
                    slot.tamper.read(&mut data);
                    devices = Some(match devices.take() {
                        None => (reply, data),
                        Some(others) => wired_and(others, (reply, data)),
                    });
                }
                Endpoint::Target { line, .. } => targets.push(Hearer {
                    slot: i,
                    line: Rc::clone(line),
                    tamper: slot.tamper,
                }),
            }
        }
        if targets.is_empty() {
            return devices.map_or(Plan::Nack, |(reply, data)| Plan::Device(reply, data));
        }
        match devices {
            // A device holding SDA low fails the transfer before any firmware sees it.
            Some((Reply::HoldSda(clocks), _)) => Plan::Device(Reply::HoldSda(clocks), Vec::new()),
            devices => Plan::Targets(
                targets,
                devices.and_then(|(reply, data)| DevicesBeside::from_reply(reply, data)),
            ),
        }
    }

    async fn transfer(&mut self, address: u8, operation: &mut Operation<'_>) -> Result<(), ErrorKind> {
        let started = Instant::now();
        let stalled_before = self.stalled_total();
        let data_bits = 9 * match operation {
            Operation::Write(bytes) => bytes.len() as u64,
            Operation::Read(buffer) => buffer.len() as u64,
        };
        let nack = Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address));
        let (result, read) = match self.plan(address, operation) {
            Plan::Stuck => {
                // The START cannot even be made.
                self.charge(1, Duration::from_ticks(0)).await;
                (Err(ErrorKind::Bus), None)
            }
            Plan::Nack | Plan::Device(Reply::Nack, _) => {
                self.charge(ADDRESS_BITS + STOP_BITS, Duration::from_ticks(0)).await;
                (nack, None)
            }
            Plan::Mux(data) => {
                self.charge(ADDRESS_BITS + data_bits, Duration::from_ticks(0)).await;
                (Ok(()), Some(data))
            }
            Plan::Device(Reply::Ack, data) => {
                self.charge(ADDRESS_BITS + data_bits, Duration::from_ticks(0)).await;
                (Ok(()), Some(data))
            }
            Plan::Device(Reply::HoldSda(clocks), _) => {
                self.0.hold_sda(clocks);
                self.charge(ADDRESS_BITS, Duration::from_ticks(0)).await;
                (Err(ErrorKind::Bus), None)
            }
            Plan::Device(Reply::Stretch(stretch), data) => {
                let timeout = self.0.timing().timeout;
                if stretch >= timeout {
                    self.charge(ADDRESS_BITS, timeout).await;
                    (Err(ErrorKind::Other), None)
                } else {
                    self.charge(ADDRESS_BITS + data_bits, stretch).await;
                    (Ok(()), Some(data))
                }
            }
            Plan::Targets(hearers, devices) => self.targets_transfer(&hearers, devices, operation).await,
        };
        // The master's CPU stalled meanwhile and held the transfer (SCL low, waiting on its interrupt) past the
        // timeout: the master's driver reports it timed out, whatever moved on the wires.
        let held = self.stalled_total() != stalled_before && Instant::now() - started >= self.0.timing().timeout;
        let (result, read) = match result {
            Ok(()) if held => {
                self.0.0.borrow_mut().stats.stalled += 1;
                (Err(ErrorKind::Other), None)
            }
            other => (other, read),
        };
        if let (Some(data), Operation::Read(buffer)) = (&read, &mut *operation) {
            for (slot, byte) in buffer.iter_mut().zip(data.iter().chain(core::iter::repeat(&0xFF))) {
                *slot = *byte;
            }
        }
        let mut wire = self.0.0.borrow_mut();
        wire.busy_with.clear();
        match result {
            Err(ErrorKind::NoAcknowledge(_)) => wire.stats.nacks += 1,
            Err(ErrorKind::Other) => wire.stats.timeouts += 1,
            Err(_) => wire.stats.bus_errors += 1,
            Ok(()) => {}
        }
        wire.note(address, operation, result.is_ok());
        result
    }

    /// Add `bits` bit times to the bus's count; the caller waits them out.
    fn count(&self, bits: u64) {
        self.0.0.borrow_mut().stats.bits += bits;
    }

    /// `bits` bit times after `from`.
    fn after_bits(&self, from: Instant, bits: u64) -> Instant {
        let bit = self.0.timing().bit;
        from + Duration::from_ticks(bit.as_ticks().saturating_mul(bits))
    }

    /// When the slave at `slot` lost power during the transfer under way, if it did.
    fn cut_of(&self, slot: usize) -> Option<Instant> {
        self.0.0.borrow().cut_of(slot)
    }

    /// The address byte, then hand the transfer to every firmware port that acknowledged it and wait, SCL
    /// stretched, until the last of them (and of the devices beside them) has answered; then move the bytes, and
    /// tell each port how its bytes fared. A power cut on the way tears a port's part where it lands; the master
    /// sees it only where no other slave drives the ACK.
    async fn targets_transfer(
        &self,
        hearers: &[Hearer],
        devices: Option<DevicesBeside>,
        operation: &Operation<'_>,
    ) -> (Result<(), ErrorKind>, Option<Vec<u8>>) {
        let data_nack = Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Data));
        // A peripheral matches its address once the byte is in, and acknowledges it unless it lost power first.
        self.charge(ADDRESS_BITS, Duration::from_ticks(0)).await;
        let addressed: Vec<&Hearer> = hearers
            .iter()
            .filter(|hearer| self.cut_of(hearer.slot).is_none())
            .collect();
        if addressed.is_empty() && devices.is_none() {
            self.charge(STOP_BITS, Duration::from_ticks(0)).await;
            return (Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)), None);
        }
        for hearer in &addressed {
            // An answer or a cut left over from a transfer the master gave up on is not this one's.
            hearer.line.answer.reset();
            hearer.line.moved.reset();
            hearer.line.stage.set(Stage::Stretching);
        }
        let guard = Addressed {
            lines: addressed.iter().map(|hearer| &*hearer.line).collect(),
            wire: &self.0.0,
        };
        let (request, length) = match operation {
            Operation::Write(bytes) => (Request::Write, bytes.len()),
            Operation::Read(buffer) => (Request::Read, buffer.len()),
        };
        for hearer in &addressed {
            hearer.line.handoff.signal(match operation {
                Operation::Write(bytes) => {
                    let mut bytes = bytes.to_vec();
                    hearer.tamper.write(&mut bytes);
                    Handoff::Write(bytes)
                }
                Operation::Read(_) => Handoff::Read,
            });
        }
        let data_bits = 9u64.saturating_mul(length as u64);
        // SCL stays low until the last slave lets it go; the master's patience runs from the address.
        let addressed_at = Instant::now();
        let timeout = self.0.timing().timeout;
        let deadline = addressed_at + timeout;
        let mut answers = Vec::with_capacity(addressed.len());
        for hearer in &addressed {
            match with_deadline(deadline, hearer.line.answer.wait()).await {
                // A slave never let SCL go: embassy-stm32 reports its timeout as `Other`.
                Err(_) => return (Err(ErrorKind::Other), None),
                Ok(answer) => answers.push(answer),
            }
        }
        if let Some(stretch) = devices
            .as_ref()
            .map(|devices| devices.stretch)
            .filter(|stretch| stretch.as_ticks() > 0)
        {
            if stretch >= timeout {
                Timer::at(deadline).await;
                return (Err(ErrorKind::Other), None);
            }
            Timer::at(addressed_at + stretch).await;
        }
        let from = Instant::now();
        let parts: Vec<Part> = answers
            .into_iter()
            .map(|answer| match (answer, request) {
                (Answer::Unpowered, _) => Part::Unpowered,
                (Answer::Written, Request::Write) => Part::Moves(None),
                (Answer::Read(data), Request::Read) => Part::Moves(Some(data)),
                _ => Part::Broken,
            })
            .collect();
        // One that lost power while it stretched SCL lets the lines go: the master clocks on against the others,
        // or the pull-ups. Its read is torn, and its write too unless it has no data byte to miss.
        let unpowered = parts.iter().filter(|part| matches!(part, Part::Unpowered)).count() as u64;
        if request == Request::Read || length > 0 {
            self.0.0.borrow_mut().stats.torn += unpowered;
        }
        if parts.iter().any(|part| matches!(part, Part::Broken)) {
            // A glitch, or an answer of the wrong kind.
            self.charge(data_bits, Duration::from_ticks(0)).await;
            return (Err(ErrorKind::Bus), None);
        }
        let movers: Vec<(&Hearer, Option<Vec<u8>>)> = addressed
            .iter()
            .zip(parts)
            .filter_map(|(hearer, part)| match part {
                Part::Moves(data) => Some((*hearer, data)),
                _ => None,
            })
            .collect();
        let devices_ack = devices.is_some();
        let devices_data = devices.map(|devices| devices.data);
        if movers.is_empty() {
            return match request {
                Request::Read => {
                    self.charge(data_bits, Duration::from_ticks(0)).await;
                    (Ok(()), Some(devices_data.unwrap_or_else(|| vec![0xFF; length])))
                }
                Request::Write if devices_ack => {
                    self.charge(data_bits, Duration::from_ticks(0)).await;
                    (Ok(()), None)
                }
                // The first data byte is not acknowledged.
                Request::Write if length > 0 => {
                    self.charge(9 + STOP_BITS, Duration::from_ticks(0)).await;
                    (data_nack, None)
                }
                Request::Write => (Ok(()), None),
            };
        }
        let slots: Vec<(usize, &TargetLine)> = movers.iter().map(|(hearer, _)| (hearer.slot, &*hearer.line)).collect();
        let tears = self.move_bytes(&slots, request, from, length, devices_ack).await;
        let intact: Vec<usize> = slots
            .iter()
            .zip(&tears)
            .filter(|(_, tear)| tear.is_none())
            .map(|((slot, _), _)| *slot)
            .collect();
        let outcome = match request {
            Request::Write => {
                // Each byte is acknowledged while any slave still acknowledges; the master stops at the first one
                // nobody does, and ends with a STOP.
                let acknowledged = tears
                    .iter()
                    .map(|tear| tear.map_or(length, |(byte, _)| byte))
                    .chain(devices_ack.then_some(length))
                    .max()
                    .unwrap_or(0);
                if acknowledged < length {
                    let bits = 9u64.saturating_mul((acknowledged as u64).saturating_add(1)) + STOP_BITS;
                    self.count(bits);
                    Timer::at(self.after_bits(from, bits)).await;
                    (data_nack, None)
                } else {
                    self.count(data_bits);
                    (Ok(()), None)
                }
            }
            Request::Read => {
                self.count(data_bits);
                let mut read = devices_data.unwrap_or_else(|| vec![0xFF; length]);
                for ((hearer, data), tear) in movers.into_iter().zip(tears) {
                    let mut data = data.unwrap_or_default();
                    hearer.tamper.read(&mut data);
                    data.resize(length, 0xFF);
                    if let Some((byte, into)) = tear {
                        // The bits the slave drove before the cut came through; the pull-ups give the rest.
                        let released = 0xFFu8.checked_shr(into).unwrap_or(0);
                        for (n, value) in data.iter_mut().enumerate().skip(byte) {
                            *value |= if n == byte { released } else { 0xFF };
                        }
                    }
                    read = and_bytes(&read, &data);
                }
                (Ok(()), Some(read))
            }
        };
        // A port's bytes all moved when the master's transfer went through and no cut tore its part.
        let ok = outcome.0.is_ok();
        guard.end(addressed.iter().map(|hearer| ok && intact.contains(&hearer.slot)));
        outcome
    }

    /// Let the `length` bytes of a transfer move from `from` between the master and the firmware ports `movers`
    /// (each its place on the bus and its wires), unless they lose power first; returns, for each, where its cut
    /// landed (the byte, and how many of its bits had moved), None if its bytes all moved. A write's master stops
    /// at the first byte nobody acknowledges (`devices_ack`: devices beside them acknowledge every byte): when every
    /// port tore, the caller waits that out.
    async fn move_bytes(
        &self,
        movers: &[(usize, &TargetLine)],
        request: Request,
        from: Instant,
        length: usize,
        devices_ack: bool,
    ) -> Vec<Option<(usize, u32)>> {
        self.0.0.borrow_mut().moving = Some(Moving {
            slots: movers.iter().map(|(slot, _)| *slot).collect(),
            request,
            since: from,
        });
        let end = self.after_bits(from, 9u64.saturating_mul(length as u64));
        // Only a power cut signals a line while the bytes move: wait for the end, or until every port is cut.
        let mut cuts: Vec<_> = movers.iter().map(|(_, line)| line.answer.wait()).collect();
        loop {
            let any_cut = core::future::poll_fn(|cx| {
                for cut in cuts.iter_mut() {
                    if let Poll::Ready(answer) = Pin::new(cut).poll(cx) {
                        return Poll::Ready(answer);
                    }
                }
                Poll::Pending
            });
            let ended = with_deadline(end, any_cut).await.is_err();
            if ended || movers.iter().all(|(slot, _)| self.cut_of(*slot).is_some()) {
                break;
            }
        }
        let bit = self.0.timing().bit;
        let tears: Vec<Option<(usize, u32)>> = movers
            .iter()
            .map(|(slot, _)| {
                // One cut before the bytes began (while another still stretched SCL) drove none of them.
                self.cut_of(*slot)
                    .map(|cut| cut_into(from, cut, bit).unwrap_or((0, 0)))
                    .filter(|(byte, _)| *byte < length)
            })
            .collect();
        self.0.0.borrow_mut().moving = None;
        self.0.0.borrow_mut().stats.torn += tears.iter().filter(|tear| tear.is_some()).count() as u64;
        // The master clocks a read to its end whatever drives SDA, and a write while anyone acknowledges.
        let write_stops = request == Request::Write && !devices_ack && tears.iter().all(Option::is_some);
        if !write_stops {
            Timer::at(end).await;
        }
        tears
    }
}

impl ErrorType for Master {
    type Error = ErrorKind;
}

impl I2c for Master {
    /// Each operation is one transfer (repeated START between them); the transaction ends with a STOP once they
    /// all went through. A failed transfer ends it.
    async fn transaction(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), ErrorKind> {
        for operation in operations.iter_mut() {
            self.transfer(address, operation).await?;
        }
        self.charge(STOP_BITS, Duration::from_ticks(0)).await;
        Ok(())
    }
}

/// The master's SCL line as an open-drain GPIO.
#[derive(Debug, Clone)]
pub struct Scl(Bus);

/// The master's SDA line as an open-drain GPIO: driven low or released, and read back.
#[derive(Debug, Clone)]
pub struct Sda(Bus);

impl digital::ErrorType for Scl {
    type Error = Infallible;
}

impl OutputPin for Scl {
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.0.0.borrow_mut().scl_low = true;
        Ok(())
    }

    /// Releasing SCL after driving it low is one clock: a slave holding SDA counts it.
    fn set_high(&mut self) -> Result<(), Infallible> {
        let mut wire = self.0.0.borrow_mut();
        if mem::replace(&mut wire.scl_low, false) {
            wire.stats.pin_clocks += 1;
            wire.stats.bits += 1;
            wire.sda_hold = match wire.sda_hold {
                Some(u32::MAX) => Some(u32::MAX),
                Some(clocks) if clocks > 1 => Some(clocks - 1),
                _ => None,
            };
        }
        Ok(())
    }
}

impl digital::ErrorType for Sda {
    type Error = Infallible;
}

impl OutputPin for Sda {
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.0.0.borrow_mut().sda_low = true;
        Ok(())
    }

    /// SDA rising while SCL is high is a STOP.
    fn set_high(&mut self) -> Result<(), Infallible> {
        let mut wire = self.0.0.borrow_mut();
        if mem::replace(&mut wire.sda_low, false) && !wire.scl_low && wire.sda_high() {
            wire.stats.pin_stops += 1;
            wire.stats.bits += STOP_BITS;
        }
        Ok(())
    }
}

impl InputPin for Sda {
    fn is_high(&mut self) -> Result<bool, Infallible> {
        Ok(self.0.0.borrow().sda_high())
    }

    fn is_low(&mut self) -> Result<bool, Infallible> {
        Ok(!self.0.0.borrow().sda_high())
    }
}

/// The slave port of firmware on a [`Bus`], shaped like embassy-stm32's I2C slave: wait to be addressed, then
/// answer the write or the read. A binding of the firmware's own slave trait forwards to these.
#[derive(Debug)]
pub struct Target {
    line: Rc<TargetLine>,
    pending: Option<Vec<u8>>,
}

impl core::fmt::Debug for TargetLine {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("TargetLine")
            .field("resets", &self.resets.get())
            .finish_non_exhaustive()
    }
}

impl Target {
    /// Wait until the master addresses this port.
    pub async fn listen(&mut self) -> Result<Request, TargetError> {
        Ok(match self.line.handoff.wait().await {
            Handoff::Write(bytes) => {
                self.pending = Some(bytes);
                Request::Write
            }
            Handoff::Read => Request::Read,
        })
    }

    /// Take the master's write into `buffer` once its bytes have moved; returns how many bytes were stored. Like
    /// the STM32, what does not fit is acknowledged and dropped.
    pub async fn respond_to_write(&mut self, buffer: &mut [u8]) -> Result<usize, TargetError> {
        let bytes = self.pending.take().ok_or(TargetError)?;
        self.line.answer_and_move(Answer::Written).await?;
        let stored = bytes.len().min(buffer.len());
        for (slot, byte) in buffer.iter_mut().zip(&bytes) {
            *slot = *byte;
        }
        Ok(stored)
    }

    /// Send `data` to the reading master; returns once the bytes have moved.
    pub async fn respond_to_read(&mut self, data: &[u8]) -> Result<(), TargetError> {
        self.line.answer_and_move(Answer::Read(data.to_vec())).await
    }

    /// Re-initialise the port: anything half-received is forgotten.
    pub fn reset(&mut self) {
        self.line.resets.set(self.line.resets.get().saturating_add(1));
        self.pending = None;
    }
}

#[cfg(test)]
mod tests;
