//! NUCLEO-G431RB + X-NUCLEO-IHM08M1 wiring of the thruster controller and the adapters from embassy-stm32
//! peripherals to the core's ports; the settings they are configured with are the core's (`thruster_fw::CONFIG`).
//!
//! The pins and peripherals are the image's description (`g431_hw::images`: `thruster_image!` for the brushless
//! build, `thruster_brushed_image!`, `thruster_motorless_image!`), checked at build time against what the boards put
//! on each pin; every register value written here comes from `g431_hw`.

use core::cell::RefCell;

use embassy_boot::{AlignedBuffer, BlockingFirmwareState, FirmwareUpdaterError, State};
use embassy_embedded_hal::SetConfig;
use embassy_embedded_hal::flash::partition::BlockingPartition;
#[cfg(feature = "motorless")]
use embassy_stm32::adc::SampleTime;
use embassy_stm32::adc::{Adc, AnyAdcChannel};
use embassy_stm32::flash::{Blocking, Flash, WRITE_SIZE};
use embassy_stm32::i2c::{self, I2c, SlaveCommandKind};
use embassy_stm32::mode::Async;
use embassy_stm32::pac;
use embassy_stm32::peripherals::ADC1;
use embassy_stm32::time::Hertz;
use embassy_sync::blocking_mutex::Mutex as BlockingMutex;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embedded_storage::nor_flash::ReadNorFlash;
use g431_hw::memory::{self, THRUSTER_PARTITIONS};
use g431_hw::{adc, clock, iwdg};
use static_cell::StaticCell;
use thruster_fw::faults::{ResetKind, carried_latch, latch_word};
use thruster_fw::ports::{BootState, I2cTarget, LatchStore, MarkError, Request, Updater, Watchdog};
use thruster_fw::update::{mark_for_swap, verdict_in};
use thruster_fw::{CONFIG, FAMILY};
use tmc_proto::Faults;
use tmc_proto::ext::INFO_LEN;
use update_image::{Ticket, Verdict};
#[cfg(not(feature = "motorless"))]
use {
    core::future::poll_fn,
    core::task::Poll,
    embassy_stm32::exti::ExtiInput,
    embassy_stm32::gpio::{Flex, Output},
    embassy_stm32::pac::timer::regs::{BdtrAdv, CcerAdv, CcmrOutputGp16, EgrAdv, SrAdv},
    embassy_stm32::peripherals::TIM1,
    embassy_stm32::timer::complementary_pwm::ComplementaryPwm,
    g431_hw::tim1::{self, PhaseMode},
    thruster_fw::Duty,
    thruster_fw::commutation::{BridgeDrive, PhaseDrive},
    thruster_fw::hall::HallState,
    thruster_fw::ports::{Bridge, HallSensors, RawSample, Sensors},
};
#[cfg(feature = "motorless")]
use {
    embassy_stm32::gpio::Input,
    thruster_fw::motorless::{ModelSensors, MotorModel, Motorless},
    thruster_fw::ports::{HoldInput, WaterInput},
};

/// The motor-less controller's model motor (Cargo feature `motorless`), for the image's configuration.
#[cfg(feature = "motorless")]
pub static MOTORLESS: Motorless = Motorless::new(MotorModel::new(&CONFIG));

/// What the fault task samples: the ADC inputs, or in the motor-less controller the model and the water pin.
#[cfg(not(feature = "motorless"))]
pub type Analog = AnalogInputs;
#[cfg(feature = "motorless")]
pub type Analog = ModelSensors<'static, WaterPin, UserButton>;

/// What commutation reads and drives: the halls and the power stage, or in the motor-less controller the model's.
#[cfg(not(feature = "motorless"))]
pub type HallInputs = Halls;
#[cfg(not(feature = "motorless"))]
pub type Stage = PowerStage;
#[cfg(feature = "motorless")]
pub type HallInputs = thruster_fw::motorless::ModelHalls<'static>;
#[cfg(feature = "motorless")]
pub type Stage = thruster_fw::motorless::ModelBridge<'static>;

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
/// TIM1 BDTR once a sustained overcurrent is cleared: AOE = 1, the outputs back at the next update event.
#[cfg(not(feature = "motorless"))]
const BDTR_RESTARTED: u32 = BRIDGE.bdtr_restarted(clock::TIM1_HZ);

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

