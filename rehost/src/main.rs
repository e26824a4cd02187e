//! The register-level run's reference: what each firmware image must leave in the G431's registers after start-up
//! (computed by `g431-hw` from the reference manual's rules), the pins it may touch, and tmc-proto's encodings,
//! printed as JSON for the tests in `rehost/tests`, which run the images on the Unicorn engine.
//!
//! `rehost expected` prints everything, the boards' partitions and what their bootloader reads and writes there
//! among it; `rehost status FAMILY HEX` decodes a status frame the thruster image sent, `rehost order FAMILY HEX`
//! an order the master image sent; `rehost update FAMILY` gives a field update for that family's thruster (a
//! payload signed with the development key, and the extension's commands that finish it, with a good and a bad
//! signature), `rehost reply HEX` decodes an extension reply the thruster image sent; `rehost sign SEED` signs the
//! payload it reads (hex) on its standard input with that secret key, as `lbv image sign` does, and gives the key's
//! public half and the ticket an application writes for it.

use std::io::Read;
use std::process::ExitCode;

use g431_hw::clock::{self, registers as rcc};
use g431_hw::memory::{self, Partitions, Span};
use g431_hw::pins::{Mode, Pull};
use g431_hw::tim1::{IHM08M1 as BRIDGE, PhaseMode};
use g431_hw::{adc, fdcan, i2c, images, iwdg};
use serde_json::{Value, json};
use thruster_fw::commutation::{BridgeDrive, PhaseDrive, drive_for};
use thruster_fw::hall::FORWARD_SEQUENCE;
use thruster_fw::{Direction, Duty};
use tmc_proto::ext::{self, Command, CommandFrame, Reply};
use tmc_proto::{Family, Order, Speed, Status};
use update_image::{
    HEADER_LEN, INFO_OFFSET, ImageInfo, KEY_LEN, KEY_OFFSET, MIN_PAYLOAD, SLOTS, TICKET_OFFSET, TOLD_OFFSET, Target,
    Ticket, VERDICT_OFFSET, Verdict, Version, key_from_hex,
};

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.iter().map(String::as_str).collect::<Vec<_>>().as_slice() {
        ["expected"] => Ok(expected()),
        ["status", family, hex] => family_of(family).and_then(|family| decode_status(family, hex)),
        ["order", family, hex] => family_of(family).and_then(|family| decode_order(family, hex)),
        ["update", "master"] => master_update(),
        ["update", family] => family_of(family).and_then(update),
        ["reply", hex] => decode_reply(hex),
        ["sign", seed] => sign_stdin(seed),
        _ => Err(
            "usage: rehost expected | rehost status FAMILY HEX | rehost order FAMILY HEX | rehost update FAMILY \
             | rehost update master | rehost reply HEX | rehost sign SEED < PAYLOAD_HEX"
                .to_string(),
        ),
    };
    match result {
        Ok(value) => {
            println!("{value}");
            ExitCode::SUCCESS
        }
        Err(error) => {
            eprintln!("rehost: {error}");
            ExitCode::FAILURE
        }
    }
}

fn family_of(name: &str) -> Result<Family, String> {
    match name {
        "seabotix" => Ok(Family::SeaBotix),
        "legacy" => Ok(Family::Legacy),
        _ => Err(format!("unknown family {name:?}: seabotix or legacy")),
    }
}

fn bytes_of(hex: &str) -> Result<Vec<u8>, String> {
    if hex.len() > 2 * ext::MAX_FRAME_LEN {
        return Err(format!("{hex:?} is longer than a frame"));
    }
    hex_bytes(hex)
}

fn hex_bytes(hex: &str) -> Result<Vec<u8>, String> {
    if !hex.len().is_multiple_of(2) {
        return Err(format!("{} hex digits: not whole bytes", hex.len()));
    }
    (0..hex.len())
        .step_by(2)
        .map(|i| {
            hex.get(i..i + 2)
                .and_then(|pair| u8::from_str_radix(pair, 16).ok())
                .ok_or_else(|| format!("{hex:?} is not hex"))
        })
        .collect()
}

