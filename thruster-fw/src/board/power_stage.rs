//! The power stage (every build but `motorless`): TIM1's bridge on the IHM08M1, the halls, and ADC1's inputs with
//! the phase currents.

use core::future::poll_fn;
use core::task::Poll;

use defmt::warn;
use embassy_stm32::Peri;
use embassy_stm32::adc::{Adc, AnyAdcChannel};
use embassy_stm32::exti::ExtiInput;
use embassy_stm32::gpio::{AfType, Flex, Level, Output, Pin, Pull, Speed};
use embassy_stm32::mode::Async;
use embassy_stm32::pac;
use embassy_stm32::pac::syscfg::regs::Cfgr2;
use embassy_stm32::pac::timer::regs::{Af1Adv, BdtrAdv, CcerAdv, CcmrOutputGp16, Cr2Adv, EgrAdv, SrAdv};
use embassy_stm32::peripherals::{ADC1, TIM1};
use embassy_stm32::timer::complementary_pwm::ComplementaryPwm;
use embassy_stm32::timer::{BkIn1, BreakInputPin};
use g431_hw::tim1::{self, PhaseMode};
use g431_hw::{adc, clock};
use thruster_fw::Duty;
use thruster_fw::commutation::{BridgeDrive, COAST, PhaseDrive};
use thruster_fw::hall::HallState;
use thruster_fw::ports::{Bridge, HallSensors, RawSample, Sensors};

use super::{BDTR_STOPPED, BRIDGE};

/// What the fault task samples: the ADC inputs.
pub type Analog = AnalogInputs;

/// What commutation reads: the halls.
pub type HallInputs = Halls;
/// What commutation drives: the power stage.
pub type Stage = PowerStage;

/// TIM1 BDTR once a sustained overcurrent is cleared: AOE = 1, the outputs back at the next update event.
const BDTR_RESTARTED: u32 = BRIDGE.bdtr_restarted(clock::TIM1_HZ);

/// The three hall inputs, and the state last read.
pub struct Halls {
    h1: ExtiInput<'static, Async>,
    h2: ExtiInput<'static, Async>,
    h3: ExtiInput<'static, Async>,
    last: HallState,
}

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
pub struct PowerStage {
    _pwm: ComplementaryPwm<'static, TIM1>,
    _break_input: Flex<'static>,
    /// The overcurrent comparator's reference (CURRENT_REF), held high.
    _current_ref: Output<'static>,
    /// TIM1's auto-reload value: the PWM period in counts.
    arr: u16,
}

impl PowerStage {
    /// The bridge on embassy's `pwm` driver (TIM1 and its six outputs), with the break input `bkin` and
    /// CURRENT_REF `current_ref`, armed ([`PowerStage::arm`]) with every switch off.
    pub fn new(
        pwm: ComplementaryPwm<'static, TIM1>,
        bkin: Peri<'static, impl BreakInputPin<TIM1, BkIn1>>,
        current_ref: Peri<'static, impl Pin>,
    ) -> Self {
        // PA6 in its TIM1_BKIN alternate function, driven by the IHM08M1's overcurrent comparators. They are open
        // drain by the second binding review's reading of the board (UM1996 not read here): the pull-up holds the line
        // high (no break) between their pulls low, and costs nothing should the output be push-pull.
        let break_af = BreakInputPin::<TIM1, BkIn1>::af_num(&*bkin);
        let mut break_input = Flex::new(bkin);
        break_input.set_as_af_unchecked(break_af, AfType::input(Pull::Up));
        // CURRENT_REF, held high before the outputs are armed: a known level, not the reset state's pull-up
        // (`g431_hw::images`, docs/hardware.md "The break").
        let current_ref = Output::new(current_ref, Level::High, Speed::Low);
        // The period is written here, not taken from embassy: its centre-aligned set-up counts ARR = 4249 (an
        // edge-aligned period less one), while a centre-aligned period is 2 x ARR timer clocks (RM0440 TIM1
        // centre-aligned mode), so 20 kHz from 170 MHz is ARR = 4250 with PSC = 0. The outputs are not armed yet.
        const ARR: u16 = {
            let arr = BRIDGE.arr(clock::TIM1_HZ);
            assert!(arr <= u16::MAX as u32, "the PWM period does not fit TIM1's 16 bits");
            arr as u16
        };
        pac::TIM1.arr().write(|w| w.set_arr(ARR));
        let (arr, psc) = (pac::TIM1.arr().read().arr(), pac::TIM1.psc().read());
        if arr != ARR || psc != 0 {
            warn!(
                "TIM1 counts ARR {=u16} with PSC {=u16}, not {=u16} with 0",
                arr, psc, ARR
            );
        }
        let mut bridge = PowerStage {
            _pwm: pwm,
            _break_input: break_input,
            _current_ref: current_ref,
            arr,
        };
        bridge.arm();
        bridge
    }

    /// TIM1 from `g431_hw::tim1`: every phase off and driven (OSSR / OSSI), the L6398's inverted low inputs, the
    /// idle levels, dead time, filtered active-low break (tripped too by a core lockup or a flash ECC error) and
    /// commutation through COM events. The outputs come on at the next update event (automatic output enable),
    /// with every switch off until the commutation task drives.
    fn arm(&mut self) {
        use embassy_stm32::pac::timer::vals::Ckd;
        let tim = pac::TIM1;
        // t_DTS = t_CK_INT: the dead time and the break filter are counted in timer clocks.
        tim.cr1().modify(|w| w.set_ckd(Ckd::DIV1));
        tim.bdtr().write_value(BdtrAdv(BRIDGE.bdtr(clock::TIM1_HZ)));
        tim.cr2().write_value(Cr2Adv(BRIDGE.cr2()));
        tim.af1().write_value(Af1Adv(tim1::AF1));
        pac::SYSCFG.cfgr2().write_value(Cfgr2(tim1::SYSCFG_CFGR2));
        // A debugger's halt stops TIM1 and turns every switch off (RM0440 TIM1 "Debug mode").
        pac::DBGMCU
            .apb2fzr()
            .write_value(pac::dbgmcu::regs::Apb2fzr(tim1::DBGMCU_APB2FZR));
        self.apply(COAST, Duty::ZERO);
    }
}

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
fn take_break() -> bool {
    let sr = pac::TIM1.sr().read().0;
    if sr & (tim1::SR_BIF | tim1::SR_SBIF) != 0 {
        pac::TIM1.sr().write_value(SrAdv(tim1::SR_CLEAR_BREAK));
    }
    tim1::break_tripped(sr)
}

/// ADC1 and the fault / telemetry inputs: the three phase currents converted by TIM1's trigger once per PWM
/// period (docs/hardware.md, "Current sensing"), the rest converted by software once per sample.
pub struct AnalogInputs {
    /// Holds ADC1 clocked, calibrated and enabled (embassy-stm32's `Adc::new`); the conversions go through its
    /// registers, set up in [`AnalogInputs::new`].
    _adc: Adc<'static, ADC1>,
    water: AnyAdcChannel<'static, ADC1>,
    ntc: AnyAdcChannel<'static, ADC1>,
    vbus: AnyAdcChannel<'static, ADC1>,
    _currents: [AnyAdcChannel<'static, ADC1>; 3],
}

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
