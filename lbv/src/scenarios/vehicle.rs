//! The vehicle as a whole: a dive from the ground station, the console link dropping, the battery board's frames
//! lost and its status bits switching.

use bat_proto::StatusBit;
use lbv_master_fw::mixer::ManualInput;
use serde_json::json;
use tmc_proto::Family;

use super::fault::Fault;
use super::harness::{AHEAD, Run, round};

pub fn dive(run: &mut Run) {
    run.arm_and_go(AHEAD);
    let acked = run.bench.ground.seen.acks.first().copied();
    run.check(
        "arming accepted",
        acked == Some((400, 0)),
        format!("first COMMAND_ACK {acked:?}"),
    );

    // Console to wire: a new stick position reaches thruster 1's controller.
    let before = run.bench.thrusters[0].shared().link.try_get().map(|link| link.order);
    let latency = run.run_until(0.5, |bench| {
        bench.thrusters[0].shared().link.try_get().map(|link| link.order) != before
    });
    let latency_ms = latency.map(|s| round(s * 1e3, 2));
    run.metric("console_to_wire_latency_ms", json!(latency_ms));
    run.check(
        "stick reaches the thruster within 40 ms",
        latency.is_some_and(|s| s <= 0.04),
        format!("{latency_ms:?} ms"),
    );

    run.run_for(3.0);
    let rpm: Vec<f64> = (0..4).map(|i| round(run.rpm(i), 0)).collect();
    run.check(
        "the horizontal thrusters turn ahead",
        rpm.iter().all(|r| *r > 800.0),
        format!("rpm {rpm:?}"),
    );
    // SeaBotix thrusters report their speed; Legacy ones only their current (IDS 8.4.1).
    let seen = run.bench.ground.seen.clone();
    let moving = run
        .bench
        .thrusters
        .iter()
        .zip(seen.rpm.iter().zip(seen.current_ca))
        .take(4)
        .all(|(thruster, (rpm, ca))| match thruster.config.family {
            Family::SeaBotix => *rpm > 500,
            Family::Legacy => ca > 0,
        });
    run.check(
        "ESC telemetry reaches the console",
        moving,
        format!("telemetry rpm {:?}, cA {:?}", seen.rpm, seen.current_ca),
    );
    run.check(
        "the ground station sees it armed",
        run.bench.ground.seen.armed,
        "HEARTBEAT armed flag",
    );

    run.bench.ground.sticks = Some(ManualInput { r: 500, ..AHEAD });
    run.run_for(3.0);
    let yaw: Vec<f64> = (0..4).map(|i| round(run.rpm(i), 0)).collect();
    let differs = (yaw[0] - yaw[1]).abs() > 300.0;
    run.check("yaw splits the horizontal thrusters", differs, format!("rpm {yaw:?}"));

    run.disarm();
    run.run_for(2.0);
    let duties: Vec<i16> = run
        .bench
        .thrusters
        .iter()
        .map(|thruster| thruster.drive().1.value())
        .collect();
    let still: Vec<f64> = (0..run.bench.thrusters.len()).map(|i| round(run.rpm(i), 0)).collect();
    run.check(
        "disarmed, every thruster stops driving and slows",
        duties.iter().all(|d| *d == 0) && still.iter().all(|r| (0.0..300.0).contains(r)),
        format!("duty {duties:?}, rpm {still:?}"),
    );
    let faults: Vec<u8> = (0..run.bench.thrusters.len()).map(|i| run.faults(i).bits()).collect();
    run.check(
        "no faults in a clean dive",
        faults.iter().all(|f| *f == 0),
        format!("fault bits {faults:?}"),
    );
    run.metric("battery_v_at_end", json!(round(run.bench.battery.voltage, 2)));
}

pub fn console_silence(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.0);
    run.inject(Fault::ConsoleSilence);
    // FS_PILOT_TIMEOUT (3 s) after the last stick frame, up to 0.1 s before the loss.
    let neutral = run.run_until(4.0, |bench| {
        bench
            .master
            .shared
            .orders
            .try_get()
            .is_some_and(|orders| orders.iter().all(|order| order.speed.is_zero()))
    });
    run.check(
        "neutral after 3 s without sticks",
        neutral.is_some_and(|s| (2.85..=3.05).contains(&s)),
        format!("after {neutral:?} s (the last stick frame was up to 0.1 s before the loss)"),
    );
    let armed = run.bench.master.shared.vehicle.try_get().is_some_and(|v| v.armed);
    run.check("still armed while neutral", armed, "");
    // FS_GCS_TIMEOUT (5 s) after the last heartbeat, up to 1 s before the loss.
    let disarmed = run
        .run_until(3.0, |bench| {
            !bench.master.shared.vehicle.try_get().is_some_and(|v| v.armed)
        })
        .zip(neutral)
        .map(|(disarmed, neutral)| disarmed + neutral);
    run.check(
        "disarms 5 s after the last heartbeat",
        disarmed.is_some_and(|s| (3.95..=5.05).contains(&s)),
        format!("after {disarmed:?} s (the last heartbeat was up to 1 s before the loss)"),
    );
    run.run_for(0.5);
    let duties: Vec<i16> = (0..6).map(|i| run.duty(i)).collect();
    run.check(
        "every thruster stops driving",
        duties.iter().all(|d| *d == 0),
        format!("duty {duties:?}"),
    );
    run.clear(Fault::ConsoleSilence);
    run.run_for(1.5);
    let duties: Vec<i16> = (0..6).map(|i| run.duty(i)).collect();
    run.check(
        "no restart until re-armed",
        duties.iter().all(|d| *d == 0),
        format!("duty {duties:?}"),
    );
    run.check("the console hears why", run.said("Failsafe"), "STATUSTEXT");
}

