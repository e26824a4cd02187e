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
//! - Power ([`Bus::set_powered`]): an unpowered slave's pins let SCL and SDA go, to the pull-ups (UM10204 3.1.1).
//!   A firmware port that loses power in the middle of a transfer tears it: in its address byte, the address is
//!   not acknowledged; while it stretches SCL or while the bytes move, the master clocks on against released lines,
//!   so the rest of a read is 0xFF and a write's next byte is not acknowledged. A [`Device`] is not torn: its power
//!   counts from the next START.
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

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer, with_deadline, with_timeout};
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
    /// Transfers that two devices answered at once (their bytes would collide on SDA).
    pub collisions: u64,
    /// Transfers a firmware port's power cut tore after it had acknowledged its address: a read's bits from the cut
    /// on read 1, a write's next byte is not acknowledged.
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

/// A transfer to a firmware port from its address on: dropped before it ends (the master's task stopped), it
/// still ends, so the firmware does not wait for bytes that never come.
struct Addressed<'a> {
    line: &'a TargetLine,
    wire: &'a RefCell<Wire>,
}

impl Addressed<'_> {
    /// The transfer ended as the master saw it.
    fn end(self, ok: bool) {
        self.line.end(if ok { Ok(()) } else { Err(TargetError) });
    }
}