/// The three hall inputs, and the state last read.
#[cfg(not(feature = "motorless"))]
pub struct Halls {
    h1: ExtiInput<'static, Async>,
    h2: ExtiInput<'static, Async>,
    h3: ExtiInput<'static, Async>,
    last: HallState,
}

#[cfg(not(feature = "motorless"))]
impl Halls {
    /// The halls on their EXTI lines, read once.
    pub fn new(h1: ExtiInput<'static, Async>, h2: ExtiInput<'static, Async>, h3: ExtiInput<'static, Async>) -> Self {
        let mut halls = Halls {
            h1,
            h2,
            h3,
            last: HallState::from_bits(0),
        };
        halls.last = halls.pins();
        halls
    }

    fn pins(&self) -> HallState {
        HallState::from_pins(self.h1.is_high(), self.h2.is_high(), self.h3.is_high())
    }
}

#[cfg(not(feature = "motorless"))]
impl HallSensors for Halls {
    /// Returns once the halls differ from the last `read`. Arming an EXTI line clears its pending bit, so an edge
    /// between the last read and the arming would otherwise wait for the next tick (a sector lasts 0.5 ms at
    /// 4500 rpm): the lines are armed first and the pins compared after, as embassy's own `wait_for_low` does.
    async fn wait_for_edge(&mut self) {
        poll_fn(|cx| {
            self.h1.poll_for_any_edge(cx);
            self.h2.poll_for_any_edge(cx);
            self.h3.poll_for_any_edge(cx);
            if self.pins() == self.last {
                Poll::Pending
            } else {
                Poll::Ready(())
            }
        })
        .await
    }

    fn read(&mut self) -> HallState {
        self.last = self.pins();
        self.last
    }
}

/// TIM1's three complementary pairs on the IHM08M1's L6398 gate drivers. The registers are written from
/// `g431_hw::tim1`; embassy's driver and the break input's pin are held only so that the timer stays clocked and
/// the pins stay in their alternate functions (dropping them would disconnect the pins).
#[cfg(not(feature = "motorless"))]
pub struct PowerStage {
    pub _pwm: ComplementaryPwm<'static, TIM1>,
    pub _break_input: Flex<'static>,
    /// The overcurrent comparator's reference (CURRENT_REF), held high.
    pub _current_ref: Output<'static>,
    /// TIM1's auto-reload value: the PWM period in counts.
    pub arr: u16,
}

#[cfg(not(feature = "motorless"))]
impl Bridge for PowerStage {
    /// The step's output modes and enables change together at a COM event; the compare registers (the same
    /// value for all three: only the switching phase uses it) at the next update event.
    fn apply(&mut self, drive: BridgeDrive, duty: Duty) {
        let step = BRIDGE.commutation(drive.map(|phase| match phase {
            PhaseDrive::Pwm => PhaseMode::Switching,
            PhaseDrive::Low => PhaseMode::LowOn,
            PhaseDrive::Float => PhaseMode::Off,
        }));
        let compare = BRIDGE.compare(duty.magnitude(), self.arr);
        let tim = pac::TIM1;
        for channel in 0..3 {
            tim.ccr(channel).write(|w| w.set_ccr(compare));
        }
        // The currents' trigger, in the middle of the longer half of the period at this duty.
        tim.ccr(3)
            .write(|w| w.set_ccr(BRIDGE.current_trigger(compare, self.arr)));
        tim.ccmr_output(0).write_value(CcmrOutputGp16(step.ccmr1));
        tim.ccmr_output(1).write_value(CcmrOutputGp16(step.ccmr2));
        tim.ccer().write_value(CcerAdv(step.ccer));
        tim.egr().write_value(EgrAdv(tim1::EGR_COMG));
    }

