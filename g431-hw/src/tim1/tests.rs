//! TIM1's values checked against a model of its output stage (RM0440) driving a model of the L6398, and against
//! the register layouts of stm32-metapac (generated from ST's SVD files).

use super::*;
use stm32_metapac::dbgmcu::regs::Apb2fzr;
use stm32_metapac::syscfg::regs::Cfgr2;
use stm32_metapac::timer::regs::{Af1Adv, BdtrAdv, CcerAdv, CcmrOutputGp16, Cr2Adv, EgrAdv, SrAdv};
use stm32_metapac::timer::vals::{Bkp, FilterValue, Mms2, Ocm, Ossi, Ossr};

const TIM_HZ: u32 = 170_000_000;

/// A pin as the gate driver sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Level {
    High,
    Low,
    /// Not driven by the timer.
    Floating,
}

fn level(high: bool) -> Level {
    if high { Level::High } else { Level::Low }
}

/// What OCxREF does during the instant examined.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ref {
    /// Active (counter below CCR in PWM mode 1).
    Active,
    /// Inactive.
    Inactive,
    /// Inside a dead time: both delayed references inactive.
    DeadTime,
}

/// The register fields that decide one channel pair's outputs.
struct Channel {
    cce: bool,
    ccp: bool,
    ccne: bool,
    ccnp: bool,
    /// OCxM forces the reference inactive.
    forced_inactive: bool,
    ois: bool,
    oisn: bool,
}

fn channel(commutation: Commutation, cr2: u32, index: u32) -> Channel {
    let nibble = commutation.ccer >> (4 * index);
    let ccmr = if index < 2 {
        commutation.ccmr1
    } else {
        commutation.ccmr2
    };
    let shift = 8 * (index % 2);
    let ocm = ((ccmr >> (4 + shift)) & 0b111) | (((ccmr >> (16 + shift)) & 1) << 3);
    assert!(ocm == OCM_PWM1 || ocm == OCM_FORCE_INACTIVE, "unexpected OCxM {ocm:#b}");
    Channel {
        cce: nibble & 1 != 0,
        ccp: nibble & 2 != 0,
        ccne: nibble & 4 != 0,
        ccnp: nibble & 8 != 0,
        forced_inactive: ocm == OCM_FORCE_INACTIVE,
        ois: cr2 & (1 << (8 + 2 * index)) != 0,
        oisn: cr2 & (1 << (9 + 2 * index)) != 0,
    }
}

/// OCx and OCxN per RM0440's table "Output control bits for complementary OCx and OCxN channels with break
/// feature" (MOE, OSSI, OSSR, CCxE, CCxNE), the reference being `reference` unless OCxM forces it inactive.
fn outputs(ch: &Channel, bdtr: u32, reference: Ref) -> (Level, Level) {
    let moe = bdtr & MOE != 0;
    let ossi = bdtr & OSSI != 0;
    let ossr = bdtr & OSSR != 0;
    if !moe {
        // Break or MOE cleared: OSSI = 0 floats both; OSSI = 1 drives the idle levels of channels set as outputs
        // (after a dead time, during which the inactive levels CCxP / CCxNP hold). A pair with neither enable bit
        // is modelled floating, the conservative reading.
        if !ossi || !(ch.cce || ch.ccne) {
            return (Level::Floating, Level::Floating);
        }
        return (level(ch.ois), level(ch.oisn));
    }
    let reference = if ch.forced_inactive { Ref::Inactive } else { reference };
    let oc_ref = reference == Ref::Active;
    match (ch.cce, ch.ccne) {
        (false, false) => (Level::Floating, Level::Floating),
        (false, true) => {
            let oc = if ossr { level(ch.ccp) } else { Level::Floating };
            (oc, level(oc_ref ^ ch.ccnp))
        }
        (true, false) => {
            let ocn = if ossr { level(ch.ccnp) } else { Level::Floating };
            (level(oc_ref ^ ch.ccp), ocn)
        }
        (true, true) => {
            // Complementary with dead time: each output rises a dead time after its reference does.
            let (oc_on, ocn_on) = match reference {
                Ref::Active => (true, false),
                Ref::Inactive => (false, true),
                Ref::DeadTime => (false, false),
            };
            (level(oc_on ^ ch.ccp), level(ocn_on ^ ch.ccnp))
        }
    }
}