/// One register expectation: `value` under `mask` at `address`.
fn register(name: &str, address: u32, mask: u32, value: u32, source: &str) -> Value {
    json!({ "name": name, "address": address, "mask": mask, "value": value & mask, "source": source })
}

/// The clock tree both images set up (RM0440 7.4, 3.7.1).
fn clock_registers(ccipr: &[(u32, u32)]) -> Vec<Value> {
    const RCC: u32 = 0x4002_1000;
    let mut out = vec![
        register(
            "RCC_PLLCFGR",
            RCC + 0x0C,
            0x07FF_7FF3,
            rcc::PLLCFGR,
            "g431_hw::clock::registers::PLLCFGR",
        ),
        register(
            "RCC_CFGR.SWS",
            RCC + 0x08,
            0b1100,
            rcc::SW_PLL << 2,
            "g431_hw::clock::registers::SW_PLL",
        ),
        register(
            "RCC_CFGR.HPRE/PPRE1/PPRE2",
            RCC + 0x08,
            rcc::CFGR_PRESCALERS,
            rcc::CFGR_BOOSTED,
            "g431_hw::clock::registers::CFGR_BOOSTED",
        ),
        register(
            "FLASH_ACR.LATENCY",
            0x4002_2000,
            0xF,
            rcc::LATENCY,
            "g431_hw::clock::registers::LATENCY",
        ),
    ];
    for &(shift, value) in ccipr {
        out.push(register(
            &format!("RCC_CCIPR[{}:{shift}]", shift + 1),
            RCC + 0x88,
            0b11 << shift,
            value << shift,
            "g431_hw::clock::registers",
        ));
    }
    out
}

fn pins(image: &g431_hw::pins::Image) -> Vec<Value> {
    image
        .uses
        .iter()
        .map(|used| {
            let (mode, af, pull, open_drain, channel) = match used.mode {
                Mode::Alternate { af, pull, .. } => ("alternate", af, pull, false, None),
                Mode::AlternateOpenDrain { af, .. } => ("alternate", af, Pull::None, true, None),
                Mode::Input(pull) => ("input", 0, pull, false, None),
                Mode::Analog { adc1_in } => ("analog", 0, Pull::None, false, Some(adc1_in)),
                Mode::Output { .. } => ("output", 0, Pull::None, false, None),
            };
            let level = match used.mode {
                Mode::Output { high } => Some(u8::from(high)),
                _ => None,
            };
            let pull = match pull {
                Pull::None => "none",
                Pull::Up => "up",
                Pull::Down => "down",
            };
            json!({
                "port": used.pin.port.letter().to_string(), "pin": used.pin.number, "function": used.function,
                "mode": mode, "af": af, "pull": pull, "open_drain": open_drain, "adc1_in": channel, "level": level,
            })
        })
        .collect()
}

/// The interrupts whose priority the image's description sets, with the NVIC level (`P1` is 1).
fn interrupts(image: &g431_hw::pins::Image) -> Vec<Value> {
    image
        .interrupts
        .iter()
        .map(|interrupt| {
            let level = interrupt.priority.trim_start_matches('P').parse::<u8>().ok();
            json!({ "name": interrupt.name, "priority": level, "function": interrupt.function })
        })
        .collect()
}

/// CCMR1, CCMR2, CCER of a bridge drive, as the binding maps it onto `g431_hw::tim1`.
fn commutation(drive: BridgeDrive) -> Value {
    let step = BRIDGE.commutation(drive.map(|phase| match phase {
        PhaseDrive::Pwm => PhaseMode::Switching,
        PhaseDrive::Low => PhaseMode::LowOn,
        PhaseDrive::Float => PhaseMode::Off,
    }));
    json!({ "ccmr1": step.ccmr1, "ccmr2": step.ccmr2, "ccer": step.ccer })
}

