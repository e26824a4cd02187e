//! The bus on its own: timing, routing, faults, a firmware port and the lines.

use super::*;
use crate::{Executor, clock};
use std::cell::Cell;

const TIMING: Timing = Timing::new(100_000, Duration::from_millis(25));
const BIT: Duration = Duration::from_micros(10);

/// Remembers what was written; answers reads with 1, 2, 3, ...
struct Register {
    address: u8,
    written: Vec<Vec<u8>>,
    reply: Reply,
}

impl Register {
    fn at(address: u8) -> Rc<RefCell<Register>> {
        Rc::new(RefCell::new(Register {
            address,
            written: Vec::new(),
            reply: Reply::Ack,
        }))
    }
}

impl Device for Register {
    fn address(&self) -> u8 {
        self.address
    }

    fn write(&mut self, bytes: &[u8]) -> Reply {
        self.written.push(bytes.to_vec());
        self.reply
    }

    fn read(&mut self, buffer: &mut [u8]) -> Reply {
        for (byte, value) in buffer.iter_mut().zip(1..) {
            *byte = value;
        }
        self.reply
    }
}

/// Run `script` against the bus on the virtual clock, in 1 us steps, until it ends; returns when it ended.
fn run(script: impl Future<Output = ()>) -> Instant {
    let clock = clock::take();
    let done = Cell::new(false);
    let mut executor = Executor::new();
    executor.spawn(async {
        script.await;
        done.set(true);
    });
    let took = executor.run_until(&clock, Duration::from_secs(1), Duration::from_micros(1), || done.get());
    assert!(took.is_some(), "the script ended");
    clock.now()
}

#[test]
fn transfers_are_charged_their_bit_times_and_absent_addresses_nack() {
    let bus = Bus::new(TIMING);
    let register = Register::at(0x29);
    bus.attach(register.clone(), Route::Direct);
    let mut master = bus.master();
    let end = run(async {
        master.write(0x29, &[0x52, 0x80, 100, 0x36]).await.unwrap();
        let mut status = [0; 7];
        master.read(0x29, &mut status).await.unwrap();
        assert_eq!(status, [1, 2, 3, 4, 5, 6, 7]);
        let nack = master.write(0x2A, &[0]).await;
        assert_eq!(nack, Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)));
    });
    // Order 1 + 9 + 36 + 1, status 1 + 9 + 63 + 1, NACK 1 + 9 + 1.
    assert_eq!(bus.stats().bits, 47 + 74 + 11);
    assert_eq!(end, Instant::from_ticks(0) + BIT * (47 + 74 + 11));
    assert_eq!(register.borrow().written, [vec![0x52, 0x80, 100, 0x36]]);
    let stats = bus.stats();
    assert_eq!((stats.transfers, stats.nacks), (3, 1));
}

#[test]
fn the_mux_routes_its_channels_and_unpowered_devices_are_absent() {
    let bus = Bus::new(TIMING);
    bus.fit_mux(0x70);
    let (a, b) = (Register::at(0x29), Register::at(0x29));
    bus.attach(a.clone(), Route::Mux(0));
    let id = bus.attach(b.clone(), Route::Mux(3));
    let mut master = bus.master();
    run(async {
        assert!(master.write(0x29, &[1]).await.is_err(), "no channel selected");
        master.write(0x70, &[0b0000_1000]).await.unwrap();
        master.write(0x29, &[2]).await.unwrap();
        master.write(0x70, &[0b0000_1001]).await.unwrap();
        master.write(0x29, &[3]).await.unwrap();
        bus.set_powered(id, false);
        master.write(0x29, &[4]).await.unwrap();
        let mut control = [0];
        master.read(0x70, &mut control).await.unwrap();
        assert_eq!(control, [0b0000_1001]);
    });
    assert_eq!(a.borrow().written, [vec![3], vec![4]]);
    assert_eq!(b.borrow().written, [vec![2], vec![3]]);
    assert_eq!(bus.stats().collisions, 1, "both answered [3]");
    assert_eq!(bus.mux_control(), Some(0b0000_1001));
}

