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