fn thruster(image: &g431_hw::pins::Image, family: Family, power_stage: bool) -> Value {
    const TIM1: u32 = 0x4001_2C00;
    const I2C3: u32 = 0x4000_7800;
    const IWDG: u32 = 0x4000_3000;
    const DBGMCU: u32 = 0xE004_2000;
    let config = &thruster_fw::CONFIG;
    let schedule = config.watchdog.schedule(&config.bus);
    let watchdog = schedule.check().unwrap_or(iwdg::Iwdg { pr: 0, rlr: 0 });
    let mut registers = clock_registers(&[(rcc::I2C3SEL, rcc::I2C_HSI16), (rcc::ADC12SEL, rcc::ADC_SYSCLK)]);
    registers.extend([
        register(
            "I2C3_TIMINGR",
            I2C3 + 0x10,
            u32::MAX,
            i2c::TIMINGR,
            "g431_hw::i2c::TIMINGR",
        ),
        register(
            "I2C3_OAR1",
            I2C3 + 0x08,
            0xFFFF,
            i2c::oar1(family.address()),
            "g431_hw::i2c::oar1",
        ),
        register(
            "IWDG_PR",
            IWDG + 0x04,
            0x7,
            watchdog.pr.into(),
            "CONFIG.watchdog via g431_hw::iwdg",
        ),
        register(
            "IWDG_RLR",
            IWDG + 0x08,
            0xFFF,
            watchdog.rlr.into(),
            "CONFIG.watchdog via g431_hw::iwdg",
        ),
        register(
            "DBGMCU_APB1FZR1",
            DBGMCU + 0x08,
            iwdg::DBGMCU_APB1FZR1,
            iwdg::DBGMCU_APB1FZR1,
            "g431_hw::iwdg",
        ),
    ]);
    let mut six_step = Vec::new();
    if power_stage {
        let arr = BRIDGE.arr(clock::TIM1_HZ);
        // ADC1: every analog input's sample time, and the phase currents as the injected sequence TIM1 triggers.
        let analog: Vec<(&str, u8)> = image
            .uses
            .iter()
            .filter_map(|used| match used.mode {
                Mode::Analog { adc1_in } => Some((used.function, adc1_in)),
                _ => None,
            })
            .collect();
        let sample = |function: &str| match function {
            "water sensor" => adc::WATER_SAMPLE,
            "supply voltage" => adc::VBUS_SAMPLE,
            f if f.ends_with("current") => adc::CURRENT_SAMPLE,
            _ => adc::NTC_SAMPLE,
        };
        let inputs: Vec<_> = analog
            .iter()
            .map(|&(function, channel)| (channel, sample(function)))
            .collect();
        let [smpr1, smpr2] = adc::smpr(&inputs);
        let phase = |name: &str| {
            analog
                .iter()
                .find(|(function, _)| *function == name)
                .map_or(0, |&(_, channel)| channel)
        };
        let currents = [
            phase("phase A current"),
            phase("phase B current"),
            phase("phase C current"),
        ];
        const ADC1: u32 = 0x5000_0000;
        registers.extend([
            register("ADC1_SMPR1", ADC1 + 0x14, 0x07FF_FFFF, smpr1, "g431_hw::adc::smpr"),
            register("ADC1_SMPR2", ADC1 + 0x18, 0x07FF_FFFF, smpr2, "g431_hw::adc::smpr"),
            register(
                "ADC1_JSQR",
                ADC1 + 0x4C,
                u32::MAX,
                adc::jsqr(currents),
                "g431_hw::adc::jsqr",
            ),
        ]);
        registers.extend([
            register("TIM1_ARR", TIM1 + 0x2C, 0xFFFF, arr, "g431_hw::tim1::IHM08M1.arr"),
            register("TIM1_PSC", TIM1 + 0x28, 0xFFFF, 0, "centre-aligned 20 kHz from 170 MHz"),
            // CEN, CMS = 0b11 (centre-aligned mode 3: compare flags both ways), CKD = 0 (t_DTS = t_CK_INT).
            register("TIM1_CR1", TIM1, 0x0371, 0x0061, "centre-aligned, counting"),
            register(
                "TIM1_CR2",
                TIM1 + 0x04,
                u32::MAX,
                BRIDGE.cr2(),
                "g431_hw::tim1::IHM08M1.cr2",
            ),
            register(
                "TIM1_BDTR",
                TIM1 + 0x44,
                u32::MAX,
                BRIDGE.bdtr_armed(clock::TIM1_HZ),
                "g431_hw::tim1::IHM08M1.bdtr_armed",
            ),
            register(
                "TIM1_AF1",
                TIM1 + 0x60,
                u32::MAX,
                g431_hw::tim1::AF1,
                "g431_hw::tim1::AF1",
            ),
            register(
                "SYSCFG_CFGR2",
                0x4001_0000 + 0x1C,
                0xF,
                g431_hw::tim1::SYSCFG_CFGR2,
                "g431_hw::tim1",
            ),
            register(
                "DBGMCU_APB2FZR",
                DBGMCU + 0x10,
                g431_hw::tim1::DBGMCU_APB2FZR,
                g431_hw::tim1::DBGMCU_APB2FZR,
                "g431_hw::tim1",
            ),
        ]);
        let quarter = Duty::new_saturating(i32::from(g431_hw::tim1::FULL_DUTY) / 4);
        for state in FORWARD_SEQUENCE {
            let drive = drive_for(state, quarter);
            // What each phase's switches must do, for the tests that read the gate pins rather than the registers.
            let phases = drive.map(|phase| match phase {
                PhaseDrive::Pwm => "pwm",
                PhaseDrive::Low => "low",
                PhaseDrive::Float => "float",
            });
            six_step.push(json!({ "hall": state.bits(), "drive": commutation(drive), "phases": phases }));
        }
    }
    // Readings that put the sensors at a working point, and past the IDS's fault thresholds (IDS 8.4.2).
    let analog = json!({
        "dry": config.water.raw_at(10 * config.thresholds.water_ohms),
        "wet": config.water.raw_at(config.thresholds.water_ohms / 10),
        "ntc_25c": config.ntc.raw_at(250),
        "ntc_hot": config.ntc.raw_at(config.thresholds.overtemp_set_decicelsius + 50),
        "current_zero": config.current.offset_raw,
        "current_milliamps_per_count": config.current.milliamps_per_count,
        "vbus_24v": config.vbus.raw_at(24_000),
    });
    json!({
        "kind": "thruster",
        "family": family.name(),
        "address": family.address(),
        "pins": pins(image),
        "interrupts": interrupts(image),
        "registers": registers,
        "coast": commutation(thruster_fw::commutation::COAST),
        "forward": six_step,
        "sample_times": {
            "water": adc::WATER_SAMPLE.bits(), "ntc": adc::NTC_SAMPLE.bits(), "current": adc::CURRENT_SAMPLE.bits(),
            "vbus": adc::VBUS_SAMPLE.bits(),
        },
        "watchdog_timeout_us": watchdog.timeout_us(clock::LSI_HZ),
        "watchdog_feed_us": schedule.feed_period_us,
        "analog": analog,
        "pole_pairs": config.pole_pairs,
    })
}