#[test]
fn a_device_stretching_past_the_timeout_times_the_master_out() {
    let bus = Bus::new(TIMING);
    let register = Register::at(0x29);
    bus.attach(register.clone(), Route::Direct);
    let mut master = bus.master();
    register.borrow_mut().reply = Reply::Stretch(Duration::from_millis(30));
    let end = run(async {
        assert_eq!(master.write(0x29, &[1]).await, Err(ErrorKind::Other));
    });
    assert_eq!(end, Instant::from_ticks(0) + BIT * 10 + Duration::from_millis(25));
    register.borrow_mut().reply = Reply::Stretch(Duration::from_millis(1));
    let end = run(async {
        master.write(0x29, &[1]).await.unwrap();
    });
    assert_eq!(end, Instant::from_ticks(0) + BIT * 20 + Duration::from_millis(1));
    assert_eq!(bus.stats().timeouts, 1);

    // While the transfer is under way, the bus says with whom.
    let id = DeviceId(0);
    let clock = clock::take();
    let mut executor = Executor::new();
    executor.spawn(async move {
        let _ = master.write(0x29, &[1]).await;
    });
    executor.run_for(&clock, Duration::from_micros(500), BIT);
    assert!(bus.in_transfer_with(id));
    executor.run_for(&clock, Duration::from_millis(2), BIT);
    assert!(!bus.in_transfer_with(id));
}

#[test]
fn tampering_corrupts_both_ways() {
    let bus = Bus::new(TIMING);
    let register = Register::at(0x29);
    let id = bus.attach(register.clone(), Route::Direct);
    bus.tamper(
        id,
        Tamper {
            read_xor: 0x10,
            write_last_xor: 0x01,
            rewrite: Some(|bytes| bytes.reverse()),
            rewrite_read: None,
        },
    );
    bus.record(true);
    let mut master = bus.master();
    run(async {
        master.write(0x29, &[1, 2, 3]).await.unwrap();
        let mut read = [0; 2];
        master.read(0x29, &mut read).await.unwrap();
        assert_eq!(read, [0x11, 0x12]);
    });
    assert_eq!(register.borrow().written, [vec![3, 2, 0]]);
    let log = bus.take_log();
    assert_eq!(log.len(), 2);
    assert_eq!(
        log[0].data,
        Data::Write(vec![1, 2, 3]),
        "the log has what the master sent"
    );
    assert_eq!(log[1].data, Data::Read(vec![0x11, 0x12]));
}

#[test]
fn a_firmware_port_takes_writes_and_answers_reads_and_a_silent_one_times_out() {
    let bus = Bus::new(TIMING);
    let id = bus.attach_target(0x2A, Route::Direct);
    let mut target = bus.target(id).unwrap();
    let mut master = bus.master();
    let clock = clock::take();
    let got = RefCell::new(Vec::new());
    let done = Cell::new(false);
    let mut executor = Executor::new();
    let firmware = executor.spawn(async {
        loop {
            match target.listen().await.unwrap() {
                Request::Write => {
                    let mut buffer = [0; 2];
                    let n = target.respond_to_write(&mut buffer).await.unwrap();
                    got.borrow_mut().push(buffer[..n].to_vec());
                }
                Request::Read => target.respond_to_read(&[0x55, 9]).await.unwrap(),
            }
        }
    });
    let done = &done;
    executor.spawn(async move {
        master.write(0x2A, &[7, 8, 9]).await.unwrap();
        let mut read = [0; 3];
        master.read(0x2A, &mut read).await.unwrap();
        assert_eq!(read, [0x55, 9, 0xFF], "past its data the slave leaves SDA high");
        done.set(true);
    });
    let took = executor.run_until(&clock, Duration::from_secs(1), BIT, || done.get());
    assert_eq!(took, Some(BIT * (47 - 9 + 1 + 9 + 27 + 1)));
    assert_eq!(*got.borrow(), [vec![7, 8]], "what does not fit is dropped");

    // The controller resets: nobody answers, the master times out, and the next boot answers again.
    executor.remove(firmware);
    done.set(false);
    let mut master = bus.master();
    executor.spawn(async move {
        assert_eq!(master.write(0x2A, &[1]).await, Err(ErrorKind::Other));
        done.set(true);
    });
    let took = executor.run_until(&clock, Duration::from_secs(1), BIT, || done.get());
    assert_eq!(took, Some(Duration::from_millis(25) + BIT * 10));
    let mut target = bus.target(id).unwrap();
    target.reset();
    assert_eq!(bus.target_resets(id), 1);
}

#[test]
fn a_glitch_tears_one_transfer_at_both_ends() {
    let bus = Bus::new(TIMING);
    let id = bus.attach_target(0x29, Route::Direct);
    let mut target = bus.target(id).unwrap();
    let mut master = bus.master();
    let clock = clock::take();
    let seen = RefCell::new(Vec::new());
    let results = RefCell::new(Vec::new());
    let mut executor = Executor::new();
    executor.spawn(async {
        loop {
            let request = target.listen().await;
            let mut buffer = [0; 4];
            let answer = match request {
                Ok(Request::Write) => target.respond_to_write(&mut buffer).await.map(|_| ()),
                Ok(Request::Read) => target.respond_to_read(&[1]).await,
                Err(error) => Err(error),
            };
            seen.borrow_mut().push(answer);
        }
    });
    bus.disturb(id);
    executor.spawn(async {
        for _ in 0..2 {
            let result = master.write(0x29, &[5]).await;
            results.borrow_mut().push(result);
        }
    });
    executor.run_for(&clock, Duration::from_millis(2), BIT);
    assert_eq!(*results.borrow(), [Err(ErrorKind::Bus), Ok(())]);
    assert_eq!(*seen.borrow(), [Err(TargetError), Ok(())]);
}