/// Which switches an L6398 turns on: HIN active high with a pull-down, LIN active low with a pull-up, both asked
/// for at once turns both off (interlock).
fn l6398(hin: Level, lin: Level) -> (bool, bool) {
    let high = hin == Level::High;
    let low = lin == Level::Low;
    (high && !low, low && !high)
}

/// The switches (high on, low on) of phase `index` under BDTR `bdtr`.
fn switches(commutation: Commutation, cr2: u32, bdtr: u32, index: u32, reference: Ref) -> (bool, bool) {
    let (hin, lin) = outputs(&channel(commutation, cr2, index), bdtr, reference);
    l6398(hin, lin)
}

const MODES: [PhaseMode; 3] = [PhaseMode::Switching, PhaseMode::LowOn, PhaseMode::Off];
const REFS: [Ref; 3] = [Ref::Active, Ref::Inactive, Ref::DeadTime];

/// Every assignment of modes to the three phases.
fn every_step() -> Vec<[PhaseMode; 3]> {
    let mut steps = Vec::new();
    for a in MODES {
        for b in MODES {
            for c in MODES {
                steps.push([a, b, c]);
            }
        }
    }
    steps
}

#[test]
fn each_mode_drives_the_l6398_as_intended() {
    let bridge = IHM08M1;
    let cr2 = bridge.cr2();
    let armed = bridge.bdtr_armed(TIM_HZ);
    for step in every_step() {
        let commutation = bridge.commutation(step);
        for (index, mode) in step.into_iter().enumerate() {
            let index = index as u32;
            for reference in REFS {
                let got = switches(commutation, cr2, armed, index, reference);
                let want = match (mode, reference) {
                    (PhaseMode::Switching, Ref::Active) => (true, false),
                    (PhaseMode::Switching, Ref::Inactive) => (false, true),
                    (PhaseMode::Switching, Ref::DeadTime) => (false, false),
                    (PhaseMode::LowOn, _) => (false, true),
                    (PhaseMode::Off, _) => (false, false),
                };
                assert_eq!(got, want, "{step:?} phase {index} {reference:?}");
                // Never both on, and the MCU drives both inputs: nothing is left to the driver's pulls.
                let (hin, lin) = outputs(&channel(commutation, cr2, index), armed, reference);
                assert!(
                    hin != Level::Floating && lin != Level::Floating,
                    "{step:?} phase {index} floats"
                );
            }
        }
    }
}

#[test]
fn non_inverted_low_side_outputs_never_turn_a_switch_on() {
    // The defect this replaces: CCxNP = 0 (embassy's default polarity) with an L6398. In PWM the high input asks
    // for its switch exactly when the low input (active low, fed the complement) does too: the interlock keeps
    // both off, and the motor never turns.
    let bridge = Bridge {
        driver: GateDriver {
            high_active_high: true,
            low_active_high: true,
        },
        ..IHM08M1
    };
    let armed = bridge.bdtr_armed(TIM_HZ);
    let commutation = bridge.commutation([PhaseMode::Switching, PhaseMode::LowOn, PhaseMode::Off]);
    for reference in REFS {
        for index in 0..3 {
            let (hin, lin) = outputs(&channel(commutation, bridge.cr2(), index), armed, reference);
            let (high, low) = l6398(hin, lin);
            assert!(!high, "phase {index} {reference:?}");
            // The "low on" phase's low input is driven high: its switch stays off too.
            assert!(!(low && index == 1), "phase {index} {reference:?}");
        }
    }
    assert_ne!(bridge.commutation([PhaseMode::Off; 3]), IHM08M1.off());
}