impl Drop for Addressed<'_> {
    fn drop(&mut self) {
        self.line.end(Err(TargetError));
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
    /// The device the master's transfer under way addressed.
    busy_with: Option<usize>,
    /// When that device lost power, if it did during the transfer.
    cut: Option<Instant>,
    /// The firmware port whose data bytes are moving now, which way, and since when.
    moving: Option<(usize, Request, Instant)>,
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
            busy_with: None,
            cut: None,
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
        let in_transfer = wire.busy_with == Some(id.0) && wire.cut.is_none();
        let Some(slot) = wire.slots.get_mut(id.0) else {
            return;
        };
        let cut = slot.powered && !powered && in_transfer;
        slot.powered = powered;
        if cut {
            if let Endpoint::Target { line, .. } = &slot.endpoint {
                line.answer.signal(Answer::Unpowered);
            }
            wire.cut = Some(Instant::now());
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

    /// Whether the master's transfer under way is addressed to the device at `id` (a fault that lands now lands
    /// mid-transfer).
    pub fn in_transfer_with(&self, id: DeviceId) -> bool {
        self.0.borrow().busy_with == Some(id.0)
    }

    /// Which way the data bytes of a transfer to the firmware port at `id` are moving now, if they are, and since
    /// when: it has acknowledged its address and answered (a power cut that lands now lands in the bytes).
    pub fn bytes_moving(&self, id: DeviceId) -> Option<(Request, Instant)> {
        self.0
            .borrow()
            .moving
            .and_then(|(slot, request, since)| (slot == id.0).then_some((request, since)))
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
    /// A device (or a glitch) answered at once: the reply, and the bytes read (tampered).
    Device(Reply, Vec<u8>),
    /// The TCA9548A answered.
    Mux(Vec<u8>),
    /// Firmware must answer.
    Target(Rc<TargetLine>, Tamper),
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
        wire.cut = None;
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
        wire.busy_with = hearing.first().copied();
        let glitch = hearing.first().and_then(|&i| wire.slots.get_mut(i)?.glitch.take());
        if let Some(clocks) = glitch {
            return Plan::Device(Reply::HoldSda(clocks), Vec::new());
        }
        let mut plan = Plan::Nack;
        for (n, slot) in hearing.iter().filter_map(|&i| wire.slots.get(i)).enumerate() {
            let first = n == 0;
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
                    if first {
                        plan = Plan::Device(reply, data);
                    }
                }
                Endpoint::Target { line, .. } if first => plan = Plan::Target(Rc::clone(line), slot.tamper),
                Endpoint::Target { .. } => {}
            }
        }
        plan
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
            Plan::Target(line, tamper) => self.target_transfer(&line, tamper, operation).await,
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
        wire.busy_with = None;
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

    /// When the slave of the transfer under way lost power, if it did.
    fn cut(&self) -> Option<Instant> {
        self.0.0.borrow().cut
    }

    /// The address byte, then hand the transfer to firmware and wait, SCL stretched, for its answer; then move the
    /// bytes, and tell the firmware they moved. A power cut on the way tears the transfer where it lands.
    async fn target_transfer(
        &self,
        line: &TargetLine,
        tamper: Tamper,
        operation: &Operation<'_>,
    ) -> (Result<(), ErrorKind>, Option<Vec<u8>>) {
        let data_nack = Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Data));
        // The peripheral matches its address once the byte is in, and acknowledges it unless it lost power first.
        self.charge(ADDRESS_BITS, Duration::from_ticks(0)).await;
        if self.cut().is_some() {
            self.charge(STOP_BITS, Duration::from_ticks(0)).await;
            return (Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)), None);
        }
        // An answer or a cut left over from a transfer the master gave up on is not this one's.
        line.answer.reset();
        line.moved.reset();
        line.stage.set(Stage::Stretching);
        let addressed = Addressed { line, wire: &self.0.0 };
        let (request, length) = match operation {
            Operation::Write(bytes) => {
                let mut bytes = bytes.to_vec();
                tamper.write(&mut bytes);
                let length = bytes.len();
                line.handoff.signal(Handoff::Write(bytes));
                (Request::Write, length)
            }
            Operation::Read(buffer) => {
                line.handoff.signal(Handoff::Read);
                (Request::Read, buffer.len())
            }
        };
        let data_bits = 9u64.saturating_mul(length as u64);
        let answer = match with_timeout(self.0.timing().timeout, line.answer.wait()).await {
            // The slave never let SCL go: embassy-stm32 reports its timeout as `Other`.
            Err(_) => return (Err(ErrorKind::Other), None),
            Ok(answer) => answer,
        };
        let from = Instant::now();
        let moved = match (answer, request) {
            // It lost power while it stretched SCL: the lines are released and the master clocks on. A read gets the
            // pull-ups' 0xFF; a write's first data byte is not acknowledged.
            (Answer::Unpowered, Request::Read) => {
                self.0.0.borrow_mut().stats.torn += 1;
                self.charge(data_bits, Duration::from_ticks(0)).await;
                (Ok(()), Some(vec![0xFF; length]))
            }
            (Answer::Unpowered, Request::Write) if length > 0 => {
                self.0.0.borrow_mut().stats.torn += 1;
                self.charge(9 + STOP_BITS, Duration::from_ticks(0)).await;
                (data_nack, None)
            }
            (Answer::Unpowered, Request::Write) => (Ok(()), None),
            (Answer::Written, Request::Write) => {
                let torn = self.move_bytes(line, request, from, length).await;
                match torn {
                    Some((byte, _)) => {
                        // The master stops at the byte not acknowledged, and ends with a STOP.
                        let bits = 9u64.saturating_mul((byte as u64).saturating_add(1)) + STOP_BITS;
                        self.count(bits);
                        Timer::at(self.after_bits(from, bits)).await;
                        (data_nack, None)
                    }
                    None => {
                        self.count(data_bits);
                        (Ok(()), None)
                    }
                }
            }
            (Answer::Read(mut data), Request::Read) => {
                let torn = self.move_bytes(line, request, from, length).await;
                self.count(data_bits);
                tamper.read(&mut data);
                data.resize(length, 0xFF);
                if let Some((byte, into)) = torn {
                    // The bits the slave drove before the cut came through; the pull-ups give the rest.
                    let released = 0xFFu8.checked_shr(into).unwrap_or(0);
                    for (n, value) in data.iter_mut().enumerate().skip(byte) {
                        *value |= if n == byte { released } else { 0xFF };
                    }
                }
                (Ok(()), Some(data))
            }
            // A glitch, or an answer of the wrong kind.
            _ => {
                self.charge(data_bits, Duration::from_ticks(0)).await;
                (Err(ErrorKind::Bus), None)
            }
        };
        addressed.end(moved.0.is_ok());
        moved
    }

    /// Let the `length` bytes of a transfer move from `from`, unless the port loses power first; returns where the
    /// cut landed (the byte, and how many of its bits had moved), None if the bytes all moved. A torn write's
    /// master stops at the byte not acknowledged: the caller waits that out.
    async fn move_bytes(
        &self,
        line: &TargetLine,
        request: Request,
        from: Instant,
        length: usize,
    ) -> Option<(usize, u32)> {
        let slot = self.0.0.borrow().busy_with;
        self.0.0.borrow_mut().moving = slot.map(|slot| (slot, request, from));
        let end = self.after_bits(from, 9u64.saturating_mul(length as u64));
        // Only a power cut signals the line while the bytes move.
        let _ = with_deadline(end, line.answer.wait()).await;
        let torn = self
            .cut()
            .and_then(|cut| cut_into(from, cut, self.0.timing().bit))
            .filter(|(byte, _)| *byte < length);
        self.0.0.borrow_mut().moving = None;
        if torn.is_some() {
            self.0.0.borrow_mut().stats.torn += 1;
        }
        // The master clocks a read to its end whatever drives SDA.
        if torn.is_none() || request == Request::Read {
            Timer::at(end).await;
        }
        torn
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