fn master(image: &g431_hw::pins::Image) -> Value {
    let config = &lbv_master_fw::CONFIG;
    let can = fdcan::nominal(
        clock::FDCAN_KERNEL_HZ,
        config.can_bitrate,
        fdcan::SAMPLE_POINT_PERMILLE,
        fdcan::BUS_DELAY_NS,
    )
    .map(|timing| timing.nbtp())
    .unwrap_or(0);
    let mut registers = clock_registers(&[
        (rcc::I2C1SEL, rcc::I2C_HSI16),
        (rcc::I2C2SEL, rcc::I2C_HSI16),
        (rcc::I2C3SEL, rcc::I2C_HSI16),
        (rcc::FDCANSEL, rcc::FDCAN_HSE),
    ]);
    for (name, base) in [("I2C1", 0x4000_5400u32), ("I2C2", 0x4000_5800), ("I2C3", 0x4000_7800)] {
        registers.push(register(
            &format!("{name}_TIMINGR"),
            base + 0x10,
            u32::MAX,
            i2c::TIMINGR,
            "g431_hw::i2c",
        ));
    }
    registers.push(register(
        "FDCAN1_NBTP",
        0x4000_6400 + 0x1C,
        u32::MAX,
        can,
        "g431_hw::fdcan::nominal",
    ));
    json!({
        "kind": "master",
        "pins": pins(image),
        "interrupts": interrupts(image),
        "registers": registers,
        "console_baud": config.console_baud,
        "can_bitrate": config.can_bitrate,
        "watchdog_feed_us": iwdg::MASTER_SCHEDULE.feed_period_us,
    })
}

