//! TIM1 driving three half-bridges through high/low gate drivers: the register values for each commutation step,
//! the dead time, the break input and the safe state (RM0440, advanced-control timers TIM1/TIM8/TIM20).
//!
//! The X-NUCLEO-IHM08M1 drives each MOSFET pair through an L6398, whose low-side input LIN is *active low* with an
//! internal pull-up and whose high-side input HIN is active high with an internal pull-down; with both inputs
//! asking for their switch, its interlock turns both off. Sources: the L6398 datasheet (Doc ID 18199), whose DC
//! characteristics give LIN's bias current at LIN = 0 V and HIN's at HIN = 15 V; ST's answer on the ST community
//! forum about the L6398 input logic on the IHM08M1 (HIN high + LIN high turns the high side on, HIN low + LIN low
//! the low side; output LIN inverted); and NuttX's IHM08M1 board support, which requires CHxN inverted for it
//! (`boards/arm/stm32/common/src/stm32_ihm08m1.c`: "PWM complementary channels must have inverted polarity"). So
//! CCxP = 0 and CCxNP = 1, and every idle and off level below derives from them.
//!
//! The safe state: both switches of every phase off, *driven* by the MCU (not left to the driver's pulls):
//! - a phase that floats is `CCxE = 1, CCxNE = 0, OCxREF forced inactive` with OSSR = 1: CHx = CCxP and CHxN sits
//!   in its off state CCxNP (RM0440 "Output control bits for complementary OCx and OCxN channels with break
//!   feature": with MOE = 1 and CCxE = CCxNE = 0 the outputs are *not driven*, whatever OSSR);
//! - after a break, or with MOE cleared, OSSI = 1 drives the idle levels OISx = CCxP, OISxN = CCxNP;
//! - the break input is filtered (BKF) so switching noise on the overcurrent line does not trip it.
//!
//! Commutation changes CCER and the output modes together at a COM event (CR2.CCPC = 1, software COMG), so a
//! step never passes through a mixed pattern; the compare registers are preloaded and take effect at the next
//! update event.

/// What one half-bridge does in a commutation step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PhaseMode {
    /// Complementary PWM: high switch for the duty, low switch for the rest, dead time between.
    Switching,
    /// Low switch held on.
    LowOn,
    /// Both switches held off.
    Off,
}

/// The input polarity of a high/low gate driver.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GateDriver {
    /// The high-side input turns its switch on when high.
    pub high_active_high: bool,
    /// The low-side input turns its switch on when high.
    pub low_active_high: bool,
}

impl GateDriver {
    /// ST L6398: HIN active high, LIN active low (see the module documentation).
    pub const L6398: GateDriver = GateDriver {
        high_active_high: true,
        low_active_high: false,
    };

    /// CCxP: 1 inverts the channel output, so a driver input that is active low gets CCxP = 1.
    const fn ccp(&self) -> bool {
        !self.high_active_high
    }

    /// CCxNP likewise for the complementary output.
    const fn ccnp(&self) -> bool {
        !self.low_active_high
    }
}

/// The power stage behind TIM1 and the choices made for it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Bridge {
    /// The gate drivers' input polarity.
    pub driver: GateDriver,
    /// Dead time TIM1 inserts between a phase's two switches, in ns.
    pub dead_time_ns: u32,
    /// The break input is active low.
    pub break_active_low: bool,
    /// Pulses on the break input shorter than this are ignored (switching noise), in ns.
    pub break_glitch_ns: u32,
    /// Re-enable the outputs at the next update event once the break input is inactive (AOE): cycle-by-cycle
    /// current limiting by the overcurrent comparator.
    pub auto_restart: bool,
    /// PWM frequency, center-aligned.
    pub pwm_hz: u32,
    /// Largest duty the high switch may get, in 1/10 000: the low switch must conduct every period to recharge
    /// the high-side driver's bootstrap capacitor.
    pub max_duty: u16,
}