#[test]
fn sda_held_low_fails_every_transfer_until_enough_clocks_free_it() {
    let bus = Bus::new(TIMING);
    let register = Register::at(0x29);
    bus.attach(register.clone(), Route::Direct);
    let register_reply = |_: &Bus, reply| register.borrow_mut().reply = reply;
    let (mut scl, mut sda, mut master) = (bus.scl(), bus.sda(), bus.master());
    bus.hold_sda(3);
    run(async {
        assert_eq!(master.write(0x29, &[1]).await, Err(ErrorKind::Bus));
    });
    assert!(sda.is_low().unwrap());
    for _ in 0..2 {
        scl.set_low().unwrap();
        scl.set_high().unwrap();
    }
    assert!(bus.sda_held(), "two clocks are not enough");
    scl.set_low().unwrap();
    assert!(bus.sda_held(), "a clock counts when SCL rises");
    scl.set_high().unwrap();
    assert!(sda.is_high().unwrap());
    // STOP: SDA rises while SCL is high.
    sda.set_low().unwrap();
    sda.set_high().unwrap();
    let stats = bus.stats();
    assert_eq!((stats.pin_clocks, stats.pin_stops, stats.bus_errors), (3, 1, 1));
    run(async {
        master.write(0x29, &[1]).await.unwrap();
    });

    // A device that goes wrong mid-transfer.
    register_reply(&bus, Reply::HoldSda(u32::MAX));
    run(async {
        assert_eq!(master.write(0x29, &[1]).await, Err(ErrorKind::Bus));
    });
    for _ in 0..20 {
        scl.set_low().unwrap();
        scl.set_high().unwrap();
    }
    assert!(bus.sda_held(), "a slave that never lets go");
    assert_eq!(bus.stats().bus_errors, 2);
    bus.hold_sda(0);
    assert!(!bus.sda_held());
}

#[test]
fn a_glitch_at_the_next_transfer_to_a_port_holds_sda_low_unseen_by_its_firmware() {
    let bus = Bus::new(TIMING);
    let id = bus.attach_target(0x29, Route::Direct);
    let mut target = bus.target(id).unwrap();
    let (mut scl, mut master) = (bus.scl(), bus.master());
    let clock = clock::take();
    let seen = Cell::new(0);
    let results = RefCell::new(Vec::new());
    let mut executor = Executor::new();
    executor.spawn(async {
        loop {
            if target.listen().await.is_ok() && target.respond_to_write(&mut [0; 4]).await.is_ok() {
                seen.set(seen.get() + 1);
            }
        }
    });
    bus.hold_sda_at_next_transfer(id, 2);
    assert!(!bus.sda_held(), "not before the transfer");
    executor.spawn(async {
        for _ in 0..2 {
            let result = master.write(0x29, &[5]).await;
            results.borrow_mut().push(result);
        }
        assert!(bus.sda_held());
        for _ in 0..2 {
            scl.set_low().unwrap();
            scl.set_high().unwrap();
        }
        let result = master.write(0x29, &[6]).await;
        results.borrow_mut().push(result);
    });
    executor.run_for(&clock, Duration::from_millis(2), BIT);
    assert_eq!(*results.borrow(), [Err(ErrorKind::Bus), Err(ErrorKind::Bus), Ok(())]);
    assert_eq!(seen.get(), 1, "the firmware saw only the last");
    assert_eq!(bus.stats().bus_errors, 2);
}