/// Orders the tests send or expect, in both families.
fn orders() -> Value {
    let mut out = serde_json::Map::new();
    for family in [Family::SeaBotix, Family::Legacy] {
        let mut by_step = serde_json::Map::new();
        for step in [0i8, 25, -25, 63, -63] {
            if let Some(speed) = Speed::new(step) {
                let bytes = Order::new(speed).encode(family);
                by_step.insert(step.to_string(), json!(bytes));
            }
        }
        out.insert(family.name().to_string(), Value::Object(by_step));
    }
    Value::Object(out)
}

/// A thruster at rest in each family, as tmc-proto encodes it: what the master's modelled thrusters answer.
fn statuses() -> Value {
    let seabotix = tmc_proto::SeaBotixStatus {
        revision: 0,
        motor: tmc_proto::MotorKind::Brushless,
        current_limited: false,
        faults: tmc_proto::Faults::NONE,
        current_deciamps: 0,
        speed: Speed::new_saturating(0),
        temperature_c: 25,
    };
    let legacy = tmc_proto::LegacyStatus {
        revision: tmc_proto::LegacyRevision::AVEOX_BRUSHLESS,
        faults: tmc_proto::Faults::NONE,
        max_power: tmc_proto::MaxPower::Current { deciamps: 0 },
    };
    json!({ "SeaBotix": seabotix.encode(), "Legacy": legacy.encode() })
}

fn expected() -> Value {
    json!({
        "images": {
            "thruster-fw": thruster(&images::THRUSTER, Family::SeaBotix, true),
            "thruster-fw-legacy": thruster(&images::THRUSTER, Family::Legacy, true),
            "thruster-fw-brushed": thruster(&images::THRUSTER_BRUSHED, Family::SeaBotix, true),
            "thruster-fw-bringup": thruster(&images::THRUSTER, Family::SeaBotix, true),
            "thruster-fw-motorless": thruster(&images::THRUSTER_MOTORLESS, Family::SeaBotix, false),
            "lbv-master-fw": master(&images::MASTER),
            "lbv-master-fw-devkit": master(&images::MASTER),
            "lbv-master-fw-acceptance": master(&images::MASTER),
        },
        "stack_budgets": images::BUILDS
            .iter()
            .map(|build| (build.name.to_string(), json!(build.stack_budget)))
            .collect::<serde_json::Map<String, Value>>(),
        "orders": orders(),
        "statuses": statuses(),
        "forward_direction": format!("{:?}", Direction::Forward),
        "boot": boot(),
        "crash_region": span(g431_hw::memory::CRASH),
        "black_box": span(g431_hw::memory::BLACK_BOX),
    })
}

fn span(span: Span) -> Value {
    json!({ "origin": span.origin, "length": span.length })
}

fn partitions(partitions: &Partitions) -> Value {
    json!({
        "bootloader": span(partitions.bootloader),
        "state": span(partitions.state),
        "record": span(partitions.record),
        "ticket": span(partitions.ticket()),
        "counter": span(partitions.counter()),
        "active": span(partitions.active),
        "dfu": span(partitions.dfu),
    })
}

