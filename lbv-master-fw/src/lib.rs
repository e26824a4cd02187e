//! The LBV master node's hardware-free core.
//!
//! Everything here runs unchanged on the STM32 (through the binary's binding: `main.rs`, `stm32.rs` and `board.rs`)
//! and on the host, where tests and the bench drive it through simulated ports. It never touches a register and
//! never panics on bus input.
//!
//! [`run`] is the whole node: the STM32 binding builds its [`Ports`] from peripherals and calls it with [`CONFIG`];
//! the bench and the tests call it with simulated ports (lbv-sim's buses, links and flash). Every trait a port
//! implements, and the [`Board`] that names their types, is in [`ports`].
#![cfg_attr(not(test), no_std)]
// What only this crate uses is `pub(crate)`, and its docs still link to it: they are read with the private items
// documented (`cargo doc --document-private-items`, as test.sh builds them), where those links resolve.
#![allow(rustdoc::private_intra_doc_links)]

pub mod acceptance;
pub(crate) mod battery;
pub mod blackbox;
pub mod config;
pub mod console;
pub(crate) mod follow;
pub mod mixer;
pub mod params;
pub(crate) mod poll;
pub mod ports;
pub mod recovery;
pub mod settings;
pub mod shared;
pub mod thrusters;
pub mod update;
pub mod vehicle;

use embassy_futures::join::{join, join3, join5};
use embedded_hal_async::i2c::I2c;

pub use config::{CONFIG, MasterConfig};

use battery::can_task;
use console::{ConsoleStats, console_rx_task, console_tx_task};
use ports::{Board, BusRecovery, BusWork, OwnUpdate, Ports, SettingsStore};
use settings::settings_task;
use shared::{BUSES, Severity, Shared, text};
use thrusters::{Links, bus_task};
use update::courier::Transfers;
use vehicle::vehicle_task;

/// What an image that takes update files signed with the development key (update-image's `UPDATE_KEY_IS_DEV`)
/// says at every start, as a warning: the key's secret is published, so anyone can sign an image it takes
/// (AUTOPILOT_VERSION says it too, [`console::outbound::DEV_KEY_MARK`]).
pub(crate) const DEV_KEY_TEXT: &str = "Takes update files signed with the development key";
// Whole in one STATUSTEXT.
const _: () = assert!(DEV_KEY_TEXT.len() <= shared::TEXT_LEN);

/// Why the settings store and the master's own update write nothing: the chip's flash is not in the layout their
/// pages are placed for (`g431_hw::flash::master_layout_ok`, which the binding reads at start).
pub(crate) const NOT_DUAL_BANK: &str = "flash not dual-bank";
/// What a master whose flash is not in dual-bank mode says at every start, as an error (docs/flashing.md, "Option
/// bytes"): its settings last until the next restart, and master images are refused.
pub(crate) const NOT_DUAL_BANK_TEXT: &str = "Settings and updates refused: flash not dual-bank";
// Whole in one STATUSTEXT.
const _: () = assert!(NOT_DUAL_BANK_TEXT.len() <= shared::TEXT_LEN);

/// The vehicle's work: every bus that has thrusters in the table is polled by its own task ([`bus_task`]), which
/// also carries the update images in `transfers` to its thrusters, between polls.
#[derive(Debug, Clone, Copy, Default)]
pub struct Polling<'a> {
    /// The images on their way to the thrusters: the update sink's ([`update::VehicleSink`]), or `None` when
    /// none are sent.
    pub transfers: Option<&'a Transfers>,
}

impl BusWork for Polling<'_> {
    const POLLS: bool = true;

    async fn run<B: I2c + BusRecovery>(self, buses: &mut [B; BUSES], config: &MasterConfig, shared: &Shared) {
        let [first, second, third] = buses;
        let links = Links::new(&config.poll);
        // Before the vehicle can arm, every thruster is asked what it runs: it may have come up on trial ([`update::courier`]).
        if let Some(transfers) = self.transfers {
            transfers.with(|courier| courier.expect(config.thrusters.as_slice().len()));
            transfers.publish(shared);
        }
        join3(
            poll_bus(first, 0, config, shared, &links, self.transfers),
            poll_bus(second, 1, config, shared, &links, self.transfers),
            poll_bus(third, 2, config, shared, &links, self.transfers),
        )
        .await;
    }
}

impl<O: acceptance::Operator> BusWork for acceptance::Script<O> {
    const POLLS: bool = false;

    async fn run<B: I2c + BusRecovery>(self, buses: &mut [B; BUSES], config: &MasterConfig, shared: &Shared) {
        acceptance::Script::run(self, buses, &config.acceptance, shared).await
    }
}

/// Poll bus `index` forever, or wait forever when no thruster hangs on it.
async fn poll_bus<B: I2c + BusRecovery>(
    bus: &mut B,
    index: u8,
    config: &MasterConfig,
    shared: &Shared,
    links: &Links,
    transfers: Option<&Transfers>,
) {
    if config.thrusters.uses_bus(index) {
        bus_task(
            bus,
            index,
            config.thrusters.as_slice(),
            &config.poll,
            shared,
            links,
            transfers,
        )
        .await
    } else {
        core::future::pending().await
    }
}