#[test]
fn a_break_or_a_stop_drives_every_switch_off() {
    let bridge = IHM08M1;
    for bdtr in [bridge.bdtr(TIM_HZ), bridge.bdtr_stopped(TIM_HZ)] {
        assert_eq!(bdtr & MOE, 0);
        for step in every_step() {
            let commutation = bridge.commutation(step);
            for index in 0..3 {
                for reference in REFS {
                    let (hin, lin) = outputs(&channel(commutation, bridge.cr2(), index), bdtr, reference);
                    assert_eq!((hin, lin), (Level::Low, Level::High), "{step:?} phase {index}");
                    assert_eq!(l6398(hin, lin), (false, false));
                }
            }
        }
    }
    // The stopped value cannot come back on by itself: no automatic output enable.
    assert_eq!(bridge.bdtr_stopped(TIM_HZ) & AOE, 0);
    assert_ne!(bridge.bdtr(TIM_HZ) & AOE, 0, "cycle-by-cycle limiting while running");
}

#[test]
fn the_previous_safe_state_floated_the_gate_inputs() {
    // The binding before: OSSI = 0 and a floating phase as CCxE = CCxNE = 0 (embassy's `disable`), OSSR = 1.
    let armed_old = OSSR | BKE | MOE;
    let disabled = Channel {
        cce: false,
        ccp: false,
        ccne: false,
        ccnp: false,
        forced_inactive: false,
        ois: false,
        oisn: false,
    };
    assert_eq!(
        outputs(&disabled, armed_old, Ref::Active),
        (Level::Floating, Level::Floating)
    );
    // And a break with OSSI = 0 floats even an enabled pair.
    let enabled = Channel {
        cce: true,
        ccne: true,
        ..disabled
    };
    assert_eq!(
        outputs(&enabled, armed_old & !MOE, Ref::Active),
        (Level::Floating, Level::Floating)
    );
}

#[test]
fn dead_time_encoding_follows_rm0440() {
    // The four ranges and their steps.
    assert_eq!(dead_time_ticks(0x00), 0);
    assert_eq!(dead_time_ticks(0x7F), 127);
    assert_eq!(dead_time_ticks(0x80), 128);
    assert_eq!(dead_time_ticks(0xBF), 254);
    assert_eq!(dead_time_ticks(0xC0), 256);
    assert_eq!(dead_time_ticks(0xDF), 504);
    assert_eq!(dead_time_ticks(0xE0), 512);
    assert_eq!(dead_time_ticks(0xFF), 1008);
    // The smallest encoding at least as long, for every length up to the maximum.
    for ticks in 0..=1008 {
        let dtg = dtg_at_least(ticks).unwrap();
        let got = dead_time_ticks(dtg);
        assert!(got >= ticks);
        let shorter = (0..=255u8).map(dead_time_ticks).filter(|&t| t >= ticks).min().unwrap();
        assert_eq!(got, shorter, "{ticks}");
    }
    assert_eq!(dtg_at_least(1009), None);
    // 1 us at 170 MHz: 170 ticks, encoded (64 + 21) * 2.
    assert_eq!(IHM08M1.dtg(TIM_HZ), 0x95);
    assert_eq!(ticks_to_ns(dead_time_ticks(0x95), TIM_HZ), 1_000);
}

#[test]
fn the_break_input_is_filtered() {
    let bkf = IHM08M1.bkf(TIM_HZ);
    assert_ne!(bkf, 0, "an unfiltered break input trips on switching noise");
    let length = ticks_to_ns(break_filter_ticks(bkf), TIM_HZ);
    // Rejects the 400 ns glitches, reacts within the microsecond budget: fDTS/16, N = 5, 80 ticks = 470 ns.
    assert!((400..=1_000).contains(&length), "{length} ns");
    assert_eq!(bkf, 0b1010);
    // Every filter code's length, from the RM0440 table.
    let table = [0, 2, 4, 8, 12, 16, 24, 32, 48, 64, 80, 96, 128, 160, 192, 256];
    for (code, ticks) in table.into_iter().enumerate() {
        assert_eq!(break_filter_ticks(code as u8), ticks);
    }
    // The binding before: no filter at all.
    assert!(
        !Bridge {
            break_glitch_ns: 0,
            ..IHM08M1
        }
        .is_valid(TIM_HZ)
    );
    assert!(IHM08M1.is_valid(TIM_HZ));
}