#[test]
fn a_transfer_held_past_the_timeout_by_the_masters_stall_times_out() {
    let clock = clock::take();
    let bus = Bus::new(TIMING);
    bus.attach(Register::at(0x29), Route::Direct);
    let cpu = Cpu::new();
    bus.set_master_cpu(&cpu);
    let results = RefCell::new(Vec::new());
    let mut master = bus.master();
    let mut executor = Executor::new();
    executor.spawn_on(&cpu, async {
        for stall in [Duration::from_millis(10), Duration::from_millis(25)] {
            // The transfer starts, then the CPU stalls before it ends.
            let transfer = master.write(0x29, &[1, 2, 3, 4]);
            let mut transfer = core::pin::pin!(transfer);
            let started = core::future::poll_fn(|cx| {
                let _ = transfer.as_mut().poll(cx);
                core::task::Poll::Ready(Instant::now())
            })
            .await;
            cpu.stall(stall);
            let result = transfer.await;
            results.borrow_mut().push((result, Instant::now() - started));
        }
    });
    executor.run_for(&clock, Duration::from_millis(100), Duration::from_micros(10));
    drop(executor);
    let results = results.into_inner();
    // 10 ms: late, but within the 25 ms timeout. 25 ms: a timeout.
    assert_eq!(results.len(), 2);
    assert_eq!(results[0].0, Ok(()));
    assert!(results[0].1 >= Duration::from_millis(10), "{:?}", results[0].1);
    assert_eq!(results[1].0, Err(ErrorKind::Other));
    let stats = bus.stats();
    assert_eq!((stats.timeouts, stats.stalled), (1, 1));
}

/// What a firmware port on the bus did: each answer's result and when it returned, and the writes it stored.
#[derive(Default)]
struct Served {
    answers: RefCell<Vec<(Result<(), TargetError>, Instant)>>,
    stored: RefCell<Vec<Vec<u8>>>,
}

/// A firmware port at 0x29 that answers each transfer `delay` after it is addressed, reads with `reply`.
async fn firmware(mut target: Target, delay: Duration, reply: &[u8], served: &Served) {
    loop {
        let Ok(request) = target.listen().await else {
            continue;
        };
        Timer::after(delay).await;
        let result = match request {
            Request::Write => {
                let mut buffer = [0; 8];
                let result = target.respond_to_write(&mut buffer).await;
                if let Ok(n) = result {
                    served.stored.borrow_mut().push(buffer[..n].to_vec());
                }
                result.map(|_| ())
            }
            Request::Read => target.respond_to_read(reply).await,
        };
        served.answers.borrow_mut().push((result, Instant::now()));
    }
}

/// The master's transfer to a port at 0x29 that answers `delay` after it is addressed: the port loses power (its
/// task dropped, as at a reset) `cut` after the START, if given. Returns the master's result, the bytes read (a read
/// when `write` is None), when the transfer ended, what the port did, and the bus's count of torn transfers.
fn cut_at(
    write: Option<&[u8]>,
    delay: Duration,
    cut: Option<Duration>,
) -> (Result<(), ErrorKind>, [u8; 7], Instant, Served, u64) {
    let bus = Bus::new(TIMING);
    let id = bus.attach_target(0x29, Route::Direct);
    let target = bus.target(id).unwrap();
    let mut master = bus.master();
    let clock = clock::take();
    let served = Served::default();
    let ended = Cell::new(None);
    let mut read = [0; 7];
    let mut executor = Executor::new();
    let port = executor.spawn(firmware(target, delay, &[1, 2, 3, 4, 5, 6, 7], &served));
    executor.spawn(async {
        let result = match write {
            Some(bytes) => master.write(0x29, bytes).await,
            None => master.read(0x29, &mut read).await,
        };
        ended.set(Some((result, Instant::now())));
    });
    if let Some(cut) = cut {
        executor.run_for(&clock, cut, BIT);
        executor.remove(port);
        bus.set_powered(id, false);
    }
    executor.run_for(&clock, Duration::from_millis(40), BIT);
    drop(executor);
    let (result, end) = ended.get().expect("the transfer ended");
    (result, read, end, served, bus.stats().torn)
}

/// `bits` bit times after the clock's start.
fn at_bits(bits: u64) -> Instant {
    Instant::from_ticks(0) + BIT * bits as u32
}

#[test]
fn a_firmware_ports_answer_returns_once_its_bytes_have_moved() {
    let (result, read, end, served, torn) = cut_at(None, Duration::from_ticks(0), None);
    assert_eq!((result, read, torn), (Ok(()), [1, 2, 3, 4, 5, 6, 7], 0));
    // START, address and ACK, 7 bytes; then the STOP.
    assert_eq!(*served.answers.borrow(), [(Ok(()), at_bits(10 + 63))]);
    assert_eq!(end, at_bits(10 + 63 + 1));

    let (result, _, end, served, _) = cut_at(Some(&[9, 8, 7, 6]), Duration::from_micros(200), None);
    assert_eq!(result, Ok(()));
    assert_eq!(*served.answers.borrow(), [(Ok(()), at_bits(10 + 20 + 36))]);
    assert_eq!(*served.stored.borrow(), [vec![9, 8, 7, 6]]);
    assert_eq!(end, at_bits(10 + 20 + 36 + 1));
}