/// What the bootloader tests need: each board's partitions (g431_hw::memory), where an image keeps its information
/// record and key and what they hold, where the application's ticket and the bootloader's verdict go in the
/// record's first page (update-image's `bootloader` module) and each verdict's word, the trial watchdog, and the
/// thruster's gate inputs the bootloader holds off.
fn boot() -> Value {
    let verdicts: serde_json::Map<String, Value> = Verdict::ALL
        .into_iter()
        .map(|verdict| {
            (
                format!("{verdict:?}"),
                json!({ "code": verdict.code(), "word": hex(&verdict.to_word()) }),
            )
        })
        .collect();
    let targets: serde_json::Map<String, Value> = Target::ALL
        .into_iter()
        .map(|target| (format!("{target:?}"), json!(target.to_byte())))
        .collect();
    let gates: Vec<Value> = images::THRUSTER_GATES_OFF
        .iter()
        .map(|gates| {
            json!({
                "port": gates.port.letter().to_string(), "bsrr": gates.bsrr, "moder_mask": gates.moder_mask,
                "moder_output": gates.moder_output,
            })
        })
        .collect();
    json!({
        "page": memory::PAGE,
        "write_unit": memory::WRITE_UNIT,
        "thruster": partitions(&memory::THRUSTER_PARTITIONS),
        "master": partitions(&memory::MASTER_PARTITIONS),
        "master_storage": span(memory::MASTER_STORAGE),
        "info_offset": INFO_OFFSET,
        "key_offset": KEY_OFFSET,
        "key_len": KEY_LEN,
        "min_payload": MIN_PAYLOAD,
        "ticket_offset": TICKET_OFFSET,
        "verdict_offset": VERDICT_OFFSET,
        "previous_offset": update_image::PREVIOUS_OFFSET,
        "told_offset": TOLD_OFFSET,
        "slots": SLOTS,
        "verdicts": verdicts,
        "targets": targets,
        "trial": { "pr": iwdg::BOOT_TRIAL.pr, "rlr": iwdg::BOOT_TRIAL.rlr },
        "thruster_gates_off": gates,
        "crash_register": g431_hw::backup::CRASH_REGISTER,
        "early_crashes": update_image::EARLY_CRASHES,
    })
}

fn decode_status(family: Family, hex: &str) -> Result<Value, String> {
    let bytes = bytes_of(hex)?;
    let (decoded, form) = Status::decode_either(family, &bytes).map_err(|error| error.to_string())?;
    let canonical = decoded.status.encode().as_bytes() == bytes.as_slice();
    let fields = match decoded.status {
        Status::SeaBotix(status) => json!({
            "faults": status.faults.bits(), "rpm": status.speed.rpm(), "current_deciamps": status.current_deciamps,
            "temperature_c": status.temperature_c, "revision": status.revision,
            "link_failsafe": tmc_proto::SeaBotixStatus::link_failsafe_in(&bytes),
        }),
        Status::Legacy(status) => json!({
            "faults": status.faults.bits(), "revision": status.revision.number(),
            "max_power": format!("{:?}", status.max_power),
        }),
    };
    Ok(json!({ "form": format!("{form:?}"), "canonical": canonical, "fields": fields }))
}

fn decode_order(family: Family, hex: &str) -> Result<Value, String> {
    let bytes = bytes_of(hex)?;
    let order = Order::decode(family, &bytes).map_err(|error| error.to_string())?;
    Ok(json!({ "step": order.speed.step(), "canonical": order.encode(family).as_slice() == bytes.as_slice() }))
}