#[test]
fn duty_is_capped_for_the_bootstrap() {
    let arr = IHM08M1.arr(TIM_HZ);
    assert_eq!(arr, 4250);
    let arr = arr as u16;
    assert_eq!(IHM08M1.compare(0, arr), 0);
    assert_eq!(IHM08M1.compare(5_000, arr), 2125);
    assert_eq!(IHM08M1.compare(9_500, arr), 4037);
    assert_eq!(
        IHM08M1.compare(FULL_DUTY, arr),
        4037,
        "100 % is never asked of the stage"
    );
    assert_eq!(IHM08M1.compare(u16::MAX, arr), 4037);
    assert!(IHM08M1.compare(FULL_DUTY, arr) < arr);
    // The low switch still conducts 1.5 us per period at the cap.
    assert_eq!(ticks_to_ns(IHM08M1.low_side_ticks(TIM_HZ), TIM_HZ), 1_505);
    // Without the cap (CCR = ARR) it never does.
    let uncapped = Bridge {
        max_duty: FULL_DUTY,
        ..IHM08M1
    };
    assert_eq!(uncapped.low_side_ticks(TIM_HZ), 0);
    assert!(!uncapped.is_valid(TIM_HZ));
}

#[test]
fn bit_positions_agree_with_the_pac() {
    let bridge = IHM08M1;
    for step in every_step() {
        let ours = bridge.commutation(step);
        let mut ccmr = [CcmrOutputGp16(0), CcmrOutputGp16(0)];
        let mut ccer = CcerAdv(0);
        for (index, mode) in step.into_iter().enumerate() {
            let reg = &mut ccmr[index / 2];
            let n = index % 2;
            reg.set_ocpe(n, true);
            reg.set_ocm(
                n,
                match mode {
                    PhaseMode::Switching => Ocm::PWM_MODE1,
                    _ => Ocm::FORCE_INACTIVE,
                },
            );
            ccer.set_cce(index, true);
            ccer.set_ccp(index, false);
            ccer.set_ccne(index, mode != PhaseMode::Off);
            ccer.set_ccnp(index, true);
        }
        // Channel 4, the ADC's trigger: PWM mode 1, preloaded, no output.
        ccmr[1].set_ocpe(1, true);
        ccmr[1].set_ocm(1, Ocm::PWM_MODE1);
        assert_eq!(
            (ours.ccmr1, ours.ccmr2, ours.ccer),
            (ccmr[0].0, ccmr[1].0, ccer.0),
            "{step:?}"
        );
    }

    let mut cr2 = Cr2Adv(0);
    cr2.set_ccpc(true);
    for n in 0..3 {
        cr2.set_ois(n, false);
        cr2.set_oisn(n, true);
    }
    cr2.set_mms2(Mms2::COMPARE_OC4);
    assert_eq!(bridge.cr2(), cr2.0);

    let mut bdtr = BdtrAdv(0);
    bdtr.set_dtg(0x95);
    bdtr.set_ossi(Ossi::IDLE_LEVEL);
    bdtr.set_ossr(Ossr::IDLE_LEVEL);
    bdtr.set_bke(0, true);
    bdtr.set_bkp(0, Bkp::ACTIVE_LOW);
    bdtr.set_aoe(true);
    bdtr.set_bkf(0, FilterValue::FDTS_DIV16_N5);
    assert_eq!(bridge.bdtr(TIM_HZ), bdtr.0);
    bdtr.set_moe(true);
    assert_eq!(bridge.bdtr_armed(TIM_HZ), bdtr.0);
    bdtr.set_moe(false);
    bdtr.set_aoe(false);
    assert_eq!(bridge.bdtr_stopped(TIM_HZ), bdtr.0);
    // Restarted after a sustained overcurrent: AOE back, MOE left to the next update event.
    bdtr.set_aoe(true);
    assert_eq!(bridge.bdtr_restarted(TIM_HZ), bdtr.0);

    let mut sr = SrAdv(0);
    sr.set_bif(0, true);
    assert_eq!(SR_BIF, sr.0);
    let mut sr = SrAdv(0);
    sr.set_sbif(true);
    assert_eq!(SR_SBIF, sr.0);

    let mut egr = EgrAdv(0);
    egr.set_comg(true);
    assert_eq!(EGR_COMG, egr.0);
    let mut af1 = Af1Adv(0);
    af1.set_bkine(true);
    assert_eq!(AF1, af1.0);

    let mut cfgr2 = Cfgr2(0);
    cfgr2.set_cll(true);
    cfgr2.set_eccl(true);
    assert_eq!(SYSCFG_CFGR2, cfgr2.0);

    let mut freeze = Apb2fzr(0);
    freeze.set_tim1(true);
    assert_eq!(DBGMCU_APB2FZR, freeze.0, "DBG_TIM1_STOP and nothing else");
}