#[test]
fn a_read_torn_mid_way_reads_0xff_from_the_cut_on() {
    // The bytes move from bit 10: the cut lands 3 bits into the third byte, whose first 3 bits (of 3 = 0b0000_0011)
    // came through.
    let (result, read, end, served, torn) = cut_at(None, Duration::from_ticks(0), Some(BIT * (10 + 18 + 3)));
    assert_eq!(
        result,
        Ok(()),
        "the master cannot tell released lines from a slave sending 1s"
    );
    assert_eq!(read, [1, 2, 0b0001_1111, 0xFF, 0xFF, 0xFF, 0xFF]);
    assert_eq!(end, at_bits(10 + 63 + 1), "the master clocks the read to its end");
    assert!(served.answers.borrow().is_empty(), "the firmware never saw it end");
    assert_eq!(torn, 1);

    // A cut in a byte's ACK bit leaves that byte whole.
    let (_, read, _, _, _) = cut_at(None, Duration::from_ticks(0), Some(BIT * (10 + 9 + 8)));
    assert_eq!(read, [1, 2, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]);
    // One in the last byte's ACK bit tears nothing.
    let (_, read, _, _, torn) = cut_at(None, Duration::from_ticks(0), Some(BIT * (10 + 54 + 8)));
    assert_eq!((read, torn), ([1, 2, 3, 4, 5, 6, 7], 0));
}

#[test]
fn a_write_torn_mid_way_has_its_next_byte_not_acknowledged() {
    let data_nack = Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Data));
    // 2 bits into the second byte: the first was acknowledged, the second is not, and the master stops there.
    let (result, _, end, served, torn) = cut_at(Some(&[9, 8, 7, 6]), Duration::from_ticks(0), Some(BIT * (10 + 11)));
    assert_eq!((result, torn), (data_nack, 1));
    assert_eq!(end, at_bits(10 + 18 + 1));
    assert!(served.stored.borrow().is_empty(), "the firmware never stored it");
    // In the first byte's ACK bit: the first acknowledged, the second not.
    let (result, _, end, _, _) = cut_at(Some(&[9, 8, 7, 6]), Duration::from_ticks(0), Some(BIT * (10 + 8)));
    assert_eq!((result, end), (data_nack, at_bits(10 + 18 + 1)));
    // In the address byte: the address is not acknowledged.
    let (result, _, end, _, torn) = cut_at(Some(&[9, 8, 7, 6]), Duration::from_ticks(0), Some(BIT * 5));
    assert_eq!(result, Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)));
    assert_eq!((end, torn), (at_bits(10 + 1), 0));
}

#[test]
fn a_port_cut_while_it_stretches_scl_lets_the_lines_go() {
    let stretch = Duration::from_millis(1);
    let cut = Some(BIT * 10 + Duration::from_micros(500));
    let (result, read, end, _, torn) = cut_at(None, stretch, cut);
    assert_eq!((result, read, torn), (Ok(()), [0xFF; 7], 1), "SDA pulled up");
    assert_eq!(end, at_bits(10 + 50 + 63 + 1));
    let (result, _, end, _, torn) = cut_at(Some(&[9, 8, 7, 6]), stretch, cut);
    assert_eq!(result, Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Data)));
    assert_eq!((end, torn), (at_bits(10 + 50 + 9 + 1), 1));
}

#[test]
fn a_port_that_answers_after_the_master_gave_up_waits_for_nothing() {
    // The port answers 30 ms after it is addressed, past the 25 ms timeout: at once, as if the bytes had moved.
    let (result, _, _, served, _) = cut_at(None, Duration::from_millis(30), None);
    assert_eq!(result, Err(ErrorKind::Other));
    assert_eq!(
        *served.answers.borrow(),
        [(Ok(()), Instant::from_ticks(0) + BIT * 10 + Duration::from_millis(30))]
    );
}

#[test]
fn a_port_whose_master_stops_mid_transfer_is_not_left_waiting() {
    let bus = Bus::new(TIMING);
    let id = bus.attach_target(0x29, Route::Direct);
    let target = bus.target(id).unwrap();
    let mut master = bus.master();
    let clock = clock::take();
    let served = Served::default();
    let mut executor = Executor::new();
    executor.spawn(firmware(target, Duration::from_ticks(0), &[1, 2], &served));
    let reader = executor.spawn(async move {
        let mut read = [0; 2];
        let _ = master.read(0x29, &mut read).await;
    });
    executor.run_for(&clock, BIT * 15, BIT);
    assert_eq!(bus.bytes_moving(id), Some((Request::Read, at_bits(10))));
    // The master resets while the bytes move.
    executor.remove(reader);
    executor.run_for(&clock, BIT, BIT);
    assert_eq!(*served.answers.borrow(), [(Err(TargetError), at_bits(15))]);
    assert_eq!(bus.bytes_moving(id), None);
}