    /// BDTR alone: MOE and AOE cleared holds every switch off (OSSI idle levels) through any update event; the
    /// restart value sets AOE again and leaves MOE to the hardware (RM0440 TIMx_BDTR).
    fn hold_off(&mut self, off: bool) {
        let bdtr = if off { BDTR_STOPPED } else { BDTR_RESTARTED };
        pac::TIM1.bdtr().write_value(BdtrAdv(bdtr));
    }
}

/// Whether TIM1's break tripped since the last call, clearing its flags: BIF stays set from a trip until software
/// clears it (RM0440 TIMx_SR), so one read per sample sees every trip in between. Cleared only when set, so a trip
/// between the read and a write is never wiped unseen.
#[cfg(not(feature = "motorless"))]
fn take_break() -> bool {
    let sr = pac::TIM1.sr().read().0;
    if sr & (tim1::SR_BIF | tim1::SR_SBIF) != 0 {
        pac::TIM1.sr().write_value(SrAdv(tim1::SR_CLEAR_BREAK));
    }
    tim1::break_tripped(sr)
}

/// embassy-stm32's sample time of ours: `g431_hw::adc`'s, from the sources' impedance and DS12589's R_AIN table
/// (it checks that each input settles; the water sensor relies on its 100 nF).
#[cfg(feature = "motorless")]
const fn sample_time(sample: adc::SampleTime) -> SampleTime {
    SampleTime::from_bits(sample.bits())
}