/// One GPIO port's part in holding a power stage's gate-driver inputs off by software, before TIM1 drives them:
/// the pins' levels set first (GPIOx_BSRR, RM0440 9.4.7: the low half sets, the high half resets), then the pins
/// made general-purpose outputs (GPIOx_MODER = 01, RM0440 9.4.1), so that no pin drives the wrong level between the
/// two writes. Push-pull is OTYPER's reset value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GatesOff {
    /// The port.
    pub port: crate::pins::Port,
    /// What to write to its BSRR.
    pub bsrr: u32,
    /// The MODER bits to clear (two per pin).
    pub moder_mask: u32,
    /// The MODER bits to set after (01 per pin: output).
    pub moder_output: u32,
}

/// The level that turns a TIM1 channel's gate input off: a high-side input (CHx) is off at its inactive level, a
/// low-side one (CHxN) likewise, from `driver`'s polarity; `None` for a signal that is no gate output (the break
/// input, another timer).
pub const fn gate_off_level(signal: &str, driver: GateDriver) -> Option<bool> {
    let high_side = crate::pins::same(signal, "TIM1_CH1")
        || crate::pins::same(signal, "TIM1_CH2")
        || crate::pins::same(signal, "TIM1_CH3");
    let low_side = crate::pins::same(signal, "TIM1_CH1N")
        || crate::pins::same(signal, "TIM1_CH2N")
        || crate::pins::same(signal, "TIM1_CH3N");
    if high_side {
        Some(!driver.high_active_high)
    } else if low_side {
        Some(!driver.low_active_high)
    } else {
        None
    }
}

/// The writes to `port` that hold every gate input `image` wires to TIM1 at its off level (see [`GatesOff`]).
pub const fn gates_off(image: &crate::pins::Image, driver: GateDriver, port: crate::pins::Port) -> GatesOff {
    let mut out = GatesOff {
        port,
        bsrr: 0,
        moder_mask: 0,
        moder_output: 0,
    };
    let mut rest = image.uses;
    while let [used, tail @ ..] = rest {
        rest = tail;
        let crate::pins::Mode::Alternate { signal, .. } = used.mode else {
            continue;
        };
        let Some(high) = gate_off_level(signal, driver) else {
            continue;
        };
        if used.pin.port as u8 != port as u8 {
            continue;
        }
        let n = used.pin.number as u32;
        out.bsrr |= if high { 1 << n } else { 1 << (n + 16) };
        out.moder_mask |= 0b11 << (2 * n);
        out.moder_output |= 0b01 << (2 * n);
    }
    out
}

/// The X-NUCLEO-IHM08M1 as the thruster drives it.
///
/// - 1 us dead time in TIM1, on top of the L6398's own fixed 320 ns (NuttX's IHM08M1 support, which also keeps a
///   timer dead time "for sure").
/// - The overcurrent comparator pulls BKIN low (the binding's PA6); pulses under 400 ns are taken as switching
///   noise (an engineering margin over the MOSFETs' switching transients, to confirm on the scope at first
///   power-up); the filter still reacts well within a microsecond.
/// - 20 kHz: above hearing.
/// - At most 95 % duty, as NuttX's IHM08M1 support (`MAX_DUTY_B16 = 0.95` for center-aligned PWM): at 20 kHz
///   that leaves the low switch 2.5 us per period, 1.5 us of it conducting after TIM1's dead time, to refresh the
///   bootstrap capacitor.
pub const IHM08M1: Bridge = Bridge {
    driver: GateDriver::L6398,
    dead_time_ns: 1_000,
    break_active_low: true,
    break_glitch_ns: 400,
    auto_restart: true,
    pwm_hz: 20_000,
    max_duty: 9_500,
};

/// Full scale of a duty in [`Bridge::compare`].
pub const FULL_DUTY: u16 = 10_000;

/// The least time per period the low switch must conduct at the highest duty, so the bootstrap capacitor of the
/// high-side driver is refreshed every period: an engineering margin over the L6398's own 320 ns dead time and
/// its propagation delays, to be confirmed on the scope at first power-up (no bootstrap under-voltage dropouts of
/// the high-side gate at full duty).
pub const MIN_LOW_SIDE_NS: u32 = 1_000;

/// CCMRx output-compare modes OCxM\[3:0\] (RM0440 TIMx_CCMR1).
const OCM_FORCE_INACTIVE: u32 = 0b0100;
const OCM_PWM1: u32 = 0b0110;