pub fn battery_lost(run: &mut Run) {
    run.run_for(1.5);
    let fresh = run.bench.master.shared.battery.try_get().is_some_and(|b| !b.stale);
    run.check("battery data fresh at first", fresh, "");
    run.inject(Fault::BatteryFramesLost);
    let stale = run.run_until(2.0, |bench| {
        bench.master.shared.battery.try_get().is_some_and(|b| b.stale)
    });
    run.check(
        "flagged stale after 1 s",
        stale.is_some_and(|s| (0.9..=1.2).contains(&s)),
        format!("after {stale:?} s"),
    );
    run.run_for(2.0);
    run.clear(Fault::BatteryFramesLost);
    run.run_for(1.0);
    let fresh = run.bench.master.shared.battery.try_get().is_some_and(|b| !b.stale);
    run.check("resumed", fresh && run.said("BAT data resumed"), "");
    run.check("the console hears of it", run.said("BAT data stale"), "");
}

pub fn battery_bits(run: &mut Run) {
    run.run_for(1.0);
    let startup = run
        .bench
        .ground
        .seen
        .texts
        .iter()
        .filter(|(_, text)| text.starts_with("BAT ") && text.contains('='))
        .count();
    run.check(
        "start-up report names every bit",
        startup == 12,
        format!("{startup} bit texts"),
    );
    let before = run.bench.ground.seen.texts.len();
    run.inject(Fault::BatteryBit(StatusBit::HsmSwFault));
    run.run_for(1.0);
    let new: Vec<String> = run
        .bench
        .ground
        .seen
        .texts
        .iter()
        .skip(before)
        .map(|(_, text)| text.clone())
        .collect();
    let bits: Vec<&String> = new.iter().filter(|text| text.contains('=')).collect();
    run.check(
        "only the switched bit is reported",
        bits.len() == 1 && bits[0].contains("HSM_SW_F=1"),
        format!("{new:?}"),
    );
}

/// The master resets while the vehicle drives: it boots with fresh state, so it comes up disarmed, orders every
/// thruster to stop at its first polls, finds them all again, and drives once re-armed.
pub fn master_reboot(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(2.0);
    run.bench.note("master reset");
    run.bench.reboot_master();
    let stopped = run.run_until(0.2, |bench| {
        bench.thrusters.iter().all(|thruster| {
            thruster
                .shared()
                .link
                .try_get()
                .is_some_and(|link| link.order.speed.is_zero())
        })
    });
    run.check(
        "every thruster is ordered to stop at once",
        stopped.is_some_and(|s| s <= 0.05),
        format!("after {stopped:?} s"),
    );
    run.run_for(1.0);
    let online = (0..6).all(|i| run.health(i).online);
    let armed = run
        .bench
        .master
        .shared
        .vehicle
        .try_get()
        .is_some_and(|state| state.armed);
    run.check(
        "it finds every thruster again and stays disarmed",
        online && !armed,
        format!("all online {online}, armed {armed}"),
    );
    let arm = run.bench.ground.arm(true);
    run.bench.send(arm);
    run.run_for(2.0);
    let rpm: Vec<f64> = (0..4).map(|i| round(run.rpm(i), 0)).collect();
    run.check(
        "re-armed, it drives again",
        rpm.iter().all(|r| *r > 800.0),
        format!("rpm {rpm:?}"),
    );
}