/// How one of two firmware ports at 0x29, on the mux's channels 0 and 1 both enabled, takes a transfer.
#[derive(Clone, Copy)]
struct Port {
    /// It answers this long after it is addressed; None: its firmware never answers.
    delay: Option<Duration>,
    /// What it sends to a read.
    reply: &'static [u8],
    /// It loses power (its task dropped, as at a reset) this long after the START, if given.
    cut: Option<Duration>,
    /// Powered at the START.
    powered: bool,
    /// What corrupts its bytes.
    tamper: Tamper,
}

impl Port {
    /// Powered, answering at once, untampered.
    const PROMPT: Port = Port {
        delay: Some(Duration::from_ticks(0)),
        reply: &[],
        cut: None,
        powered: true,
        tamper: Tamper::NONE,
    };
}

/// What a transfer heard by two ports did.
struct Heard {
    /// The master's result.
    result: Result<(), ErrorKind>,
    /// The bytes read, for a read.
    read: [u8; 3],
    /// When the transfer ended.
    end: Instant,
    /// What each port did.
    served: [Served; 2],
    /// What the bus counted, the mux's selection of both channels included.
    stats: Stats,
}

/// The master's transfer to 0x29 heard by two ports, each as `ports` says: `write`, or a read when None. The mux
/// is set before the clock starts, so the transfer's START is at 0.
fn two_ports(write: Option<&[u8]>, ports: [Port; 2]) -> Heard {
    let bus = Bus::new(TIMING);
    bus.fit_mux(0x70);
    let ids = [
        bus.attach_target(0x29, Route::Mux(0)),
        bus.attach_target(0x29, Route::Mux(1)),
    ];
    let mut master = bus.master();
    run(async {
        master.write(0x70, &[0b0000_0011]).await.unwrap();
    });
    let clock = clock::take();
    let served = [Served::default(), Served::default()];
    let ended = Cell::new(None);
    let mut read = [0; 3];
    let mut executor = Executor::new();
    let mut tasks = [None, None];
    for (((id, port), served), task) in ids.iter().zip(ports).zip(&served).zip(&mut tasks) {
        bus.tamper(*id, port.tamper);
        bus.set_powered(*id, port.powered);
        let target = bus.target(*id).unwrap();
        *task = port
            .delay
            .map(|delay| executor.spawn(firmware(target, delay, port.reply, served)));
    }
    executor.spawn(async {
        let result = match write {
            Some(bytes) => master.write(0x29, bytes).await,
            None => master.read(0x29, &mut read).await,
        };
        ended.set(Some((result, Instant::now())));
    });
    let mut cuts: Vec<(Duration, usize)> = ports
        .iter()
        .enumerate()
        .filter_map(|(n, port)| port.cut.map(|cut| (cut, n)))
        .collect();
    cuts.sort();
    for (cut, n) in cuts {
        executor.run_for(&clock, cut - (clock.now() - Instant::from_ticks(0)), BIT);
        if let Some(task) = tasks[n] {
            executor.remove(task);
        }
        bus.set_powered(ids[n], false);
    }
    executor.run_for(&clock, Duration::from_millis(40), BIT);
    drop(executor);
    let (result, end) = ended.get().expect("the transfer ended");
    Heard {
        result,
        read,
        end,
        served,
        stats: bus.stats(),
    }
}

#[test]
fn a_write_heard_on_two_channels_reaches_both_ports() {
    let heard = two_ports(Some(&[9, 8, 7, 6]), [Port::PROMPT; 2]);
    assert_eq!(heard.result, Ok(()));
    for port in &heard.served {
        assert_eq!(*port.stored.borrow(), [vec![9, 8, 7, 6]]);
        assert_eq!(*port.answers.borrow(), [(Ok(()), at_bits(10 + 36))]);
    }
    assert_eq!(heard.end, at_bits(10 + 36 + 1), "as long as a write to one");
    assert_eq!(heard.stats.collisions, 1);

    // Each port gets the bytes through its own tamper.
    let tampered = Port {
        tamper: Tamper {
            write_last_xor: 0x01,
            ..Tamper::NONE
        },
        ..Port::PROMPT
    };
    let heard = two_ports(Some(&[9, 8, 7, 6]), [Port::PROMPT, tampered]);
    assert_eq!(heard.result, Ok(()));
    assert_eq!(*heard.served[0].stored.borrow(), [vec![9, 8, 7, 6]]);
    assert_eq!(*heard.served[1].stored.borrow(), [vec![9, 8, 7, 7]]);
}