/// The compare register CCRx is preloaded (OCxPE).
const OCPE: u32 = 1 << 3;

/// CR2: capture/compare preloaded control (CCxE, CCxNE, OCxM change at a COM event).
const CCPC: u32 = 1 << 0;

/// CR2.MMS2 = 0111: TRGO2 is OC4REF (RM0440 TIMx_CR2 MMS2\[3:0\]), the ADC's injected trigger for the phase
/// currents ([`Bridge::current_trigger`]).
const MMS2_OC4REF: u32 = 0b0111 << 20;

/// CCMR2's channel 4 (bits 8..=15, OC4M\[3\] at bit 24): PWM mode 1 with its compare preloaded (taken at the
/// update event), so OC4REF is active while the counter is below CCR4. Channel 4 has no pin here (CC4E = 0):
/// OC4REF exists inside the timer all the same (RM0440 TIMx_CCMR2, "Output compare mode").
const CCMR2_CH4_TRIGGER: u32 = (OCPE | (OCM_PWM1 << 4)) << 8;

/// BDTR bits.
const OSSI: u32 = 1 << 10;
const OSSR: u32 = 1 << 11;
const BKE: u32 = 1 << 12;
const BKP: u32 = 1 << 13;
const AOE: u32 = 1 << 14;
const MOE: u32 = 1 << 15;
const BKF_SHIFT: u32 = 16;

/// TIMx_SR: BIF (bit 7), set by hardware when break input 1 goes active (here: the overcurrent comparator on
/// BKIN), and SBIF (bit 13), set by a system break (here: core lockup, flash ECC double error). Both stay set
/// until software clears them (RM0440 TIMx_SR; "Using the break function"). With AOE = 1 the outputs come back
/// at the next update event, so BIF is the only trace a cycle-by-cycle trip leaves.
pub const SR_BIF: u32 = 1 << 7;
pub const SR_SBIF: u32 = 1 << 13;

/// What to write to SR to clear BIF and SBIF alone: SR's flags are rc_w0 (writing 0 clears a flag, 1 leaves it),
/// so every other bit is written 1 and no flag the hardware sets meanwhile is lost (RM0440 TIMx_SR; ST's HAL
/// clears a timer flag the same way, `__HAL_TIM_CLEAR_FLAG` writing `~flag`).
pub const SR_CLEAR_BREAK: u32 = !(SR_BIF | SR_SBIF);

/// Whether an SR value says break input 1 tripped (BIF). SBIF is not an overcurrent: its sources here end in a
/// reset, so it is cleared and not counted.
pub const fn break_tripped(sr: u32) -> bool {
    sr & SR_BIF != 0
}

/// EGR: generate a COM event.
pub const EGR_COMG: u32 = 1 << 5;

/// AF1: the BKIN pin feeds break input 1 (BKINE, its reset value), not inverted (BKINP = 0); the polarity is
/// BDTR.BKP's.
pub const AF1: u32 = 1 << 0;

/// SYSCFG_CFGR2: the core's LOCKUP output (CLL) and a flash ECC double error (ECCL) trip TIM1's break as system
/// break sources, so every switch goes off in hardware when no handler can run: a fault while stacking an
/// exception (a stack overflow below RAM, flip-link's layout) locks the core up, and the watchdog would bite only
/// 250 ms later. Both bits hold until a system reset (RM0440 SYSCFG_CFGR2; TIM1 break: system break sources).
pub const SYSCFG_CFGR2: u32 = 1 << 0 | 1 << 3;

/// DBGMCU_APB2FZR: DBG_TIM1_STOP. While a debugger halts the core, TIM1's counter stops and its outputs are
/// disabled as if MOE were cleared, to the idle levels OSSI = 1 gives them ([`Bridge::bdtr`]: every switch off):
/// a breakpoint during bring-up never leaves a phase conducting in its last step (RM0440 DBGMCU_APB2FZR; TIM1
/// "Debug mode"). Without a debugger the bit changes nothing.
pub const DBGMCU_APB2FZR: u32 = 1 << 11;

