//! The thruster buses inside the chip: lbv-sim's bus model, the bench's own (the bit times at the configured
//! speed spent on the clock, a TCA9548A, NACKs from absent or unpowered thrusters, clock stretching, a slave that
//! holds SDA low until clocked free, the lines as open-drain pins), with each thruster's target port on it and a
//! power cut during a transfer.
//!
//! A transfer hands the master's bytes to the addressed thruster's I2C task and waits, as a clock-stretching
//! slave makes the master wait, until that task answers or the bus timeout passes. The master's recovery is the
//! core's own (`lbv_master_fw::recovery::PinRecovery`) on the model's lines. On the G431 the model's work is the
//! I2C peripheral's, so it is metered apart ([`BUS_MODEL_METER`]), as the motor model's is.

use core::cell::Cell;

use embassy_time::Delay;
use embedded_hal_async::i2c::{ErrorKind, ErrorType, I2c, Operation};
use lbv_master_fw::recovery::BusConfig;
use lbv_master_fw::recovery::PinRecovery;
use lbv_master_fw::thrusters::MUX_ADDRESS;
use lbv_sim::i2c::{DeviceId, Route, Scl, Sda, Stats, Target, TargetError, Timing};
use thruster_fw::ports::{I2cTarget, Request};

use crate::meter::{self, Meter, Progress, metered};
use crate::thruster::Thruster;

/// Most thrusters on one bus.
pub const MAX_THRUSTERS: usize = 6;

/// The bus model's work inside the cores' polls: the master's transfers and the thrusters' answers.
pub static BUS_MODEL_METER: Meter = Meter::nested("I2C bus model (ports)");

/// A bus: the model, and its thrusters with their places on it.
pub struct Bus {
    model: lbv_sim::i2c::Bus,
    thrusters: heapless::Vec<&'static Thruster, MAX_THRUSTERS>,
    /// Each thruster's place on the model, in the same order.
    ids: heapless::Vec<DeviceId, MAX_THRUSTERS>,
    config: BusConfig,
    /// The thruster whose power the operator cuts when it is next addressed.
    power_cut_armed: Cell<Option<DeviceId>>,
}

impl Bus {
    /// A bus at `config`'s speed and timeout with `thrusters` on it, each on its TCA9548A channel when
    /// `mux_fitted`. Each answers once its controller has its port ([`Bus::target`]).
    pub fn new(config: BusConfig, thrusters: &[&'static Thruster], mux_fitted: bool) -> Self {
        let model = lbv_sim::i2c::Bus::new(Timing::new(config.frequency_hz, config.timeout));
        if mux_fitted {
            model.fit_mux(MUX_ADDRESS);
        }
        let (mut list, mut ids) = (heapless::Vec::new(), heapless::Vec::new());
        for thruster in thrusters.iter().take(MAX_THRUSTERS) {
            let route = thruster.mux_channel.map_or(Route::Direct, Route::Mux);
            let id = model.attach_target(thruster.config.family.address(), route);
            // Unpowered until its controller boots.
            model.set_powered(id, false);
            let _ = list.push(*thruster);
            let _ = ids.push(id);
        }
        Self {
            model,
            thrusters: list,
            ids,
            config,
            power_cut_armed: Cell::new(None),
        }
    }

    /// The master's port: transfers on this bus, the core's recovery on its lines.
    pub fn master(&self) -> MasterPort {
        PinRecovery {
            i2c: ControllerPort(self.model.master()),
            scl: self.model.scl(),
            sda: self.model.sda(),
            delay: Delay,
            bus: self.config,
        }
    }

    /// `thruster`'s target port, fresh (a controller that boots starts with an idle peripheral): from now on its
    /// address answers. None if it is not on this bus.
    pub fn target(&'static self, thruster: &'static Thruster) -> Option<TargetPort> {
        let id = self.id_of(thruster)?;
        let port = self.model.target(id)?;
        self.model.set_powered(id, true);
        Some(TargetPort {
            port,
            bus: self,
            thruster,
            id,
        })
    }

    /// The operator will cut `thruster`'s power: it lands in the next transfer to it.
    pub fn cut_power_during_next_transfer(&self, thruster: &Thruster) {
        self.power_cut_armed.set(self.id_of(thruster));
    }

    /// A glitch will leave `thruster` holding SDA low for `clocks` SCL clocks at the next transfer to it.
    pub fn glitch_during_next_transfer(&self, thruster: &Thruster, clocks: u32) {
        if let Some(id) = self.id_of(thruster) {
            self.model.hold_sda_at_next_transfer(id, clocks);
        }
    }

    /// Whether a slave still holds SDA low.
    pub fn sda_held(&self) -> bool {
        self.model.sda_held()
    }

    /// The thrusters on it.
    pub fn thrusters(&self) -> &[&'static Thruster] {
        &self.thrusters
    }

    /// What it counted.
    pub fn counts(&self) -> Stats {
        self.model.stats()
    }

    fn id_of(&self, thruster: &Thruster) -> Option<DeviceId> {
        let index = self.thrusters.iter().position(|t| core::ptr::eq(*t, thruster))?;
        self.ids.get(index).copied()
    }
}

/// The master's port on a bus: the controller and the core's recovery on the lines.
pub type MasterPort = PinRecovery<ControllerPort, Scl, Sda, Delay>;

/// The master's I2C controller on a bus. Each transaction is progress of the master's bus work
/// ([`Progress::MASTER_BUS`]).
pub struct ControllerPort(lbv_sim::i2c::Master);

impl ErrorType for ControllerPort {
    type Error = ErrorKind;
}

impl I2c for ControllerPort {
    async fn transaction(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), ErrorKind> {
        meter::progressed(Progress::MASTER_BUS);
        metered(&BUS_MODEL_METER, None, self.0.transaction(address, operations)).await
    }
}

/// The target port a thruster's I2C task serves. Every wait for an address it begins, and every answer, is
/// progress of that task ([`Progress::THRUSTER_I2C`]).
pub struct TargetPort {
    port: Target,
    bus: &'static Bus,
    thruster: &'static Thruster,
    id: DeviceId,
}

impl I2cTarget for TargetPort {
    type Error = TargetError;

    async fn listen(&mut self) -> Result<Request, TargetError> {
        meter::progressed(Progress::THRUSTER_I2C);
        // Every poll of the thruster's tasks polls this wait: a signal, as a driver's would be, so it is the
        // task's own, not the model's.
        let request = self.port.listen().await?;
        meter::progressed(Progress::THRUSTER_I2C);
        if self.bus.power_cut_armed.get() == Some(self.id) {
            // The address was acknowledged, then the board lost its power: nobody finishes the transfer, and
            // the controller's tasks are dropped.
            self.bus.power_cut_armed.set(None);
            self.bus.model.set_powered(self.id, false);
            self.thruster.cut_power();
            core::future::pending::<()>().await;
        }
        Ok(match request {
            lbv_sim::i2c::Request::Write => Request::Write,
            lbv_sim::i2c::Request::Read => Request::Read,
        })
    }

    async fn respond_to_write(&mut self, buffer: &mut [u8]) -> Result<usize, TargetError> {
        metered(&BUS_MODEL_METER, None, self.port.respond_to_write(buffer)).await
    }

    async fn respond_to_read(&mut self, data: &[u8]) -> Result<(), TargetError> {
        metered(&BUS_MODEL_METER, None, self.port.respond_to_read(data)).await
    }

    fn reset(&mut self) {
        self.port.reset();
    }
}