#[test]
fn a_port_cut_mid_write_is_hidden_behind_the_others_ack() {
    // 2 bits into the second byte: the cut port stops acknowledging, the other acknowledges every byte.
    let cut = Port {
        cut: Some(BIT * (10 + 11)),
        ..Port::PROMPT
    };
    let heard = two_ports(Some(&[9, 8, 7, 6]), [Port::PROMPT, cut]);
    assert_eq!(heard.result, Ok(()), "the master cannot tell");
    assert_eq!(heard.end, at_bits(10 + 36 + 1));
    assert_eq!(*heard.served[0].stored.borrow(), [vec![9, 8, 7, 6]]);
    assert_eq!(*heard.served[0].answers.borrow(), [(Ok(()), at_bits(10 + 36))]);
    assert!(
        heard.served[1].stored.borrow().is_empty(),
        "the cut port never stored it"
    );
    assert_eq!((heard.stats.torn, heard.stats.collisions), (1, 1));

    // Unpowered from the start: only the other hears it.
    let off = Port {
        powered: false,
        ..Port::PROMPT
    };
    let heard = two_ports(Some(&[9, 8, 7, 6]), [off, Port::PROMPT]);
    assert_eq!(heard.result, Ok(()));
    assert!(heard.served[0].stored.borrow().is_empty());
    assert_eq!(*heard.served[1].stored.borrow(), [vec![9, 8, 7, 6]]);
    assert_eq!((heard.stats.torn, heard.stats.collisions), (0, 0));

    // Cut while the other still stretches SCL: it drives none of the bytes.
    let slow = Port {
        delay: Some(Duration::from_millis(1)),
        ..Port::PROMPT
    };
    let early = Port {
        cut: Some(BIT * 10 + Duration::from_micros(500)),
        ..Port::PROMPT
    };
    let heard = two_ports(Some(&[9, 8, 7, 6]), [slow, early]);
    assert_eq!(heard.result, Ok(()));
    assert_eq!(*heard.served[0].stored.borrow(), [vec![9, 8, 7, 6]]);
    assert!(heard.served[1].stored.borrow().is_empty());
    assert_eq!(heard.end, at_bits(10 + 36 + 1) + Duration::from_millis(1));
    assert_eq!(heard.stats.torn, 1);
}

#[test]
fn a_write_every_port_tore_stops_at_the_last_byte_one_acknowledged() {
    // One cut in the second byte, the other in the third: the third is the first nobody acknowledges, and the
    // master stops there.
    let ports = [
        Port {
            cut: Some(BIT * (10 + 11)),
            ..Port::PROMPT
        },
        Port {
            cut: Some(BIT * (10 + 18 + 2)),
            ..Port::PROMPT
        },
    ];
    let heard = two_ports(Some(&[9, 8, 7, 6]), ports);
    assert_eq!(heard.result, Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Data)));
    assert_eq!(heard.end, at_bits(10 + 27 + 1));
    assert!(heard.served.iter().all(|port| port.stored.borrow().is_empty()));
    assert_eq!(heard.stats.torn, 2);
}

#[test]
fn scl_is_held_until_the_slower_port_answers() {
    let quick = Port {
        delay: Some(Duration::from_micros(200)),
        ..Port::PROMPT
    };
    let slow = Port {
        delay: Some(Duration::from_millis(1)),
        ..Port::PROMPT
    };
    for ports in [[quick, slow], [slow, quick]] {
        let heard = two_ports(Some(&[9, 8, 7, 6]), ports);
        assert_eq!(heard.result, Ok(()));
        let moved = at_bits(10 + 36) + Duration::from_millis(1);
        for port in &heard.served {
            assert_eq!(
                *port.answers.borrow(),
                [(Ok(()), moved)],
                "the bytes move once both answered"
            );
            assert_eq!(*port.stored.borrow(), [vec![9, 8, 7, 6]]);
        }
        assert_eq!(heard.end, moved + BIT);
    }
}

#[test]
fn a_port_that_never_answers_times_the_shared_transfer_out() {
    let silent = Port {
        delay: None,
        ..Port::PROMPT
    };
    let heard = two_ports(Some(&[9, 8, 7, 6]), [Port::PROMPT, silent]);
    assert_eq!(heard.result, Err(ErrorKind::Other));
    let timeout = at_bits(10) + Duration::from_millis(25);
    assert_eq!(heard.end, timeout);
    assert_eq!(
        *heard.served[0].answers.borrow(),
        [(Err(TargetError), timeout)],
        "the port that answered is told, not left waiting"
    );
    assert!(heard.served[0].stored.borrow().is_empty());
    assert_eq!(heard.stats.timeouts, 1);
}

