//! What goes wrong on the bench: one [`Fault`] type, injected and cleared the same way by the scenarios, the soak
//! (which draws from every kind) and the acceptance test's operator.

use bat_proto::StatusBit;
use lbv_sim::i2c::Tamper;
use thruster_fw::hall::HallState;

use crate::bench::Bench;
use crate::bench::plant::{DEFAULT_AMBIENT_C, DRY_WATER_OHMS};

/// Water between the sensor electrodes: below the 1 Mohm water threshold, above the 100 kohm ground fault.
pub const WATER_OHMS: u32 = 500_000;
/// A ground fault: below 100 kohm.
pub const GROUND_FAULT_OHMS: u32 = 50_000;

/// Something that goes wrong, and stops going wrong when cleared. Thrusters are named by their index.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Fault {
    /// Water in the housing: `ohms` between the sensor electrodes ([`WATER_OHMS`], or [`GROUND_FAULT_OHMS`] for a
    /// ground fault). Cleared: dry.
    Water { thruster: usize, ohms: u32 },
    /// The winding's surroundings at `celsius` (it heats with its thermal time constant). Cleared: back to the
    /// water's temperature.
    Heat { thruster: usize, celsius: f64 },
    /// A rope in the propeller: the rotor cannot turn.
    BlockedPropeller { thruster: usize },
    /// The hall sensors unplugged: they read 000.
    HallsUnplugged { thruster: usize },
    /// A phase shorted (water in it, a failed MOSFET): the power stage's overcurrent comparator trips the break
    /// in every PWM period the bridge switches, and the motor gets no drive. Not in the soak's deck: its reaction
    /// is the `overcurrent-*` scenarios'.
    PhaseShort { thruster: usize },
    /// A shorted MOSFET: it shoots through in the two sectors of six where its partner switches, so the
    /// comparator trips on one fault-task sample in three while the bridge drives. Not in the soak's deck: its
    /// reaction is the `overcurrent-intermittent` scenario's.
    IntermittentShort { thruster: usize },
    /// One comparator trip (a switching spike), seen by the next fault-task sample. Clearing it does nothing.
    BreakSpike { thruster: usize },
    /// A noisy line: `mask` flipped in every status byte the thruster sends.
    NoisyStatus { thruster: usize, mask: u8 },
    /// The thruster lays its status out in the implied-type form, as some SeaBotix controllers do: MT taken as the
    /// read address byte, the frame starting at STATUS, the line idle (0xFF) after it.
    ImpliedTypeStatus { thruster: usize },
    /// Orders arrive with `mask` flipped in their checksum byte.
    CorruptOrders { thruster: usize, mask: u8 },
    /// Orders arrive with SPEED 0x00 (out of range) and a checksum that matches.
    OutOfRangeOrders { thruster: usize },
    /// Orders arrive as full ahead (SPEED 0xE6) with INFO `info` (50: a power limit of 50 %; anything else 100)
    /// and a checksum that matches.
    FullOrder { thruster: usize, info: u8 },
    /// The thruster loses power: its controller stops wherever it was, mid-transfer or not. Cleared: power comes
    /// back and it boots.
    PowerCut { thruster: usize },
    /// A slave holds SDA low until it has seen `clocks` SCL clocks (the master's recovery gives up to 9, and a
    /// tenth with its STOP). Cleared: it lets go, if the master has not freed it already.
    SdaHeld { clocks: u32 },
    /// The console link drops.
    ConsoleSilence,
    /// The BAT board's frames stop reaching the CAN bus.
    BatteryFramesLost,
    /// A BAT status bit reads 1. Cleared: it reads 0.
    BatteryBit(StatusBit),
}

/// A status read in the implied-type form: the bytes from STATUS on, then 0xFF.
fn implied_type(bytes: &mut [u8]) {
    if let Some(last) = bytes.len().checked_sub(1) {
        bytes.rotate_left(1);
        bytes[last] = 0xFF;
    }
}

/// Orders arrive with SPEED 0x00 and a checksum that matches, so only the range check can catch them.
fn out_of_range(bytes: &mut [u8]) {
    if let [mt, speed, info, sum] = bytes {
        *speed = 0x00;
        *sum = tmc_proto::checksum(&[*mt, *speed, *info]);
    }
}