/// A field update for a `family` thruster, for the image built with the development key (test.sh builds them so):
/// a 4 KiB payload ([`signed_file`]) signed with keys/dev.key, where it goes (the DFU partition) and where the
/// thruster hands it to its bootloader (the state, the record's ticket page), the extension's `Begin` and `Finish`
/// frames, `Finish` also with a signature one bit off, `Version`, `Reboot` and the two `PostMortem` parts, and the
/// ticket each `Finish` leaves.
fn update(family: Family) -> Result<Value, String> {
    let file = signed_file(Target::thruster(family), memory::THRUSTER_PARTITIONS.active.origin)?;
    let (header, payload) = file.split_at(HEADER_LEN);
    let header = update_image::Header::parse(header).map_err(|error| format!("{error:?}"))?;
    let payload_len = header.payload_len;
    let frame = |seq, command| hex(CommandFrame { seq, command }.encode().as_bytes());
    let mut forged = header.signature;
    if let Some(byte) = forged.first_mut() {
        *byte ^= 1;
    }
    let target = Target::thruster(family).to_byte();
    let ticket = |signature| hex(&Ticket { payload_len, signature }.to_bytes());
    let layout = memory::THRUSTER_PARTITIONS;
    Ok(json!({
        "active": layout.active.origin,
        "dfu": layout.dfu.origin,
        "state": layout.state.origin,
        "ticket_page": layout.ticket().origin,
        "payload": hex(payload),
        "ticket": ticket(header.signature),
        "ticket_forged": ticket(forged),
        "reset_handler": RESET_HANDLER_OFFSET + layout.active.origin,
        "begin": frame(1, Command::Begin { payload_len, target }),
        "finish_forged": frame(2, Command::Finish { payload_len, signature: forged }),
        "finish": frame(3, Command::Finish { payload_len, signature: header.signature }),
        "version": frame(4, Command::Version),
        "reboot": frame(5, Command::Reboot),
        "post_mortem": [frame(6, Command::PostMortem { offset: 0 }), frame(7, Command::PostMortem { offset: 64 })],
        "begin_reply_len": ext::reply_len(ext::CommandKind::Begin),
        "finish_reply_len": ext::reply_len(ext::CommandKind::Finish),
        "version_reply_len": ext::reply_len(ext::CommandKind::Version),
        "reboot_reply_len": ext::reply_len(ext::CommandKind::Reboot),
        "post_mortem_reply_len": ext::reply_len(ext::CommandKind::PostMortem),
        "finish_wait_ms": ext::FINISH_WAIT_MS,
    }))
}

/// A master update file (a 4096-byte payload, [`signed_file`], signed with the development key), the same file with
/// its signature one bit off, the ticket the master writes for the good one, and where the master's DFU, state and
/// ticket page are.
fn master_update() -> Result<Value, String> {
    let file = signed_file(Target::Master, memory::MASTER_PARTITIONS.active.origin)?;
    let (header, _) = file.split_at(HEADER_LEN);
    let header = update_image::Header::parse(header).map_err(|error| format!("{error:?}"))?;
    let ticket = Ticket {
        payload_len: header.payload_len,
        signature: header.signature,
    };
    let mut forged = file.clone();
    // The signature's first byte (the header's offset 16).
    if let Some(byte) = forged.get_mut(16) {
        *byte ^= 1;
    }
    Ok(json!({
        "dfu": memory::MASTER_PARTITIONS.dfu.origin,
        "state": memory::MASTER_PARTITIONS.state.origin,
        "ticket_page": memory::MASTER_PARTITIONS.ticket().origin,
        "ticket": hex(&ticket.to_bytes()),
        "file": hex(&file),
        "forged": hex(&forged),
    }))
}

/// Where an update's made-up image has its reset handler, from its start: just past its image info and key.
const RESET_HANDLER_OFFSET: u32 = MIN_PAYLOAD;