/// CCMRx, CCER of one commutation step; written while CR2.CCPC = 1, they take effect together at the COM event
/// (`EGR = EGR_COMG`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Commutation {
    /// CCMR1 (output mode): channels 1 and 2.
    pub ccmr1: u32,
    /// CCMR2 (output mode): channel 3, and channel 4 as the current trigger.
    pub ccmr2: u32,
    /// CCER.
    pub ccer: u32,
}

/// Bits of one output-compare channel in a CCMR register, for the low (`upper = false`) or high half: OCxM\[2:0\]
/// at bits 4..6, OCxM\[3\] at bit 16, OCxPE at bit 3; the high half is the same 8 bits up. CCxS = 00 (output).
const fn ccmr_channel(mode: PhaseMode, upper: bool) -> u32 {
    let ocm = match mode {
        PhaseMode::Switching => OCM_PWM1,
        PhaseMode::LowOn | PhaseMode::Off => OCM_FORCE_INACTIVE,
    };
    let bits = OCPE | ((ocm & 0b111) << 4) | ((ocm >> 3) << 16);
    if upper { bits << 8 } else { bits }
}

/// CCER nibble of one channel: CCxE, CCxP, CCxNE, CCxNP at bits 0..=3.
const fn ccer_channel(mode: PhaseMode, driver: &GateDriver) -> u32 {
    let (enable, enable_n) = match mode {
        PhaseMode::Switching | PhaseMode::LowOn => (true, true),
        PhaseMode::Off => (true, false),
    };
    (enable as u32) | ((driver.ccp() as u32) << 1) | ((enable_n as u32) << 2) | ((driver.ccnp() as u32) << 3)
}

/// Dead-time ticks of a BDTR.DTG value, in t_DTS (RM0440 TIMx_BDTR DTG\[7:0\]):
/// 0xx: DTG; 10x: (64 + DTG\[5:0\]) * 2; 110: (32 + DTG\[4:0\]) * 8; 111: (32 + DTG\[4:0\]) * 16.
pub const fn dead_time_ticks(dtg: u8) -> u32 {
    let dtg = dtg as u32;
    if dtg & 0x80 == 0 {
        dtg
    } else if dtg & 0xC0 == 0x80 {
        (64 + (dtg & 0x3F)) * 2
    } else if dtg & 0xE0 == 0xC0 {
        (32 + (dtg & 0x1F)) * 8
    } else {
        (32 + (dtg & 0x1F)) * 16
    }
}

/// The DTG value giving the shortest dead time of at least `ticks` t_DTS; `None` above 1008 ticks.
pub const fn dtg_at_least(ticks: u32) -> Option<u8> {
    let mut best: Option<u8> = None;
    let mut dtg: u32 = 0;
    while dtg <= 0xFF {
        let t = dead_time_ticks(dtg as u8);
        if t >= ticks {
            best = match best {
                Some(b) if dead_time_ticks(b) <= t => Some(b),
                _ => Some(dtg as u8),
            };
        }
        dtg += 1;
    }
    best
}

/// Length of the break filter BKF in t_CK_INT with t_DTS = t_CK_INT (CR1.CKD = 00): the sampling divider times
/// the N samples that must agree (RM0440 TIMx_BDTR BKF\[3:0\]); 0 for no filter.
pub const fn break_filter_ticks(bkf: u8) -> u32 {
    match bkf & 0x0F {
        0 => 0,
        1 => 2,
        2 => 4,
        3 => 8,
        4 => 2 * 6,
        5 => 2 * 8,
        6 => 4 * 6,
        7 => 4 * 8,
        8 => 8 * 6,
        9 => 8 * 8,
        10 => 16 * 5,
        11 => 16 * 6,
        12 => 16 * 8,
        13 => 32 * 5,
        14 => 32 * 6,
        _ => 32 * 8,
    }
}

/// The shortest break filter at least `ticks` long; `None` above 256 ticks.
pub const fn break_filter_at_least(ticks: u32) -> Option<u8> {
    let mut best: Option<u8> = None;
    let mut bkf: u8 = 0;
    while bkf <= 0x0F {
        let t = break_filter_ticks(bkf);
        if t >= ticks {
            best = match best {
                Some(b) if break_filter_ticks(b) <= t => Some(b),
                _ => Some(bkf),
            };
        }
        bkf += 1;
    }
    best
}