/// Read `path` from the master over MAVLink FTP as a ground station's `ftp get` does (OpenFileRO, ReadFile at
/// each offset, TerminateSession); `None` when a request is refused or unanswered.
fn ftp_get(run: &mut Run, path: &str) -> Option<Vec<u8>> {
    const TERMINATE: u8 = 1;
    const OPEN_RO: u8 = 4;
    const READ: u8 = 5;
    const ACK: u8 = 128;
    // A request whose reply does not come within a second is sent again, as the clients do: the master drops a
    // read's request past its requester's allowance (ten replies a second, `console::limit`), and its reply when
    // its outbox is full.
    let ask = |run: &mut Run, seq: u16, session: u8, opcode: u8, offset: u32, data: &[u8]| {
        for _ in 0..5 {
            run.bench.ground.seen.ftp.clear();
            let frame = run.bench.ground.ftp_request(seq, session, opcode, offset, data);
            run.bench.send(frame);
            run.run_until(1.0, |bench| !bench.ground.seen.ftp.is_empty());
            if let Some(reply) = run.bench.ground.seen.ftp.first() {
                return (reply[3] == ACK).then_some(*reply);
            }
        }
        None
    };
    let open = ask(run, 0x5000, 0, OPEN_RO, 0, path.as_bytes())?;
    let (session, len) = (open[2], u32::from_le_bytes([open[12], open[13], open[14], open[15]]));
    let mut file = Vec::new();
    while (file.len() as u32) < len {
        let seq = 0x5001 + file.len() as u16;
        let read = ask(run, seq, session, READ, file.len() as u32, &[0; 200])?;
        let size = usize::from(read[4]);
        file.extend_from_slice(read.get(12..12 + size)?);
    }
    ask(run, 0x5fff, session, TERMINATE, 0, &[]);
    Some(file)
}

/// The master's black box after a dive that ends in the master's reset: an FTP client gets `@SYS/blackbox.tlog`
/// and `lbv decode tlog`'s reader reads it back; each sample's rpm, order and arm state are the bench's own, and the
/// samples before the reset are kept across it.
pub fn black_box(run: &mut Run) {
    run.bench.keep_samples(true);
    run.arm_and_go(AHEAD);
    run.run_for(3.0);
    run.bench.note("the pilot turns");
    run.bench.ground.sticks = Some(ManualInput { r: 500, ..AHEAD });
    run.run_for(2.0);
    let reset_at = run.bench.now().as_micros() as f64 / 1e6;
    run.bench.note("master reset (watchdog)");
    run.bench.crash_master();
    run.run_for(2.0);
    let bytes = ftp_get(run, "@SYS/blackbox.tlog");
    let read = bytes
        .as_deref()
        .map(|bytes| lbv::decode::tlog::read_trace(bytes, |_| Ok(())).map_err(|error| format!("{error:?}")));
    let (log, stats) = match read {
        Some(Ok(read)) => read,
        other => {
            run.check("an FTP client gets the black box", false, format!("{other:?}"));
            return;
        }
    };
    run.metric("file_bytes", json!(bytes.as_ref().map_or(0, Vec::len)));
    run.metric("frames", json!(stats.frames));
    run.metric("samples", json!(log.samples.len()));
    run.check(
        "an FTP client gets @SYS/blackbox.tlog, every frame's CRC checks",
        stats.frames > 0 && stats.skipped == 0,
        format!("{} frames, {} bytes skipped", stats.frames, stats.skipped),
    );
    let starts: Vec<f64> = log
        .events
        .iter()
        .filter(|event| event.text == "Black box: master started")
        .map(|event| round(event.t, 2))
        .collect();
    run.check(
        "it holds the dive from the master's start, and the reset: two starts marked",
        starts.len() == 2 && starts[0] <= 0.2 && log.samples.first().is_some_and(|s| s.t <= 0.2),
        format!("starts at {starts:?} s"),
    );
    // Before the reset the log's clock is the bench's: compare each of its samples with the bench's samples of the
    // 100 ms before it (the master's sample takes each thruster's last status, and the thruster measured its
    // speed before that), the order and the arming with the last of them. The log's rpm is ESC_TELEMETRY's, a
    // magnitude.
    let trace = &run.bench.trace.samples;
    let before: Vec<_> = log.samples.iter().filter(|s| s.t < reset_at).collect();
    let mut worst_rpm = 0f64;
    let mut orders_differ = 0usize;
    let mut armed_differ = 0usize;
    for sample in &before {
        let window: Vec<_> = trace
            .iter()
            .filter(|b| b.t <= sample.t && b.t >= sample.t - 0.1)
            .collect();
        let Some(last) = window.last() else { continue };
        for (i, logged) in sample.thrusters.iter().enumerate() {
            let error = window
                .iter()
                .filter_map(|b| b.thrusters.get(i))
                .map(|bench| (bench.rpm.abs() - logged.rpm).abs())
                .fold(f64::INFINITY, f64::min);
            worst_rpm = worst_rpm.max(error);
            orders_differ += usize::from(last.thrusters.get(i).map(|b| b.ordered_step) != Some(logged.ordered_step));
        }
        armed_differ += usize::from(last.armed != sample.armed);
    }
    run.metric("worst_rpm_error", json!(round(worst_rpm, 1)));
    // A status says the speed in steps of 44 rpm; the shaft moves on while it is on its way (half a step here).
    let step = f64::from(tmc_proto::Speed::FULL_SCALE_RPM) / f64::from(tmc_proto::Speed::MAX_STEP);
    run.check(
        "before the reset, each thruster's speed is the bench's within 1.5 steps, its order and the arming the same",
        before.len() >= 50 && worst_rpm <= 1.5 * step && orders_differ == 0 && armed_differ == 0,
        format!(
            "{} samples: rpm off by {:.1} at most (a step is {step:.1}), {orders_differ} orders and \
             {armed_differ} arm states not the bench's",
            before.len(),
            worst_rpm
        ),
    );
    let after: Vec<_> = log.samples.iter().filter(|s| s.t >= reset_at).collect();
    run.check(
        "after the reset: samples on, disarmed, every order a stop",
        after.len() >= 10
            && after
                .iter()
                .all(|s| !s.armed && s.thrusters.iter().all(|t| t.ordered_step == 0)),
        format!("{} samples after the reset", after.len()),
    );
}