/// ADC1 and the fault / telemetry inputs: the three phase currents converted by TIM1's trigger once per PWM
/// period (docs/hardware.md, "Current sensing"), the rest converted by software once per sample.
#[cfg(not(feature = "motorless"))]
pub struct AnalogInputs {
    /// Holds ADC1 clocked, calibrated and enabled (embassy-stm32's `Adc::new`); the conversions go through its
    /// registers, set up in [`AnalogInputs::new`].
    _adc: Adc<'static, ADC1>,
    water: AnyAdcChannel<'static, ADC1>,
    ntc: AnyAdcChannel<'static, ADC1>,
    vbus: AnyAdcChannel<'static, ADC1>,
    _currents: [AnyAdcChannel<'static, ADC1>; 3],
}

#[cfg(not(feature = "motorless"))]
impl AnalogInputs {
    /// Every input's sample time, and the phase currents (A, B, C) as an injected sequence on TIM1_TRGO2 (OC4REF,
    /// placed by `g431_hw::tim1::Bridge::current_trigger` in each period). The pins are in analog mode from reset
    /// (RM0440 GPIOx_MODER), where the image's description wants them.
    ///
    /// The sample times are written once for all channels, before any conversion starts: SMPRx may be written only
    /// while no conversion runs (RM0440 ADC_SMPR1), and the injected conversions never stop. embassy-stm32's
    /// `blocking_read` rewrites SMPRx whole for each read, so it is not used.
    pub fn new(
        adc: Adc<'static, ADC1>,
        water: AnyAdcChannel<'static, ADC1>,
        ntc: AnyAdcChannel<'static, ADC1>,
        vbus: AnyAdcChannel<'static, ADC1>,
        currents: [AnyAdcChannel<'static, ADC1>; 3],
    ) -> Self {
        let [a, b, c] = currents.each_ref().map(AnyAdcChannel::get_hw_channel);
        let [smpr1, smpr2] = adc::smpr(&[
            (water.get_hw_channel(), adc::WATER_SAMPLE),
            (ntc.get_hw_channel(), adc::NTC_SAMPLE),
            (vbus.get_hw_channel(), adc::VBUS_SAMPLE),
            (a, adc::CURRENT_SAMPLE),
            (b, adc::CURRENT_SAMPLE),
            (c, adc::CURRENT_SAMPLE),
        ]);
        let regs = pac::ADC1;
        regs.smpr().write_value(pac::adc::regs::Smpr(smpr1));
        regs.smpr2().write_value(pac::adc::regs::Smpr2(smpr2));
        regs.jsqr().write_value(pac::adc::regs::Jsqr(adc::jsqr([a, b, c])));
        regs.cr().modify(|w| w.set_jadstart(true));
        AnalogInputs {
            _adc: adc,
            water,
            ntc,
            vbus,
            _currents: currents,
        }
    }

    /// One regular conversion of `channel`, started by software and waited for (RM0440, ADC "Single conversion mode
    /// (CONT = 0)", as embassy's `Adc::new` leaves CFGR): SQR1 may be written while ADSTART = 0, which it is between
    /// these. An injected sequence that falls inside pre-empts it and it starts again after; reading DR clears EOC.
    fn convert(channel: &AnyAdcChannel<'static, ADC1>) -> u16 {
        let regs = pac::ADC1;
        regs.sqr1().write(|w| {
            w.set_l(0);
            w.set_sq(0, channel.get_hw_channel());
        });
        regs.cr().modify(|w| w.set_adstart(true));
        while !regs.isr().read().eoc() {}
        regs.dr().read().rdata()
    }
}

#[cfg(not(feature = "motorless"))]
impl Sensors for AnalogInputs {
    async fn sample(&mut self) -> RawSample {
        // Three blocking conversions (`adc::THRUSTER_SEQUENCE`, in this order) take under 32 us, about 3 % of the
        // 1 ms tick (held to 5 % by the core's tests): not worth a DMA round trip at 1 kHz.
        let regs = pac::ADC1;
        RawSample {
            water: Self::convert(&self.water),
            temperature: Self::convert(&self.ntc),
            vbus: Self::convert(&self.vbus),
            // The last injected sequence's results, at most one PWM period old.
            currents: [0, 1, 2].map(|rank| regs.jdr(rank).read().jdata()),
            // TIM1's status register, not the ADC: the fault task's 1 kHz sample is the trip rule's tick
            // (`thruster_fw::overcurrent`). SR's flags are rc_w0, so this never disturbs the commutation's writes.
            break_tripped: take_break(),
        }
    }
}

/// The water-sensor pin of the motor-less controller: the one input that stays real.
#[cfg(feature = "motorless")]
pub struct WaterPin {
    pub adc: Adc<'static, ADC1>,
    pub pin: AnyAdcChannel<'static, ADC1>,
}

#[cfg(feature = "motorless")]
impl WaterInput for WaterPin {
    async fn water(&mut self) -> u16 {
        // ES0431: the first conversion after an idle ADC may be wrong (see `AnalogInputs::sample`); thrown away.
        let _ = self.adc.blocking_read(&mut self.pin, sample_time(adc::CURRENT_SAMPLE));
        self.adc.blocking_read(&mut self.pin, sample_time(adc::WATER_SAMPLE))
    }
}

/// The NUCLEO's blue user button B1 (PC13, high while pressed): holds the motor-less controller's model rotor.
#[cfg(feature = "motorless")]
pub struct UserButton(pub Input<'static>);

#[cfg(feature = "motorless")]
impl HoldInput for UserButton {
    fn held(&mut self) -> bool {
        self.0.is_high()
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
pub struct ImageSwap(&'static SharedFlash);

impl ImageSwap {
    /// On the flash's partitions.
    pub fn new(flash: &'static SharedFlash) -> Self {
        ImageSwap(flash)
    }
}

impl Updater for ImageSwap {
    fn running_info(&mut self) -> [u8; INFO_LEN] {
        let mut info = [0xFF; INFO_LEN];
        // A read inside ACTIVE cannot fail; were it to, the erased bytes say "no record".
        let _ = partition(self.0, THRUSTER_PARTITIONS.active).read(memory::IMAGE_INFO_OFFSET, &mut info);
        info
    }

    fn checks_signatures(&self) -> bool {
        true
    }

    fn mark_updated(&mut self, ticket: &Ticket) -> Result<(), MarkError> {
        let mut ticket_page = partition(self.0, THRUSTER_PARTITIONS.ticket());
        let mut state = partition(self.0, THRUSTER_PARTITIONS.state);
        mark_for_swap(&mut ticket_page, &mut state, ticket)
    }

    fn verdict(&mut self) -> Option<Verdict> {
        verdict_in(&mut partition(self.0, THRUSTER_PARTITIONS.ticket()))
    }

    fn reboot(&mut self) {
        cortex_m::peripheral::SCB::sys_reset()
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