/// `ns` in ticks of a `hz` clock, rounded up.
pub const fn ns_to_ticks(ns: u32, hz: u32) -> u32 {
    (ns as u64 * hz as u64).div_ceil(1_000_000_000) as u32
}

/// `ticks` of a `hz` clock in ns, rounded down.
pub const fn ticks_to_ns(ticks: u32, hz: u32) -> u32 {
    (ticks as u64 * 1_000_000_000 / hz as u64) as u32
}

impl Bridge {
    /// The step's CCMR1, CCMR2 and CCER for phases A, B, C on channels 1, 2, 3.
    pub const fn commutation(&self, modes: [PhaseMode; 3]) -> Commutation {
        let [a, b, c] = modes;
        Commutation {
            ccmr1: ccmr_channel(a, false) | ccmr_channel(b, true),
            ccmr2: ccmr_channel(c, false) | CCMR2_CH4_TRIGGER,
            ccer: ccer_channel(a, &self.driver)
                | (ccer_channel(b, &self.driver) << 4)
                | (ccer_channel(c, &self.driver) << 8),
        }
    }

    /// Every phase off: the state after reset, a fault or a stop.
    pub const fn off(&self) -> Commutation {
        self.commutation([PhaseMode::Off; 3])
    }

    /// CR2: CCPC = 1 (commutation through COM events, COMG only: CCUS = 0), the idle levels with MOE = 0 equal
    /// to each output's inactive level (OISx = CCxP, OISxN = CCxNP), and TRGO2 = OC4REF for the ADC.
    pub const fn cr2(&self) -> u32 {
        let ois = self.driver.ccp() as u32;
        let oisn = self.driver.ccnp() as u32;
        let pair = ois | (oisn << 1);
        CCPC | (pair << 8) | (pair << 10) | (pair << 12) | MMS2_OC4REF
    }

    /// CCR4 for a switching phase's CCRx `compare` with ARR `arr`: where the ADC converts the phase currents.
    ///
    /// TRGO2 = OC4REF in PWM mode 1 rises when the counter, coming down, reaches CCR4 (RM0440 28.3.12: active
    /// while CNT < CCRx counting up, while CNT <= CCRx counting down; the up-count runs 0..ARR - 1, the down-count
    /// ARR..1). CCR4 = 1 puts the edge one tick before the bottom of the period, the middle of the high switch's
    /// on-time; CCR4 = ARR - 1 one tick after the top, the middle of its off-time (with CCR4 = ARR, OC4REF would
    /// never fall: no edge). Whichever half is the longer keeps the conversions furthest from the switching edges:
    /// the bottom from 50 % duty up, else the top. The shunt of the phase held low carries the motor current
    /// through both halves, and the nearest edge is [`Bridge::sample_window_ticks`] away or more.
    pub const fn current_trigger(&self, compare: u16, arr: u16) -> u16 {
        if 2 * compare as u32 >= arr as u32 {
            1
        } else {
            arr.saturating_sub(1)
        }
    }

    /// Ticks from the current trigger to the nearest switching edge at the worst duty (just under 50 %): about a
    /// quarter of the period. The ADC's injected sequence must end well inside it
    /// (`g431_hw::adc::CURRENT_SEQUENCE_NS`).
    pub const fn sample_window_ticks(&self, tim_hz: u32) -> u32 {
        self.arr(tim_hz) / 2 - 1
    }

    /// DTG for the bridge's dead time at a `tim_hz` timer clock; 0 when it does not fit (caught by
    /// [`Bridge::is_valid`]).
    pub const fn dtg(&self, tim_hz: u32) -> u8 {
        match dtg_at_least(ns_to_ticks(self.dead_time_ns, tim_hz)) {
            Some(dtg) => dtg,
            None => 0,
        }
    }

    /// BKF for the bridge's glitch length at a `tim_hz` timer clock; 0 (no filter) when none is long enough
    /// (caught by [`Bridge::is_valid`]).
    pub const fn bkf(&self, tim_hz: u32) -> u8 {
        match break_filter_at_least(ns_to_ticks(self.break_glitch_ns, tim_hz)) {
            Some(bkf) => bkf,
            None => 0,
        }
    }