#[test]
fn a_read_heard_by_two_ports_reads_the_and_of_their_bytes() {
    let ports = [
        Port {
            reply: &[0b1100_1010, 0xF0, 0x33],
            ..Port::PROMPT
        },
        Port {
            reply: &[0b1010_0110, 0x0F],
            ..Port::PROMPT
        },
    ];
    let heard = two_ports(None, ports);
    assert_eq!(heard.result, Ok(()));
    assert_eq!(
        heard.read,
        [0b1000_0010, 0x00, 0x33],
        "past its data a port leaves SDA high"
    );
    for port in &heard.served {
        assert_eq!(*port.answers.borrow(), [(Ok(()), at_bits(10 + 27))]);
    }
    assert_eq!(heard.end, at_bits(10 + 27 + 1));
    assert_eq!(heard.stats.collisions, 1);

    // The second port is cut 3 bits into the first byte: its first 3 bits (101) still meet the other's, then it
    // drives nothing.
    let [first, second] = ports;
    let cut = Port {
        cut: Some(BIT * (10 + 3)),
        ..second
    };
    let heard = two_ports(None, [first, cut]);
    assert_eq!(heard.result, Ok(()));
    assert_eq!(heard.read, [0b1000_1010, 0xF0, 0x33]);
    assert_eq!(*heard.served[0].answers.borrow(), [(Ok(()), at_bits(10 + 27))]);
    assert!(heard.served[1].answers.borrow().is_empty(), "its firmware is gone");
    assert_eq!((heard.stats.torn, heard.stats.collisions), (1, 1));
}

#[test]
fn two_devices_heard_at_once_meet_on_the_wires() {
    let bus = Bus::new(TIMING);
    bus.fit_mux(0x70);
    let (a, b) = (Register::at(0x29), Register::at(0x29));
    bus.attach(a.clone(), Route::Mux(0));
    let id = bus.attach(b.clone(), Route::Mux(1));
    // b sends 7, 4, 5 where a sends 1, 2, 3.
    bus.tamper(
        id,
        Tamper {
            read_xor: 0x06,
            ..Tamper::NONE
        },
    );
    let mut master = bus.master();
    run(async {
        master.write(0x70, &[0b0000_0011]).await.unwrap();
    });
    let mut read = [0; 3];
    run(async {
        master.read(0x29, &mut read).await.unwrap();
    });
    assert_eq!(read, [1, 0, 1]);
    // One not acknowledging is hidden behind the other.
    a.borrow_mut().reply = Reply::Nack;
    run(async {
        master.write(0x29, &[5]).await.unwrap();
    });
    assert_eq!((a.borrow().written.len(), b.borrow().written.len()), (1, 1));
    // SCL is held as long as the longer stretch.
    b.borrow_mut().reply = Reply::Stretch(Duration::from_millis(1));
    let end = run(async {
        master.write(0x29, &[6]).await.unwrap();
    });
    assert_eq!(end, at_bits(10 + 9 + 1) + Duration::from_millis(1));
    assert_eq!(bus.stats().collisions, 3);
}

#[test]
fn a_device_and_a_port_at_one_address_both_take_a_write() {
    let bus = Bus::new(TIMING);
    bus.fit_mux(0x70);
    let register = Register::at(0x29);
    register.borrow_mut().reply = Reply::Stretch(Duration::from_millis(1));
    bus.attach(register.clone(), Route::Mux(0));
    let id = bus.attach_target(0x29, Route::Mux(1));
    let mut master = bus.master();
    run(async {
        master.write(0x70, &[0b0000_0011]).await.unwrap();
    });
    let clock = clock::take();
    let served = Served::default();
    let ended = Cell::new(None);
    let mut executor = Executor::new();
    executor.spawn(firmware(
        bus.target(id).unwrap(),
        Duration::from_micros(200),
        &[],
        &served,
    ));
    executor.spawn(async {
        let result = master.write(0x29, &[9, 8]).await;
        ended.set(Some((result, Instant::now())));
    });
    executor.run_for(&clock, Duration::from_millis(10), BIT);
    drop(executor);
    // The device's stretch is the longer: the bytes move once it is done.
    let moved = at_bits(10 + 18) + Duration::from_millis(1);
    assert_eq!(ended.get(), Some((Ok(()), moved + BIT)));
    assert_eq!(*served.answers.borrow(), [(Ok(()), moved)]);
    assert_eq!(*served.stored.borrow(), [vec![9, 8]]);
    assert_eq!(register.borrow().written, [vec![9, 8]]);
}
