//! NUCLEO-G431RB + X-NUCLEO-IHM08M1 wiring of the thruster controller and the adapters from embassy-stm32
//! peripherals to the core's ports; the settings they are configured with are the core's (`thruster_fw::CONFIG`).
//!
//! This file holds what every build has: the I2C slave, the watchdog, the fault latches, the flash (the
//! bootloader's state, the DFU partition, the field update) and the bridge's emergency stop. The ports commutation
//! and the fault task take are one variant's, under the same names (`HallInputs`, `Stage`, `Analog`):
//! `board/power_stage.rs` (TIM1's bridge, the halls, ADC1 with the phase currents) or, with the `motorless`
//! feature, `board/motorless.rs` (the model motor, the real water pin, the user button).
//!
//! The pins and peripherals are the image's description (`g431_hw::images`: `thruster_image!` for the brushless
//! build, `thruster_brushed_image!`, `thruster_motorless_image!`), checked at build time against what the boards put
//! on each pin; every register value written here and in `board/` comes from `g431_hw`.

use core::cell::RefCell;

use embassy_boot::{AlignedBuffer, BlockingFirmwareState, FirmwareUpdaterError, State};
use embassy_embedded_hal::SetConfig;
use embassy_embedded_hal::flash::partition::BlockingPartition;
use embassy_stm32::flash::{Blocking, Flash, WRITE_SIZE};
use embassy_stm32::i2c::{self, I2c, SlaveCommandKind};
use embassy_stm32::mode::Async;
use embassy_stm32::pac;
use embassy_stm32::time::Hertz;
use embassy_sync::blocking_mutex::Mutex as BlockingMutex;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embedded_storage::nor_flash::ReadNorFlash;
use g431_hw::memory::{self, THRUSTER_PARTITIONS};
use g431_hw::{clock, iwdg};
use static_cell::StaticCell;
use thruster_fw::faults::{ResetKind, carried_latch, latch_word};
use thruster_fw::ports::{BootState, I2cTarget, LatchStore, MarkError, Request, Updater, Watchdog};
use thruster_fw::update::{mark_for_swap, verdict_in};
use thruster_fw::{CONFIG, FAMILY};
use tmc_proto::Faults;
use tmc_proto::ext::{INFO_LEN, RECORD_LEN};
use update_image::{Ticket, Verdict};

#[cfg(not(feature = "motorless"))]
mod power_stage;
#[cfg(not(feature = "motorless"))]
pub use power_stage::{Analog, AnalogInputs, HallInputs, Halls, PowerStage, Stage};
#[cfg(feature = "motorless")]
mod motorless;
#[cfg(feature = "motorless")]
pub use motorless::{Analog, HallInputs, Stage, wire};

/// IWDG_PR / IWDG_RLR for the timeout, checked against the health task (`WatchdogTiming::schedule`): every task
/// reports within a feed period, and at the fastest LSI the watchdog outlasts two feed periods.
pub const WATCHDOG: iwdg::Iwdg = match SCHEDULE.check() {
    Ok(iwdg) => iwdg,
    Err(_) => iwdg::Iwdg { pr: 0, rlr: 0 },
};
const SCHEDULE: iwdg::Schedule = CONFIG.watchdog.schedule(&CONFIG.bus);
const _: () = assert!(SCHEDULE.check().is_ok());

/// The power stage on TIM1.
pub const BRIDGE: g431_hw::tim1::Bridge = g431_hw::tim1::IHM08M1;
const _: () = assert!(BRIDGE.is_valid(clock::TIM1_HZ));

/// TIM1 BDTR with the outputs stopped for good (MOE = 0, AOE = 0): both switches of every phase off.
const BDTR_STOPPED: u32 = BRIDGE.bdtr_stopped(clock::TIM1_HZ);

/// Stop the bridge from any context (panic, hard fault): the outputs drop to their idle levels, both switches of
/// every phase off, and stay there. Harmless when TIM1 is not clocked (writes to it are ignored).
pub fn stop_bridge() {
    pac::TIM1.bdtr().write_value(pac::timer::regs::BdtrAdv(BDTR_STOPPED));
}

/// Write a standard-mode TIMINGR (`g431_hw::i2c`) into an I2C peripheral, over embassy-stm32's own value,
/// disabling it meanwhile as RM0440 requires.
pub fn set_i2c_timing(regs: pac::i2c::I2c) {
    regs.cr1().modify(|w| w.set_pe(false));
    regs.timingr()
        .write_value(pac::i2c::regs::Timingr(g431_hw::i2c::TIMINGR));
    regs.cr1().modify(|w| w.set_pe(true));
}