    /// BDTR as configured, outputs not yet enabled (MOE = 0): dead time, OSSI = OSSR = 1 (off and idle states
    /// driven), break 1 enabled with its polarity and filter, AOE per `auto_restart`, LOCK = 0 (embassy-stm32's
    /// constructor writes BDTR first, and RM0440 lets LOCK be written only once after reset).
    pub const fn bdtr(&self, tim_hz: u32) -> u32 {
        let polarity = if self.break_active_low { 0 } else { BKP };
        let restart = if self.auto_restart { AOE } else { 0 };
        self.dtg(tim_hz) as u32 | OSSI | OSSR | BKE | polarity | restart | ((self.bkf(tim_hz) as u32) << BKF_SHIFT)
    }

    /// BDTR with the outputs stopped for good: MOE = 0 (idle levels, both switches off) and AOE = 0 so that no
    /// update event re-enables them. For the panic and fault handlers, and a sustained overcurrent (AOE cleared,
    /// a break no longer ends at the next update event: RM0440 TIMx_BDTR AOE, MOE).
    pub const fn bdtr_stopped(&self, tim_hz: u32) -> u32 {
        self.bdtr(tim_hz) & !(AOE | MOE)
    }

    /// BDTR after a sustained overcurrent has been cleared: [`Bridge::bdtr`] again, AOE = 1 and MOE = 0, so the
    /// outputs come back at the next update event, and only once the break input is inactive (RM0440 TIMx_BDTR
    /// AOE; "Using the break function": MOE cannot be set while the break input is active). As at start-up.
    pub const fn bdtr_restarted(&self, tim_hz: u32) -> u32 {
        self.bdtr(tim_hz)
    }

    /// BDTR with the outputs enabled (MOE = 1).
    pub const fn bdtr_armed(&self, tim_hz: u32) -> u32 {
        self.bdtr(tim_hz) | MOE
    }

    /// ARR of center-aligned PWM at the bridge's frequency: the counter runs 0..ARR..0 once per period.
    pub const fn arr(&self, tim_hz: u32) -> u32 {
        tim_hz / (2 * self.pwm_hz)
    }

    /// CCRx for a duty in 1/10 000 (0..=10 000) with ARR `arr`: the high switch is on while the counter is below
    /// CCRx (PWM mode 1), so duty = CCR / ARR; capped at `max_duty`.
    pub const fn compare(&self, duty: u16, arr: u16) -> u16 {
        let duty = if duty > self.max_duty { self.max_duty } else { duty };
        (duty as u32 * arr as u32 / FULL_DUTY as u32) as u16
    }

    /// Whether every value fits its register and the stage's limits hold at `tim_hz`: the dead time is encodable,
    /// a break filter long enough exists and still reacts within a microsecond, the PWM period fits the 16-bit
    /// counter, and at the highest duty the low switch conducts at least [`MIN_LOW_SIDE_NS`] per period.
    pub const fn is_valid(&self, tim_hz: u32) -> bool {
        if dtg_at_least(ns_to_ticks(self.dead_time_ns, tim_hz)).is_none() {
            return false;
        }
        let Some(bkf) = break_filter_at_least(ns_to_ticks(self.break_glitch_ns, tim_hz)) else {
            return false;
        };
        let arr = self.arr(tim_hz);
        if arr == 0 || arr > 0xFFFF || self.max_duty > FULL_DUTY || bkf == 0 {
            return false;
        }
        ticks_to_ns(break_filter_ticks(bkf), tim_hz) <= 1_000
            && ticks_to_ns(self.low_side_ticks(tim_hz), tim_hz) >= MIN_LOW_SIDE_NS
    }

    /// Ticks per period the low switch conducts at the highest duty: the counter spends 2 * (ARR - CCR) ticks at
    /// or above CCR per center-aligned period, and the low switch turns on a dead time after the high one turns
    /// off.
    pub const fn low_side_ticks(&self, tim_hz: u32) -> u32 {
        let arr = self.arr(tim_hz);
        let ccr = self.compare(FULL_DUTY, arr as u16) as u32;
        (2 * (arr - ccr)).saturating_sub(dead_time_ticks(self.dtg(tim_hz)))
    }
}

#[cfg(test)]
mod tests;