/// The master node: the settings loaded from their store, then the buses' work, the battery CAN task, the console's
/// receive and transmit tasks (the receiving one serving the update images, [`update`]), the vehicle task and
/// the settings task, joined. They talk only through `shared` (and
/// the console tasks through `console`), which live as long as the node: a reboot starts again from fresh ones.
///
/// Before any task runs, the settings are published and, with a signing key, a new signing reservation is stored
/// past the one loaded (the start's floor, [`console::signing`]): the first frame read (one already waiting in the UART) is
/// checked with the key, and the first telemetry goes out signed, above every timestamp used before the start.
pub async fn run<P: Board>(ports: Ports<P>, config: &MasterConfig, shared: &Shared, console: &ConsoleStats) -> ! {
    let Ports {
        mut buses,
        mut can,
        mut console_rx,
        mut console_tx,
        mut settings,
        mut reboot,
        work,
        update,
        own,
    } = ports;
    let stored = settings.load(config.vehicle.defaults()).await;
    let unreadable = settings.read_errors();
    if unreadable > 0 {
        shared.say(
            Severity::Warning,
            text(format_args!("Settings: {unreadable} unreadable in flash")),
        );
    }
    if let Some(key) = stored.signing {
        let reservation = console::signing::reservation_after(key.timestamp);
        match settings.save_signing_time(reservation).await {
            Ok(()) => shared.signing_stored.sender().send(reservation),
            // The console signs and accepts nothing until the settings task stores one.
            Err(_) => shared.say(Severity::Warning, text(format_args!("Signing: reservation not stored"))),
        }
    }
    if update_image::UPDATE_KEY_IS_DEV {
        shared.say(Severity::Warning, text(format_args!("{DEV_KEY_TEXT}")));
    }
    if settings.writes_refused() {
        shared.say(Severity::Error, text(format_args!("{NOT_DUAL_BANK_TEXT}")));
    }
    tell_crash(shared);
    shared.settings.sender().send(stored);
    // Until the own update has read whether the running image is on trial, no arm is taken ([`update::own`]).
    shared.holds.set_master(Some(shared::UpdateHold::MasterStarting));
    console.follow(shared);
    let buses = async {
        work.run(&mut buses, config, shared).await;
        core::future::pending::<()>().await
    };
    let ((_, never, ..), ..) = join3(
        join5(
            buses,
            can_task(&mut can, shared),
            console_rx_task(
                &mut console_rx,
                &config.console,
                shared,
                console,
                &config.thrusters,
                config.vehicle.frame,
                update,
            ),
            console_tx_task(&mut console_tx, &config.console, shared, console),
            vehicle_task(config.vehicle, stored, shared),
        ),
        settings_task(&mut settings, shared, &mut reboot),
        join(
            own.run(if P::Work::POLLS { config.thrusters.count() } else { 0 }, shared),
            black_box(config, shared),
        ),
    )
    .await;
    never
}

/// The black box's task ([`console::tlog`]); none in the acceptance image, which serves no files.
async fn black_box(config: &MasterConfig, shared: &Shared) {
    #[cfg(not(feature = "acceptance"))]
    console::tlog::black_box_task(shared, usize::from(config.thrusters.count())).await;
    #[cfg(feature = "acceptance")]
    let _ = (config, shared);
}

/// Tell the operator, once, of the stop before this start that the post-mortem region holds
/// ([`Shared::keep_crash`]), and where to read its record.
fn tell_crash(shared: &Shared) {
    let Some(record) = shared.crash_record().filter(|record| !record.told) else {
        return;
    };
    tell_stop(shared, None, &record);
    shared.crash_told();
}

/// Tell the operator of the stop `record` says `board` made before its start (the master's own, or a thruster's
/// by its slot), and where to read the record.
pub(crate) fn tell_stop(shared: &Shared, board: Option<u8>, record: &crash_record::Record) {
    let what = record.kind.name();
    let who = StopOf(board);
    shared.say(
        Severity::Critical,
        match (record.kind, record.panic, record.frame.pc) {
            // A watchdog's stop has no frame, and a thruster's panic keeps none.
            (crash_record::Kind::Watchdog, _, _) | (_, None, 0) => text(format_args!("{who}: {what}")),
            // Its file is an address in the image, which `lbv decode crash --elf` reads.
            (_, Some(at), _) => text(format_args!("{who}: {what}, line {}", at.line)),
            (_, None, pc) => text(format_args!("{who}: {what} at {pc:#010x}")),
        },
    );
    let file = update::sys::CrashFile(board);
    shared.say(
        Severity::Critical,
        text(format_args!("Its record: ftp get @SYS/crash/{file}")),
    );
}

/// Whose stop a text tells: `Crash before this start` (the master's), `T2: crash before its start`.
struct StopOf(Option<u8>);

impl core::fmt::Display for StopOf {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.0 {
            None => f.write_str("Crash before this start"),
            Some(slot) => write!(f, "T{}: crash before its start", u16::from(slot) + 1),
        }
    }
}

#[cfg(test)]
mod tests;

#[cfg(any(test, feature = "sim"))]
pub mod sim;