/// Orders rewritten to full ahead with INFO `info` and a checksum that matches.
fn full_order(bytes: &mut [u8], info_byte: u8) {
    if let [mt, speed, info, sum] = bytes {
        *speed = tmc_proto::Speed::MAX_FORWARD.to_byte();
        *info = info_byte;
        *sum = tmc_proto::checksum(&[*mt, *speed, *info]);
    }
}

fn full_order_info_10(bytes: &mut [u8]) {
    full_order(bytes, 10);
}

fn full_order_info_25(bytes: &mut [u8]) {
    full_order(bytes, 25);
}

fn full_order_info_50(bytes: &mut [u8]) {
    full_order(bytes, 50);
}

fn full_order_info_100(bytes: &mut [u8]) {
    full_order(bytes, tmc_proto::Order::INFO_NO_CAP);
}

impl Fault {
    /// Every kind of fault, each once, with `thruster` where a thruster is named: what the soak draws from.
    pub const fn every_kind(thruster: usize) -> [Fault; 14] {
        [
            Fault::Water {
                thruster,
                ohms: WATER_OHMS,
            },
            Fault::Water {
                thruster,
                ohms: GROUND_FAULT_OHMS,
            },
            Fault::Heat {
                thruster,
                celsius: 150.0,
            },
            Fault::BlockedPropeller { thruster },
            Fault::HallsUnplugged { thruster },
            Fault::NoisyStatus { thruster, mask: 0x10 },
            Fault::CorruptOrders { thruster, mask: 0x55 },
            Fault::OutOfRangeOrders { thruster },
            Fault::PowerCut { thruster },
            Fault::SdaHeld { clocks: 5 },
            Fault::SdaHeld { clocks: 12 },
            Fault::ConsoleSilence,
            Fault::BatteryFramesLost,
            Fault::BatteryBit(StatusBit::HsmSwFault),
        ]
    }