/// I2C3 as the thruster interface's slave port.
pub struct SlavePort(pub I2c<'static, Async, i2c::MultiMaster>);

impl I2cTarget for SlavePort {
    type Error = i2c::Error;

    async fn listen(&mut self) -> Result<Request, i2c::Error> {
        // Only the family's own address is configured, so every match is ours.
        let command = self.0.listen().await?;
        Ok(match command.kind {
            SlaveCommandKind::Write => Request::Write,
            SlaveCommandKind::Read => Request::Read,
        })
    }

    async fn respond_to_write(&mut self, buffer: &mut [u8]) -> Result<usize, i2c::Error> {
        self.0.respond_to_write(buffer).await
    }

    async fn respond_to_read(&mut self, data: &[u8]) -> Result<(), i2c::Error> {
        self.0.respond_to_read(data).await.map(|_| ())
    }

    fn reset(&mut self) {
        // Re-applying the configuration turns the peripheral off and on, which clears its state machine and
        // releases SCL and SDA; it also rewrites TIMINGR with embassy's value, so ours goes back on top.
        let _ = self.0.set_config(&(
            Hertz(CONFIG.bus.frequency_hz),
            i2c::SlaveAddrConfig::basic(FAMILY.address()),
        ));
        set_i2c_timing(pac::I2C3);
    }
}

/// The independent watchdog, set up from [`WATCHDOG`].
pub struct Iwdg(());

impl Iwdg {
    /// Start the watchdog: RM0440's IWDG procedure (start, unlock, prescaler, reload, wait for the update, then
    /// reload the counter). Taking the peripheral keeps anyone else from it.
    pub fn start(_iwdg: embassy_stm32::Peri<'static, embassy_stm32::peripherals::IWDG>) -> Self {
        use pac::iwdg::vals::{Key, Pr};
        // Frozen while a debugger halts the core (the bridge is off then: see TIM1's freeze).
        pac::DBGMCU
            .apb1lfzr()
            .write_value(pac::dbgmcu::regs::Apb1lfzr(g431_hw::iwdg::DBGMCU_APB1FZR1));
        let regs = pac::IWDG;
        regs.kr().write(|w| w.set_key(Key::START));
        regs.kr().write(|w| w.set_key(Key::ENABLE));
        regs.pr().write(|w| w.set_pr(Pr::from_bits(WATCHDOG.pr)));
        regs.rlr().write(|w| w.set_rl(WATCHDOG.rlr));
        // A few LSI cycles; were the LSI dead, the watchdog (running since START) resets the chip.
        while regs.sr().read().0 != 0 {}
        regs.kr().write(|w| w.set_key(Key::RESET));
        Iwdg(())
    }
}

impl Watchdog for Iwdg {
    fn feed(&mut self) {
        pac::IWDG.kr().write(|w| w.set_key(pac::iwdg::vals::Key::RESET));
    }
}

/// The backup register that keeps the power-cycle latches across resets (`g431_hw::backup`: kept over every reset
/// but a loss of VDD and VBAT, which are one supply on the NUCLEO).
const LATCH_REGISTER: usize = g431_hw::backup::LATCH_REGISTER;

/// The fault latches in a backup register.
pub struct BackupLatch {
    carried: Faults,
}

impl BackupLatch {
    /// Open the backup domain for writing (PWR_CR1.DBP, with the PWR and RTC/TAMP APB clocks on) and read the
    /// latches the last reset left, dropping them after a power cycle (`ResetKind`, from RCC_CSR).
    pub fn open(reset: ResetKind) -> Self {
        pac::RCC.apb1enr1().modify(|w| {
            w.set_pwren(true);
            w.set_rtcapben(true);
        });
        pac::PWR.cr1().modify(|w| w.set_dbp(true));
        let word = pac::TAMP.bkpr(LATCH_REGISTER).read().bkp();
        let mut latch = BackupLatch {
            carried: carried_latch(reset, word),
        };
        let carried = latch.carried;
        latch.save(carried);
        latch
    }
}

impl LatchStore for BackupLatch {
    fn load(&mut self) -> Faults {
        self.carried
    }

    fn save(&mut self, latched: Faults) {
        pac::TAMP.bkpr(LATCH_REGISTER).write(|w| w.set_bkp(latch_word(latched)));
    }
}

/// The flash interface, shared by every partition the image reads or writes: the bootloader's state, the DFU
/// partition and the running image's own record. Taken once: nobody else reaches the flash.
pub type SharedFlash = BlockingMutex<NoopRawMutex, RefCell<Flash<'static, Blocking>>>;

/// A partition of the flash (`g431_hw::memory::THRUSTER_PARTITIONS`).
type Part = BlockingPartition<'static, NoopRawMutex, Flash<'static, Blocking>>;

/// Open the flash interface for the partitions.
pub fn open_flash(flash: embassy_stm32::Peri<'static, embassy_stm32::peripherals::FLASH>) -> &'static SharedFlash {
    static FLASH: StaticCell<SharedFlash> = StaticCell::new();
    FLASH.init(BlockingMutex::new(RefCell::new(Flash::new_blocking(flash))))
}

/// The partition at `span` (embassy-stm32's flash is addressed by offset from the flash's start).
fn partition(flash: &'static SharedFlash, span: memory::Span) -> Part {
    BlockingPartition::new(flash, span.origin - memory::FLASH_ORIGIN, span.length)
}

/// The bootloader's state partition (g431_hw::memory::THRUSTER_PARTITIONS), read and written by embassy-boot's own
/// code: a new image confirms itself there (`thruster_fw::trial`).
pub struct BootRecord(Part);

impl BootRecord {
    /// The state partition of the flash.
    pub fn open(flash: &'static SharedFlash) -> Self {
        BootRecord(partition(flash, THRUSTER_PARTITIONS.state))
    }
}

/// The DFU partition a field update writes (`thruster_fw::update`), on embassy-stm32's blocking flash.
pub type Dfu = Part;

/// The DFU partition of the flash.
pub fn dfu(flash: &'static SharedFlash) -> Dfu {
    partition(flash, THRUSTER_PARTITIONS.dfu)
}

/// The field update's bootloader side: the running image's record from its own flash, the ticket and the mark
/// that hand a payload in DFU to the bootloader (which checks its signature before it swaps it in), the
/// bootloader's verdict on the last one, and the system reset.
pub struct ImageSwap {
    flash: &'static SharedFlash,
    /// The post-mortem record the start found in RAM, encoded.
    post_mortem: Option<[u8; RECORD_LEN]>,
}

impl ImageSwap {
    /// On the flash's partitions, with the post-mortem record the start found.
    pub fn new(flash: &'static SharedFlash, post_mortem: Option<[u8; RECORD_LEN]>) -> Self {
        ImageSwap { flash, post_mortem }
    }
}

impl Updater for ImageSwap {
    fn running_info(&mut self) -> [u8; INFO_LEN] {
        let mut info = [0xFF; INFO_LEN];
        // A read inside ACTIVE cannot fail; were it to, the erased bytes say "no record".
        let _ = partition(self.flash, THRUSTER_PARTITIONS.active).read(memory::IMAGE_INFO_OFFSET, &mut info);
        info
    }

    fn checks_signatures(&self) -> bool {
        true
    }

    fn mark_updated(&mut self, ticket: &Ticket) -> Result<(), MarkError> {
        let mut ticket_page = partition(self.flash, THRUSTER_PARTITIONS.ticket());
        let mut state = partition(self.flash, THRUSTER_PARTITIONS.state);
        mark_for_swap(&mut ticket_page, &mut state, ticket)
    }

    fn verdict(&mut self) -> Option<Verdict> {
        verdict_in(&mut partition(self.flash, THRUSTER_PARTITIONS.ticket()))
    }

    fn reboot(&mut self) {
        cortex_m::peripheral::SCB::sys_reset()
    }

    fn post_mortem(&self) -> Option<[u8; RECORD_LEN]> {
        self.post_mortem
    }
}

impl BootState for BootRecord {
    type Error = FirmwareUpdaterError;

    async fn on_trial(&mut self) -> Result<bool, Self::Error> {
        let mut word = AlignedBuffer([0; WRITE_SIZE]);
        let state = BlockingFirmwareState::new(&mut self.0, &mut word.0).get_state()?;
        Ok(state == State::Swap)
    }

    async fn confirm(&mut self) -> Result<(), Self::Error> {
        let mut word = AlignedBuffer([0; WRITE_SIZE]);
        BlockingFirmwareState::new(&mut self.0, &mut word.0).mark_booted()
    }
}