/// An update file for `target`, whose ACTIVE partition starts at `active`: a 4 KiB payload signed with keys/dev.key,
/// laid out as an image: a vector table (an initial stack pointer, the reset handler), the image info (format 2,
/// 0.2.0) and the development public key after it, the reset handler (`b .`), then arbitrary bytes.
fn signed_file(target: Target, active: u32) -> Result<Vec<u8>, String> {
    let mut payload: Vec<u8> = (0..4096u32)
        .map(|n| (n.wrapping_mul(2_654_435_761) >> 9) as u8)
        .collect();
    let seed = key_from_hex(include_str!("../../keys/dev.key")).ok_or("keys/dev.key is not a key")?;
    let record = update_image::image_record(
        ImageInfo::new(target, Version::new(0, 2, 0)),
        &update_image::public_key(&seed),
    );
    // The top of the smaller RAM, the G431's 32 KiB: inside either chip's.
    let stack_pointer = memory::G431RB.ram.end();
    let reset = RESET_HANDLER_OFFSET as usize;
    for (at, bytes) in [
        (0, &stack_pointer.to_le_bytes()[..]),
        (4, &((active + RESET_HANDLER_OFFSET) | 1).to_le_bytes()[..]),
        (INFO_OFFSET, &record[..]),
        // `b .` (ARMv7-M A7.7.12, encoding T2 with offset -4): it stays there.
        (reset, &[0xFE, 0xE7][..]),
    ] {
        payload
            .get_mut(at..at + bytes.len())
            .ok_or("no room in the payload")?
            .copy_from_slice(bytes);
    }
    update_image::sign(&payload, &seed).map_err(|error| format!("{error:?}"))
}

/// The payload on standard input (hex) signed with the secret key `seed` (64 hex digits), as `lbv image sign` signs
/// it: the padded payload's length, its signature, the ticket an application writes for it, and the key's public
/// half (what an image embeds after its information record to take it).
fn sign_stdin(seed: &str) -> Result<Value, String> {
    let seed = key_from_hex(seed).ok_or("the seed is not 64 hex digits")?;
    let mut text = String::new();
    std::io::stdin()
        .read_to_string(&mut text)
        .map_err(|error| error.to_string())?;
    let payload = hex_bytes(text.trim())?;
    let file = update_image::sign(&payload, &seed).map_err(|error| error.to_string())?;
    let header = update_image::Header::parse(&file).map_err(|error| format!("{error:?}"))?;
    let ticket = Ticket {
        payload_len: header.payload_len,
        signature: header.signature,
    };
    Ok(json!({
        "payload_len": header.payload_len,
        "signature": hex(&header.signature),
        "ticket": hex(&ticket.to_bytes()),
        "public_key": hex(&update_image::public_key(&seed)),
    }))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|byte| format!("{byte:02x}")).collect()
}

/// An extension reply: its command, sequence number and result ("done", "busy", or the refusal's name), a
/// `Version` reply's protocol and flags, the bootloader's verdict by its name, and a `PostMortem` reply's part.
fn decode_reply(reply_hex: &str) -> Result<Value, String> {
    let reply = Reply::decode(&bytes_of(reply_hex)?).map_err(|error| error.to_string())?;
    let result = match reply {
        Reply::Done { .. } => "done".to_string(),
        Reply::Busy { .. } => "busy".to_string(),
        Reply::Refused { refusal, .. } => format!("{refusal:?}"),
    };
    let version = match reply {
        Reply::Done {
            body:
                ext::ReplyBody::Version {
                    protocol,
                    on_trial,
                    checks_signatures,
                    marked,
                    dev_key,
                    verdict,
                    ..
                },
            ..
        } => json!({
            "protocol": protocol, "on_trial": on_trial, "checks_signatures": checks_signatures, "marked": marked,
            "dev_key": dev_key, "verdict_code": verdict,
            "verdict": Verdict::from_code(verdict).map(|verdict| format!("{verdict:?}")),
        }),
        _ => Value::Null,
    };
    let post_mortem = match reply {
        Reply::Done {
            body: ext::ReplyBody::PostMortem { len, offset, data },
            ..
        } => json!({ "len": len, "offset": offset, "data": hex(&data) }),
        _ => Value::Null,
    };
    Ok(json!({
        "command": format!("{:?}", reply.command()), "seq": reply.seq(), "result": result, "version": version,
        "post_mortem": post_mortem,
    }))
}