    /// Its kind's name (the soak counts them).
    pub fn kind(&self) -> &'static str {
        match self {
            Fault::Water { ohms, .. } if *ohms < 100_000 => "ground-fault",
            Fault::Water { .. } => "water",
            Fault::Heat { .. } => "heat",
            Fault::BlockedPropeller { .. } => "blocked-propeller",
            Fault::HallsUnplugged { .. } => "halls-unplugged",
            Fault::PhaseShort { .. } => "phase-short",
            Fault::IntermittentShort { .. } => "intermittent-short",
            Fault::BreakSpike { .. } => "break-spike",
            Fault::NoisyStatus { .. } => "noisy-status",
            Fault::ImpliedTypeStatus { .. } => "implied-type-status",
            Fault::CorruptOrders { .. } => "corrupt-orders",
            Fault::OutOfRangeOrders { .. } => "out-of-range-orders",
            Fault::FullOrder { .. } => "full-order",
            Fault::PowerCut { .. } => "power-cut",
            Fault::SdaHeld { clocks } if *clocks > 10 => "sda-held-long",
            Fault::SdaHeld { .. } => "sda-held",
            Fault::ConsoleSilence => "console-silence",
            Fault::BatteryFramesLost => "battery-frames-lost",
            Fault::BatteryBit(_) => "battery-bit",
        }
    }

    /// In words, for the trace.
    pub fn describe(&self) -> String {
        match self {
            Fault::Water { thruster, ohms } => {
                format!("T{}: {} kohm between the water electrodes", thruster + 1, ohms / 1000)
            }
            Fault::Heat { thruster, celsius } => format!("T{}: surroundings at {celsius:.0} C", thruster + 1),
            Fault::BlockedPropeller { thruster } => format!("T{}: propeller blocked", thruster + 1),
            Fault::HallsUnplugged { thruster } => format!("T{}: halls unplugged", thruster + 1),
            Fault::PhaseShort { thruster } => format!("T{}: a phase shorted", thruster + 1),
            Fault::IntermittentShort { thruster } => format!("T{}: a MOSFET shorted", thruster + 1),
            Fault::BreakSpike { thruster } => format!("T{}: one comparator trip", thruster + 1),
            Fault::NoisyStatus { thruster, mask } => format!("T{}: status bytes corrupted ({mask:#04x})", thruster + 1),
            Fault::ImpliedTypeStatus { thruster } => format!("T{}: status in the 6-byte form", thruster + 1),
            Fault::CorruptOrders { thruster, mask } => format!("T{}: orders corrupted ({mask:#04x})", thruster + 1),
            Fault::OutOfRangeOrders { thruster } => format!("T{}: orders out of range", thruster + 1),
            Fault::FullOrder { thruster, info } => format!("T{}: orders full ahead with INFO {info}", thruster + 1),
            Fault::PowerCut { thruster } => format!("T{}: power cut", thruster + 1),
            Fault::SdaHeld { clocks } => format!("SDA held low for {clocks} clocks"),
            Fault::ConsoleSilence => "console link lost".into(),
            Fault::BatteryFramesLost => "BAT frames lost".into(),
            Fault::BatteryBit(bit) => format!("BAT: {} set", bit.name()),
        }
    }

    /// Make it happen now.
    pub fn inject(&self, bench: &mut Bench) {
        bench.note(self.describe());
        self.apply(bench, true);
    }

    /// Make it stop now (what a latching fault latched stays latched).
    pub fn clear(&self, bench: &mut Bench) {
        bench.note(format!("cleared: {}", self.describe()));
        self.apply(bench, false);
    }

    fn apply(&self, bench: &mut Bench, on: bool) {
        let tamper = |bench: &Bench, thruster: usize, tamper: Tamper| {
            if let Some(board) = bench.thrusters.get(thruster) {
                bench
                    .thruster_bus()
                    .tamper(board.device, if on { tamper } else { Tamper::NONE });
            }
        };
        let plant = |bench: &Bench, thruster: usize, change: &dyn Fn(&mut crate::bench::plant::Plant)| {
            if let Some(board) = bench.thrusters.get(thruster) {
                change(&mut board.plant.borrow_mut());
            }
        };
        match *self {
            Fault::Water { thruster, ohms } => plant(bench, thruster, &|plant| {
                plant.water_ohms = if on { ohms } else { DRY_WATER_OHMS }
            }),
            Fault::Heat { thruster, celsius } => plant(bench, thruster, &|plant| {
                plant.ambient_c = if on { celsius } else { DEFAULT_AMBIENT_C }
            }),
            Fault::BlockedPropeller { thruster } => plant(bench, thruster, &|plant| plant.blocked = on),
            Fault::HallsUnplugged { thruster } => plant(bench, thruster, &|plant| {
                plant.hall_fault = on.then(|| HallState::from_bits(0))
            }),
            Fault::PhaseShort { thruster } => {
                if let Some(board) = bench.thrusters.get(thruster) {
                    board.shorted.set(on);
                    board.disturbed();
                }
            }
            Fault::IntermittentShort { thruster } => {
                if let Some(board) = bench.thrusters.get(thruster) {
                    board.intermittent.set(on);
                }
            }
            Fault::BreakSpike { thruster } => {
                if let Some(board) = bench.thrusters.get(thruster).filter(|_| on) {
                    board.spike();
                }
            }
            Fault::NoisyStatus { thruster, mask } => tamper(
                bench,
                thruster,
                Tamper {
                    read_xor: mask,
                    ..Tamper::NONE
                },
            ),
            Fault::ImpliedTypeStatus { thruster } => tamper(
                bench,
                thruster,
                Tamper {
                    rewrite_read: Some(implied_type),
                    ..Tamper::NONE
                },
            ),
            Fault::CorruptOrders { thruster, mask } => tamper(
                bench,
                thruster,
                Tamper {
                    write_last_xor: mask,
                    ..Tamper::NONE
                },
            ),
            Fault::OutOfRangeOrders { thruster } => tamper(
                bench,
                thruster,
                Tamper {
                    rewrite: Some(out_of_range),
                    ..Tamper::NONE
                },
            ),
            Fault::FullOrder { thruster, info } => tamper(
                bench,
                thruster,
                Tamper {
                    // A rewrite is a plain function: one per INFO the scenarios use.
                    rewrite: Some(match info {
                        10 => full_order_info_10,
                        25 => full_order_info_25,
                        50 => full_order_info_50,
                        _ => {
                            debug_assert_eq!(info, tmc_proto::Order::INFO_NO_CAP, "no rewrite for INFO {info}");
                            full_order_info_100
                        }
                    }),
                    ..Tamper::NONE
                },
            ),
            Fault::PowerCut { thruster } => bench.power(thruster, !on),
            Fault::SdaHeld { clocks } => bench.thruster_bus().hold_sda(if on { clocks } else { 0 }),
            Fault::ConsoleSilence => bench.ground.connected = !on,
            Fault::BatteryFramesLost => bench.battery.sending = !on,
            Fault::BatteryBit(bit) => bench.battery.status = bench.battery.status.with(bit, on),
        }
    }
}
