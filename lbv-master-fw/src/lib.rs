//! The LBV master node's hardware-free core.
//!
//! Everything here runs unchanged on the STM32 (through the binding in `main.rs`) and on the host, where tests
//! and the bench drive it through simulated ports. It never touches a register and never panics on bus input.
//!
//! [`run`] is the whole node: the STM32 binding builds its [`Ports`] from peripherals and calls it with [`CONFIG`];
//! the bench and the tests call it with simulated ports.
#![cfg_attr(not(test), no_std)]

pub mod acceptance;
pub mod battery;
pub mod config;
pub mod console;
pub mod mixer;
pub mod poll;
pub mod recovery;
pub mod shared;
#[cfg(any(test, feature = "sim"))]
pub mod sim;
pub mod thrusters;
pub mod vehicle;

use embassy_futures::join::{join3, join5};
use embedded_hal_async::i2c::I2c;
use embedded_io_async::{Read, Write};

pub use config::{CONFIG, MasterConfig};
pub use poll::{PollError, poll_thruster};

use battery::{CanReceiver, can_task};
use console::{ConsoleStats, console_rx_task, console_tx_task};
use recovery::BusRecovery;
use shared::Shared;
use thrusters::{BUSES, bus_task};
use vehicle::vehicle_task;

/// What the master is wired to: the three thruster buses (I2C1..3, indexed as in the thruster table), the battery
/// CAN bus, the console's serial link, and what the buses are for.
#[derive(Debug)]
pub struct Ports<B, C, R, W, J = Polling> {
    /// The thruster buses, each with its recovery.
    pub buses: [B; BUSES],
    /// The battery board's frames.
    pub can: C,
    /// The console link's receive side.
    pub console_rx: R,
    /// The console link's transmit side.
    pub console_tx: W,
    /// The buses' work: [`Polling`] the thrusters (the vehicle), or the acceptance [`acceptance::Script`].
    pub work: J,
}

/// What the master does with its thruster buses.
#[allow(async_fn_in_trait)]
pub trait BusWork {
    /// Use the buses; returning leaves them idle.
    async fn run<B: I2c + BusRecovery>(self, buses: &mut [B; BUSES], config: &MasterConfig, shared: &Shared);
}

/// The vehicle's work: every bus that has thrusters in the table is polled by its own task ([`bus_task`]).
#[derive(Debug, Clone, Copy, Default)]
pub struct Polling;

impl BusWork for Polling {
    async fn run<B: I2c + BusRecovery>(self, buses: &mut [B; BUSES], config: &MasterConfig, shared: &Shared) {
        let [first, second, third] = buses;
        join3(
            poll_bus(first, 0, config, shared),
            poll_bus(second, 1, config, shared),
            poll_bus(third, 2, config, shared),
        )
        .await;
    }
}

/// Poll bus `index` forever, or wait forever when no thruster hangs on it.
async fn poll_bus<B: I2c + BusRecovery>(bus: &mut B, index: u8, config: &MasterConfig, shared: &Shared) {
    if config.thrusters.uses_bus(index) {
        bus_task(bus, index, config.thrusters.as_slice(), &config.poll, shared).await
    } else {
        core::future::pending().await
    }
}

/// The master node: the buses' work, the battery CAN task, the console's receive and transmit tasks and the vehicle
/// task, joined. They talk only through `shared` (and the console tasks through `console`), which live as long as
/// the node: a reboot starts again from fresh ones.
pub async fn run<B, C, R, W, J>(
    ports: Ports<B, C, R, W, J>,
    config: &MasterConfig,
    shared: &Shared,
    console: &ConsoleStats,
) -> !
where
    B: I2c + BusRecovery,
    C: CanReceiver,
    R: Read,
    W: Write,
    J: BusWork,
{
    let Ports {
        mut buses,
        mut can,
        mut console_rx,
        mut console_tx,
        work,
    } = ports;
    let buses = async {
        work.run(&mut buses, config, shared).await;
        core::future::pending::<()>().await
    };
    let (_, never, ..) = join5(
        buses,
        can_task(&mut can, shared),
        console_rx_task(&mut console_rx, &config.console, shared, console),
        console_tx_task(&mut console_tx, &config.console, shared, console),
        vehicle_task(config.vehicle, shared),
    )
    .await;
    never
}

#[cfg(test)]
mod tests;

/// Virtual time for the host tests: the one clock of `lbv-sim`, taken at 0.
#[cfg(test)]
pub(crate) mod test_clock {
    /// Take the virtual clock and set it to 0.
    pub(crate) fn lock() -> lbv_sim::Clock {
        lbv_sim::clock::take()
    }
}
