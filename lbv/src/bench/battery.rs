//! The battery pack's BAT board: voltage that sags with the thrusters' current, charge that falls with use, and
//! the real firmware's CAN timing (one frame every 100 ms, alternating 0x620 and 0x629; the BMS board's 0x628
//! once a second).

use core::cell::Cell;

use bat_proto::{BatteryInfo, BmsAlarms, DcdcStatus, Frame};
use embassy_time::{Duration, Instant};
use lbv_master_fw::ports::CanFrame;

/// The BAT firmware's frame period.
const FRAME_PERIOD: Duration = Duration::from_millis(100);
/// The BMS board's period (the seed gives none; once a second).
const BMS_PERIOD: Duration = Duration::from_secs(1);

/// A 7-cell lithium-ion pack (25.2 V nominal) and its boards.
#[derive(Debug, Clone)]
pub struct BatteryBoard {
    /// State of charge, 0..=1.
    pub charge: f64,
    /// Capacity, Ah.
    pub capacity_ah: f64,
    /// Internal resistance, ohm: the voltage sags by this much per ampere drawn.
    pub resistance_ohm: f64,
    /// The DCDC status word the board reports.
    pub status: DcdcStatus,
    /// The BMS alarms.
    pub alarms: BmsAlarms,
    /// False while the CAN frames are lost (a loose connector).
    pub sending: bool,
    /// Terminal voltage now, V.
    pub voltage: f64,
    /// Current drawn now, A.
    pub current: f64,
    next_frame: Instant,
    info_next: bool,
    next_bms: Instant,
}

impl Default for BatteryBoard {
    fn default() -> Self {
        Self {
            charge: 0.9,
            capacity_ah: 10.0,
            resistance_ohm: 0.08,
            // The seed's example word: hot swap manager on and power good, both 12 V regulators on.
            status: DcdcStatus::from_word(172),
            alarms: BmsAlarms::NONE,
            sending: true,
            voltage: 0.0,
            current: 0.0,
            next_frame: Instant::from_ticks(0),
            info_next: true,
            next_bms: Instant::from_ticks(0),
        }
    }
}

impl BatteryBoard {
    /// Open-circuit voltage of the pack at the present charge: 3.0 V to 4.2 V per cell, roughly linear.
    fn open_circuit(&self) -> f64 {
        7.0 * (3.0 + 1.2 * self.charge.clamp(0.0, 1.0))
    }

    /// Draw `current` (A, negative when the thrusters regenerate) for `dt` seconds.
    pub fn step(&mut self, dt: f64, current: f64) {
        self.current = current;
        self.charge = (self.charge - current * dt / 3600.0 / self.capacity_ah).clamp(0.0, 1.0);
        self.voltage = self.open_circuit() - self.resistance_ohm * current;
    }

    /// The event engine's update: the thrusters drew `drawn_as` ampere-seconds and the electronics their hotel load
    /// over the `seconds` since the last update; the terminal voltage follows the current drawn now. The rail
    /// takes the pack's new open-circuit voltage.
    pub fn settle(&mut self, seconds: f64, rail: &Rail) {
        let drawn_as = rail.drawn_as.replace(0.0) + rail.hotel_a * seconds;
        self.charge = (self.charge - drawn_as / 3600.0 / self.capacity_ah).clamp(0.0, 1.0);
        self.current = rail.current();
        self.voltage = self.open_circuit() - self.resistance_ohm * self.current;
        rail.open_circuit_v.set(self.open_circuit());
        rail.resistance_ohm.set(self.resistance_ohm);
    }

    /// When the next frame is due (the event engine wakes for it).
    pub fn next_frame(&self) -> Instant {
        self.next_frame.min(self.next_bms)
    }

    /// The frames due at `now`.
    pub fn frames(&mut self, now: Instant) -> Vec<CanFrame> {
        let mut frames = Vec::new();
        if now >= self.next_frame {
            self.next_frame = now + FRAME_PERIOD;
            let frame = if self.info_next {
                Frame::Info(BatteryInfo {
                    voltage_decivolts: (self.voltage * 10.0).round().clamp(0.0, f64::from(u16::MAX)) as u16,
                    charge_percent: Some((self.charge * 100.0).round() as u8),
                    current_deciamps: Some((self.current * 10.0).round() as i16).filter(|d| *d != 0),
                    temperature_decicelsius: Some(215),
                })
            } else {
                Frame::Status(self.status)
            };
            self.info_next = !self.info_next;
            frames.push(frame);
        }
        if now >= self.next_bms {
            self.next_bms = now + BMS_PERIOD;
            frames.push(Frame::Bms(self.alarms));
        }
        if !self.sending {
            return Vec::new();
        }
        frames
            .into_iter()
            .map(|frame| {
                let (id, data) = frame.encode();
                CanFrame { id, len: 8, data }
            })
            .collect()
    }
}

/// The pack's terminals as the thrusters' power stages see them on the event engine, where each thruster's plant
/// is advanced on its own: the open-circuit voltage and resistance as of the battery's last update, and the latest
/// current of every load, so each plant's supply sags with what all of them draw now.
#[derive(Debug)]
pub struct Rail {
    open_circuit_v: Cell<f64>,
    resistance_ohm: Cell<f64>,
    /// What the electronics draw besides the thrusters, A.
    hotel_a: f64,
    /// Each thruster's supply current as of its plant's latest sub-step, A.
    drawn_a: Vec<Cell<f64>>,
    /// Charge the thrusters drew since the battery's last update, A s.
    drawn_as: Cell<f64>,
}

impl Rail {
    /// The terminals of `battery` with `thrusters` power stages and `hotel_a` of other load on them.
    pub fn new(battery: &BatteryBoard, thrusters: usize, hotel_a: f64) -> Self {
        Self {
            open_circuit_v: Cell::new(battery.open_circuit()),
            resistance_ohm: Cell::new(battery.resistance_ohm),
            hotel_a,
            drawn_a: (0..thrusters).map(|_| Cell::new(0.0)).collect(),
            drawn_as: Cell::new(0.0),
        }
    }

    /// Current drawn from the pack now, A.
    pub fn current(&self) -> f64 {
        self.hotel_a + self.drawn_a.iter().map(Cell::get).sum::<f64>()
    }

    /// Terminal voltage now, V.
    pub fn voltage(&self) -> f64 {
        self.open_circuit_v.get() - self.resistance_ohm.get() * self.current()
    }

    /// Thruster `index` drew `current_a` for `seconds`.
    pub fn draw(&self, index: usize, current_a: f64, seconds: f64) {
        if let Some(drawn) = self.drawn_a.get(index) {
            drawn.set(current_a);
        }
        self.drawn_as.set(self.drawn_as.get() + current_a * seconds);
    }
}