/// One thruster's core panics mid-dive (T2, as its panic handler stops it): its bridge is off at once, its watchdog
/// resets it, the master finds it again and drives it, tells the stop, fetches its post-mortem record and serves it
/// over MAVLink FTP, where `lbv decode crash` reads it. Before the panic T2's orders come corrupted for a while, and
/// its record's events say so.
pub fn thruster_crash(run: &mut Run) {
    run.arm_and_go(AHEAD);
    run.run_for(1.5);
    let corrupted = Fault::CorruptOrders {
        thruster: 1,
        mask: 0x01,
    };
    corrupted.inject(&mut run.bench);
    run.run_for(1.5);
    corrupted.clear(&mut run.bench);
    run.run_for(1.5);
    let rpm_before = round(run.rpm(1), 0);
    run.bench.note("T2's core panics");
    run.bench.stop_thruster(1, crash_record::Kind::Panic);
    run.check(
        "T2's bridge is off at once",
        run.duty(1) == 0 && run.bench.thrusters[1].drive().1.value() == 0,
        format!("duty {}", run.duty(1)),
    );
    let told = run.run_until(3.0, |bench| {
        bench
            .ground
            .seen
            .texts
            .iter()
            .any(|(_, text)| text == "T2: crash before its start: panic")
    });
    run.metric("told_after_s", json!(told.map(|s| round(s, 2))));
    run.check(
        "the master tells the stop once T2 is back, and where its record is",
        told.is_some() && run.said("Its record: ftp get @SYS/crash/thruster1.bin"),
        format!("after {told:?} s"),
    );
    run.run_for(1.5);
    let rpm: Vec<f64> = (0..4).map(|i| round(run.rpm(i), 0)).collect();
    run.check(
        "T2 drives again, the others never stopped",
        rpm.iter().all(|r| *r > 800.0),
        format!("rpm {rpm:?} (T2 {rpm_before} before)"),
    );
    let record = ftp_get(run, "@SYS/crash/thruster1.bin");
    let decoded = record.as_deref().map(crash_record::Record::decode);
    let stop = match &decoded {
        Some(Ok(record)) => format!(
            "{} of target {}, reset flags {:#010x}",
            record.kind.name(),
            record.target,
            record.reset_cause
        ),
        other => format!("{other:?}"),
    };
    run.check(
        "an FTP client gets the record: a panic of a SeaBotix thruster, reset by its watchdog",
        matches!(&decoded, Some(Ok(record)) if record.kind == crash_record::Kind::Panic
            && record.target == update_image::Target::ThrusterSeabotix.to_byte()
            && record.reset_cause & 1 << 29 != 0),
        stop,
    );
    let events: Vec<crash_record::What> = match &decoded {
        Some(Ok(record)) => record.events().iter().map(|event| event.what).collect(),
        _ => Vec::new(),
    };
    run.check(
        "its events: T2's start, then its orders lost while they came corrupted",
        matches!(
            events[..],
            [crash_record::What::Started(_), crash_record::What::OrdersLost]
        ),
        format!("{events:?}"),
    );
    let printed = match &decoded {
        Some(Ok(record)) => crate::decode::crash::describe(record, None),
        _ => String::new(),
    };
    run.check(
        "lbv decode crash prints it",
        printed.contains("panic"),
        printed.lines().next().unwrap_or_default(),
    );
    let crashes = run
        .bench
        .ground
        .seen
        .texts
        .iter()
        .filter(|(_, text)| text.contains("crash before"))
        .count();
    run.check("told once", crashes == 1, format!("{crashes} texts"));
}