#[test]
fn clearing_the_break_flags_leaves_every_other_flag_of_sr() {
    // SR is rc_w0: a bit written 0 is cleared, one written 1 kept. Every SR value the hardware can hold.
    let write = |sr: u32, value: u32| sr & value;
    for sr in [
        0,
        SR_BIF,
        SR_SBIF,
        SR_BIF | SR_SBIF,
        0x0003_3FFF,
        0x0000_0001,
        0x0000_1E5F,
    ] {
        let after = write(sr, SR_CLEAR_BREAK);
        assert_eq!(after & (SR_BIF | SR_SBIF), 0, "{sr:#x}");
        assert_eq!(after, sr & !(SR_BIF | SR_SBIF), "{sr:#x}: another flag lost");
    }
    assert!(break_tripped(SR_BIF | 1));
    assert!(!break_tripped(SR_SBIF), "a system break is not an overcurrent");
    assert!(!break_tripped(0x0000_0001 | 1 << 8), "nor the update flag or break 2");
}

/// One centre-aligned period of the counter from the top, with its direction: ARR (the first down-count value),
/// down to 0 (the first up-count value), up to ARR - 1 (RM0440 28.3.3, "Center-aligned mode").
fn period(arr: u16) -> Vec<(u16, bool)> {
    let down = (1..=arr).rev().map(|count| (count, true));
    let up = (0..arr).map(|count| (count, false));
    down.chain(up).collect()
}

/// OCxREF in PWM mode 1: active while CNT < CCRx counting up, while CNT <= CCRx counting down (RM0440 28.3.12).
fn pwm1(ccr: u16, (count, down): (u16, bool)) -> bool {
    if down { count <= ccr } else { count < ccr }
}

#[test]
fn the_current_trigger_sits_in_the_middle_of_the_longer_half_of_the_period() {
    let bridge = IHM08M1;
    let arr = bridge.arr(TIM_HZ) as u16;
    let ticks = period(arr);
    let n = ticks.len();
    for duty in (0..=FULL_DUTY).step_by(50) {
        let compare = bridge.compare(duty, arr);
        let ccr4 = bridge.current_trigger(compare, arr);
        // OC4REF's rising edges over the period (cyclically): exactly one, and it is the trigger.
        let rises: Vec<usize> = (0..n)
            .filter(|&i| pwm1(ccr4, ticks[i]) && !pwm1(ccr4, ticks[(i + n - 1) % n]))
            .collect();
        assert_eq!(rises.len(), 1, "duty {duty}: {rises:?}");
        let at = rises[0];
        // The high switch (OC1REF) is on at the trigger from 50 % duty up, off below; its nearest edge, before
        // or after, is at least the window away.
        let high = |i: usize| pwm1(compare, ticks[i % n]);
        assert_eq!(high(at), 2 * u32::from(compare) >= u32::from(arr), "duty {duty}");
        let edges: Vec<usize> = (0..n).filter(|&i| high(i) != high(i + n - 1)).collect();
        let nearest = edges
            .iter()
            .map(|&edge| (edge + n - at) % n)
            .map(|ahead| ahead.min(n - ahead))
            .min()
            .unwrap_or(n);
        assert!(
            nearest as u32 >= bridge.sample_window_ticks(TIM_HZ),
            "duty {duty}: {nearest} ticks to an edge"
        );
    }
}

#[test]
fn the_phase_currents_are_converted_well_inside_the_window() {
    let window_ns = ticks_to_ns(IHM08M1.sample_window_ticks(TIM_HZ), TIM_HZ);
    assert_eq!(window_ns, 12_494);
    assert!(crate::adc::CURRENT_SEQUENCE_NS < f64::from(window_ns) / 2.0);
}
