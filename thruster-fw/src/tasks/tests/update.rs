//! The field update over the bus, on virtual time: a master writes an image into the DFU partition with tmc-proto's
//! extension, through the controller as it ships (`run`), which checks its image info and hands its ticket (length
//! and signature) to the bootloader with embassy-boot's mark. The signature is the bootloader's to check (lbv-boot's
//! tests, and the bench's field update, where the thruster's bootloader runs): here it is bytes the thruster keeps.

use super::*;
use crate::update::{INFO_OFFSET, MAX_PAYLOAD};
use core::future::Future;
use embedded_hal_async::i2c::ErrorKind;
use lbv_sim::flash::FlashTiming;
use lbv_sim::i2c::Master;
use tmc_proto::ext::{
    self, Chunk, Command, CommandFrame, CommandKind, ERASE_WAIT_MS, FINISH_WAIT_MS, FrameError, MAX_CHUNK, PAGE_LEN,
    Refusal, Reply, ReplyBody, SIGNATURE_LEN, crc32, reply_len,
};
use update_image::{ImageInfo, Target, Ticket, Version};

/// The signature a master sends with `payload`: bytes of its own here, which the thruster keeps for its bootloader
/// in the ticket.
fn sign(payload: &[u8]) -> [u8; SIGNATURE_LEN] {
    let crc = crc32(payload).to_le_bytes();
    core::array::from_fn(|i| crc[i % 4] ^ i as u8)
}

/// A payload of `len` bytes holding `info` at 0x200 and made-up code around it.
fn payload_of(info: ImageInfo, len: usize) -> Vec<u8> {
    let mut bytes: Vec<u8> = (0..len as u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
        .collect();
    bytes[INFO_OFFSET as usize..][..32].copy_from_slice(&info.to_bytes());
    bytes
}

/// A payload of `len` bytes for `target` (the information record's target byte), version 0.2.0.
fn payload(target: u8, len: usize) -> Vec<u8> {
    let target = Target::from_byte(target).expect("a target");
    payload_of(ImageInfo::new(target, Version::new(0, 2, 0)), len)
}

/// A master speaking the extension on the bench's bus: one command at a time, its reply read after it.
struct Client {
    master: Master,
    family: Family,
    seq: u8,
    /// Busy replies read.
    busy: u32,
}

impl Client {
    fn new(master: Master, family: Family) -> Self {
        Self {
            master,
            family,
            seq: 0,
            busy: 0,
        }
    }

    /// Write a command; returns its sequence number.
    async fn send(&mut self, command: Command) -> u8 {
        self.seq = self.seq.wrapping_add(1);
        let frame = CommandFrame { seq: self.seq, command };
        self.master
            .write(self.family.address(), frame.encode().as_bytes())
            .await
            .expect("the command is acknowledged");
        self.seq
    }

    /// Read once what the thruster answers after a command of `kind`.
    async fn read(&mut self, kind: CommandKind) -> Result<Result<Reply, FrameError>, ErrorKind> {
        let mut bytes = [0; ext::MAX_FRAME_LEN];
        let read = &mut bytes[..reply_len(kind)];
        self.master.read(self.family.address(), read).await?;
        Ok(Reply::decode(read))
    }

    /// Send a command and read its reply, waiting as a master waits after it and reading again while busy.
    async fn exchange(&mut self, command: Command) -> Reply {
        let kind = command.kind();
        let seq = self.send(command).await;
        let wait = match kind {
            CommandKind::Erase => ERASE_WAIT_MS,
            CommandKind::Finish => FINISH_WAIT_MS,
            _ => 0,
        };
        Timer::after_millis(u64::from(wait)).await;
        for _ in 0..100 {
            let reply = self.read(kind).await.expect("the reply is read").expect("a reply");
            assert_eq!((reply.command(), reply.seq()), (kind, seq), "the reply to this command");
            if let Reply::Busy { .. } = reply {
                self.busy += 1;
                Timer::after_millis(5).await;
                continue;
            }
            return reply;
        }
        panic!("{kind:?} still busy after 100 reads");
    }

    /// The reply's body, which must be done.
    async fn done(&mut self, command: Command) -> ReplyBody {
        match self.exchange(command).await {
            Reply::Done { body, .. } => body,
            other => panic!("{command:?}: {other:?}"),
        }
    }

    /// The refusal, which it must be.
    async fn refused(&mut self, command: Command) -> Refusal {
        match self.exchange(command).await {
            Reply::Refused { refusal, .. } => refusal,
            other => panic!("{command:?}: {other:?}"),
        }
    }

    async fn order(&mut self, step: i8) {
        let order = Order::new(Speed::new(step).unwrap()).encode(self.family);
        self.master.write(self.family.address(), &order).await.unwrap();
    }

    async fn status(&mut self) -> Vec<u8> {
        let mut status = vec![0; self.family.status_len()];
        self.master.read(self.family.address(), &mut status).await.unwrap();
        status
    }

    /// Begin an update of `payload` for this thruster's target.
    async fn begin(&mut self, payload: &[u8]) -> ReplyBody {
        let target = Target::thruster(self.family).to_byte();
        self.done(Command::Begin {
            payload_len: payload.len() as u32,
            target,
        })
        .await
    }

    /// Erase the pages `pages` and write the payload's chunks in them; returns the chunks written.
    async fn write_pages(&mut self, payload: &[u8], pages: core::ops::Range<usize>) -> usize {
        let mut chunks = 0;
        for page in pages {
            assert_eq!(
                self.done(Command::Erase { page: page as u16 }).await,
                ReplyBody::Erase { page: page as u16 }
            );
            let start = page * PAGE_LEN as usize;
            let end = (start + PAGE_LEN as usize).min(payload.len());
            for offset in (start..end).step_by(MAX_CHUNK) {
                let data = &payload[offset..(offset + MAX_CHUNK).min(end)];
                let reply = self
                    .done(Command::Write {
                        offset: offset as u32,
                        data: Chunk::new(data).unwrap(),
                    })
                    .await;
                let expected = ReplyBody::Write {
                    offset: offset as u32,
                    len: data.len() as u8,
                    crc: crc32(data),
                };
                assert_eq!(reply, expected, "the flash holds the chunk at {offset:#x}");
                chunks += 1;
            }
        }
        chunks
    }

    async fn finish(&mut self, payload: &[u8]) -> Reply {
        self.exchange(Command::Finish {
            payload_len: payload.len() as u32,
            signature: sign(payload),
        })
        .await
    }
}

fn pages_of(payload: &[u8]) -> core::ops::Range<usize> {
    0..payload.len().div_ceil(PAGE_LEN as usize)
}

impl Bench {
    /// Run `script` as the bus's master until it ends, moving the clock to each next timer (so every bit time is
    /// exact); returns what it returned.
    fn script<T: 'static, F: Future<Output = T> + 'static>(&mut self, script: impl FnOnce(Client) -> F) -> T {
        let out = Rc::new(RefCell::new(None));
        let future = script(Client::new(self.bus.master(), self.config.family));
        let slot = out.clone();
        self.executor.spawn(async move {
            *slot.borrow_mut() = Some(future.await);
        });
        let limit = Instant::now() + Duration::from_secs(120);
        loop {
            self.executor.run_until_idle();
            if let Some(done) = out.borrow_mut().take() {
                return done;
            }
            let next = clock::next_alarm().expect("the script waits for something");
            assert!(next <= limit, "the script ran for two minutes");
            clock::advance(next.saturating_duration_since(Instant::now()));
        }
    }

    /// Let the flash's erases and writes stall the controller's CPU as the G431's do.
    fn stall_on_flash(&self) {
        self.dfu.stall_cpu(&self.cpu, FlashTiming::G431);
        self.boot.stall_cpu(&self.cpu, FlashTiming::G431);
    }
}

/// A SeaBotix controller whose flash stalls its CPU as the G431's does.
fn stalling() -> Bench {
    let bench = Bench::new(Family::SeaBotix);
    bench.stall_on_flash();
    bench
}

#[test]
fn a_whole_image_is_written_read_back_checked_finished_and_marked_for_the_swap() {
    let mut bench = stalling();
    let image = payload(1, 32 * 1024);
    let expected_info = crate::sim::info_record(Family::SeaBotix, Version::new(0, 1, 0));
    let (image_for_master, started) = (image.clone(), Instant::now());
    let (version, transfer, reboot_asked) = bench.script(|mut master| async move {
        master.order(0).await;
        let version = master.done(Command::Version).await;
        let image = image_for_master;
        let begun = Instant::now();
        assert_eq!(master.begin(&image).await, ReplyBody::Begin { payload_len: 32768 });
        let chunks = master.write_pages(&image, pages_of(&image)).await;
        assert_eq!(chunks, 512);
        let check = master
            .done(Command::Check {
                offset: 0,
                len: image.len() as u32,
            })
            .await;
        assert_eq!(
            check,
            ReplyBody::Check {
                offset: 0,
                len: 32768,
                crc: crc32(&image)
            }
        );
        assert_eq!(
            master.finish(&image).await,
            Reply::Done {
                seq: master.seq,
                body: ReplyBody::Finish { payload_len: 32768 }
            }
        );
        let transfer = Instant::now() - begun;
        let reboot = master.done(Command::Reboot).await;
        (version, transfer, reboot)
    });
    assert_eq!(
        version,
        ReplyBody::Version {
            protocol: ext::PROTOCOL_VERSION,
            on_trial: false,
            checks_signatures: true,
            marked: false,
            dev_key: update_image::UPDATE_KEY_IS_DEV,
            verdict: 0,
            max_payload: MAX_PAYLOAD,
            info: expected_info
        }
    );
    assert_eq!(reboot_asked, ReplyBody::Reboot);
    assert_eq!(&bench.dfu.contents()[..image.len()], &image[..]);
    assert_eq!(bench.boot_state(), State::Swap, "marked for the bootloader to swap in");
    assert_eq!(
        Ticket::parse(&bench.ticket.contents()),
        Some(Ticket {
            payload_len: 32768,
            signature: sign(&image)
        }),
        "the ticket the bootloader checks it with"
    );
    // The reset comes once the master has read the reply.
    bench.elapse(Duration::from_millis(1));
    assert_eq!(bench.reboots.get(), 1);
    let stats = bench.bus.stats();
    eprintln!(
        "32 KiB image, 64-byte chunks, at 100 kbit/s: Begin to Finish's reply {} ms; {} bits on the bus ({} ms of \
         bit times) in {} transfers, {} timeouts; {} pages erased, the CPU stalled {} ms; from power-up {} ms",
        transfer.as_millis(),
        stats.bits,
        stats.bits * 10 / 1000,
        stats.transfers,
        stats.timeouts,
        bench.dfu.stats().erases,
        bench.cpu.stalled_total().as_millis(),
        (Instant::now() - started).as_millis(),
    );
    assert_eq!(stats.timeouts, 0, "no read met a stalled CPU");
    assert_eq!(bench.dfu.stats().erases, 16);
    // 512 writes of 77 bytes and their replies of 17, 16 erases and theirs: 4.5 s of bit times. The master's 30 ms
    // after each erase and the reads held by the writes' programming (0.8 ms a chunk) bring it to 5.2 s.
    assert!((5_000..6_000).contains(&transfer.as_millis()), "{transfer:?}");
}

#[test]
fn an_erase_read_too_early_meets_the_stalled_cpu() {
    // With the reference timing the read is held (SCL stretched) for the whole 25 ms erase: at the master's 25 ms
    // timeout, which a slower erase would pass. Hence the master's wait before it reads.
    let mut bench = stalling();
    let image = payload(1, 4096);
    let (held, reply) = bench.script(|mut master| async move {
        master.begin(&image).await;
        master.send(Command::Erase { page: 0 }).await;
        let start = Instant::now();
        let reply = master.read(CommandKind::Erase).await;
        (Instant::now() - start, reply)
    });
    assert!(held >= Duration::from_millis(25), "held {held:?}");
    assert_eq!(
        reply,
        Ok(Ok(Reply::Done {
            seq: 2,
            body: ReplyBody::Erase { page: 0 }
        }))
    );

    // A master that gives up sooner (20 ms) fails that read, and the reply the controller sent into it is gone:
    // the next read is the status. It sends the command again, with the same sequence number.
    drop(bench);
    let mut config = Config::reference(Family::SeaBotix, MotorKind::Brushless);
    config.bus.timeout = Duration::from_millis(20);
    let mut bench = Bench::with_flash(config, VolatileLatch::default(), Flash::new(1), Flash::new(DFU_PAGES));
    bench.stall_on_flash();
    let image = payload(1, 4096);
    let (too_early, after, again) = bench.script(|mut master| async move {
        master.begin(&image).await;
        let seq = master.send(Command::Erase { page: 0 }).await;
        let too_early = master.read(CommandKind::Erase).await;
        Timer::after_millis(u64::from(ERASE_WAIT_MS)).await;
        let after = master.read(CommandKind::Erase).await.unwrap();
        master.seq = seq.wrapping_sub(1);
        let again = master.exchange(Command::Erase { page: 0 }).await;
        (too_early, after, again)
    });
    assert!(too_early.is_err(), "{too_early:?}");
    assert_eq!(bench.bus.stats().timeouts, 1);
    assert_eq!(
        after,
        Err(FrameError::MessageType {
            expected: ext::EXT_REPLY_MT,
            actual: 0x53
        })
    );
    assert_eq!(
        again,
        Reply::Done {
            seq: 2,
            body: ReplyBody::Erase { page: 0 }
        }
    );
    assert_eq!(bench.dfu.stats().erases, 2);
}

#[test]
fn nothing_is_done_while_the_thruster_is_ordered_to_turn_and_a_turning_order_drops_the_update() {
    let mut bench = stalling();
    let io = bench.io.clone();
    let image = payload(1, 8192);
    let expected = image.clone();
    bench.script(move |mut master| async move {
        // Ordered to turn: everything but Version is refused, the motor drives as ever.
        master.order(40).await;
        Timer::after_millis(20).await;
        assert!(io.bridge.get().1.value() > 0);
        assert!(matches!(master.done(Command::Version).await, ReplyBody::Version { .. }));
        assert_eq!(
            master
                .refused(Command::Begin {
                    payload_len: 8192,
                    target: 1
                })
                .await,
            Refusal::Driving
        );
        // Ordered to zero: the duty comes down, then the update may begin.
        master.order(0).await;
        while io.bridge.get().1 != Duty::ZERO {
            Timer::after_millis(1).await;
        }
        master.begin(&image).await;
        master.write_pages(&image, 0..1).await;
        // An order in the middle: it drives the motor as any order does, and the update is dropped.
        master.order(30).await;
        Timer::after_millis(20).await;
        assert!(io.bridge.get().1.value() > 0, "the order drives the motor");
        let status = master.status().await;
        assert!(Status::decode(Family::SeaBotix, &status).is_ok());
        assert_eq!(master.refused(Command::Erase { page: 1 }).await, Refusal::Driving);
        // Back at rest, the update is gone: it must begin again.
        master.order(0).await;
        while io.bridge.get().1 != Duty::ZERO {
            Timer::after_millis(1).await;
        }
        assert_eq!(master.refused(Command::Erase { page: 1 }).await, Refusal::NotBegun);
        assert_eq!(
            master
                .refused(Command::Finish {
                    payload_len: 8192,
                    signature: sign(&image)
                })
                .await,
            Refusal::NotBegun
        );
        master.begin(&image).await;
        master.write_pages(&image, 1..4).await;
        assert!(matches!(master.finish(&image).await, Reply::Done { .. }));
    });
    assert_eq!(bench.dfu.stats().erases, 4, "no erase while ordered to turn");
    assert_eq!(&bench.dfu.contents()[..8192], &expected[..]);
    assert_eq!(bench.boot_state(), State::Swap);
}

#[test]
fn refusals_over_the_bus_each_with_its_own_code() {
    let mut bench = stalling();
    let image = payload(1, 4096);
    let legacy_image = payload(2, 4096);
    let refusals = bench.script(move |mut master| async move {
        let mut seen = Vec::new();
        let mut refused = async |master: &mut Client, command| seen.push(master.refused(command).await);
        refused(&mut master, Command::Erase { page: 0 }).await;
        refused(&mut master, Command::Reboot).await;
        for (payload_len, target) in [(4096, 2), (4097, 1), (MAX_PAYLOAD + 8, 1), (0x238, 1)] {
            refused(&mut master, Command::Begin { payload_len, target }).await;
        }
        master.begin(&image).await;
        refused(&mut master, Command::Erase { page: 2 }).await;
        let chunk = Chunk::new(&[0; 8]).unwrap();
        refused(
            &mut master,
            Command::Write {
                offset: 4096,
                data: chunk,
            },
        )
        .await;
        refused(&mut master, Command::Write { offset: 4, data: chunk }).await;
        refused(&mut master, Command::Check { offset: 4000, len: 97 }).await;
        // A payload whose record names the other family, with a good signature.
        master.write_pages(&legacy_image, 0..2).await;
        refused(
            &mut master,
            Command::Finish {
                payload_len: 4096,
                signature: sign(&legacy_image),
            },
        )
        .await;
        // Over written flash.
        refused(
            &mut master,
            Command::Write {
                offset: 0,
                data: Chunk::new(&[1; 8]).unwrap(),
            },
        )
        .await;
        // This family's image, older than the one that runs (0.1.0) and not signed as a rollback.
        let older = payload_of(ImageInfo::new(Target::ThrusterSeabotix, Version::new(0, 0, 9)), 4096);
        master.write_pages(&older, 0..1).await;
        refused(
            &mut master,
            Command::Finish {
                payload_len: 4096,
                signature: sign(&older),
            },
        )
        .await;
        refused(
            &mut master,
            Command::Finish {
                payload_len: 4088,
                signature: sign(&image),
            },
        )
        .await;
        // A payload without a record.
        let mut bare = image.clone();
        bare[INFO_OFFSET as usize..][..4].copy_from_slice(b"none");
        master.write_pages(&bare, 0..1).await;
        refused(
            &mut master,
            Command::Finish {
                payload_len: 4096,
                signature: sign(&bare),
            },
        )
        .await;
        // A format-1 record: no key for the update after it.
        let mut format_1 = image.clone();
        format_1[INFO_OFFSET as usize + 4] = 1;
        master.write_pages(&format_1, 0..1).await;
        refused(
            &mut master,
            Command::Finish {
                payload_len: 4096,
                signature: sign(&format_1),
            },
        )
        .await;
        master.write_pages(&image, 0..1).await;
        assert!(matches!(master.finish(&image).await, Reply::Done { .. }));
        refused(
            &mut master,
            Command::Begin {
                payload_len: 4096,
                target: 1,
            },
        )
        .await;
        refused(&mut master, Command::Erase { page: 0 }).await;
        seen
    });
    use Refusal::*;
    assert_eq!(
        refusals,
        [
            NotBegun,
            NotFinished,
            WrongFamily,
            Unaligned,
            TooLarge,
            Truncated,
            OutOfRange,
            OutOfRange,
            Unaligned,
            OutOfRange,
            WrongFamily,
            NotErased,
            Older,
            Truncated,
            NoImageInfo,
            NoKey,
            Finished,
            Finished
        ]
    );
    assert_eq!(bench.boot_state(), State::Swap);
}

#[test]
fn an_image_on_trial_takes_no_update() {
    let mut bench = Bench::on_trial();
    let image = payload(1, 4096);
    let (version, refusal) = bench.script(move |mut master| async move {
        master.order(0).await;
        let version = master.done(Command::Version).await;
        let refusal = master
            .refused(Command::Begin {
                payload_len: 4096,
                target: 1,
            })
            .await;
        let _ = image;
        (version, refusal)
    });
    assert!(matches!(version, ReplyBody::Version { on_trial: true, .. }));
    assert_eq!(refusal, Refusal::OnTrial);
}

#[test]
fn an_interrupted_transfer_resumes_from_the_first_chunk_that_differs() {
    let family = Family::SeaBotix;
    let image = payload(1, 16 * 1024);
    let (boot, dfu) = (Flash::new(1), Flash::new(DFU_PAGES));
    let config = Config::reference(family, MotorKind::Brushless);
    let mut bench = Bench::with_flash(config.clone(), VolatileLatch::default(), boot.clone(), dfu.clone());
    // The power goes in the middle of the 150th chunk's programming (page 4): the flash holds half a chunk.
    let torn_at = 4 * 2048 + 22 * 64;
    let first_run = image.clone();
    let flash = dfu.clone();
    let written = bench.script(move |mut master| async move {
        master.begin(&first_run).await;
        let written = master.write_pages(&first_run, 0..4).await;
        master.done(Command::Erase { page: 4 }).await;
        for offset in (4 * 2048..torn_at).step_by(64) {
            let data = Chunk::new(&first_run[offset..offset + 64]).unwrap();
            master
                .done(Command::Write {
                    offset: offset as u32,
                    data,
                })
                .await;
        }
        flash.cut_power_after(20);
        let data = Chunk::new(&first_run[torn_at..torn_at + 64]).unwrap();
        let torn = master
            .refused(Command::Write {
                offset: torn_at as u32,
                data,
            })
            .await;
        assert_eq!(torn, Refusal::FlashError);
        written + 22
    });
    assert_eq!(written, 150);
    drop(bench);

    // Power back: a fresh controller, the same flash. The master begins again and looks for the first chunk that
    // differs, halving the range each time (11 checks for 256 chunks), then erases its page and writes from there.
    dfu.power_on();
    let mut bench = Bench::with_flash(config, VolatileLatch::default(), boot, dfu.clone());
    bench.stall_on_flash();
    let resumed = image.clone();
    let (first_bad, checks, rewritten) = bench.script(move |mut master| async move {
        master.order(0).await;
        master.begin(&resumed).await;
        // The longest prefix of whole chunks that checks: `good` chunks do, more than `bad` do not.
        let (mut good, mut bad) = (0usize, resumed.len() / 64);
        let mut checks = 0;
        while good < bad {
            let mid = (good + bad).div_ceil(2);
            let len = (mid * 64) as u32;
            let ReplyBody::Check { crc, .. } = master.done(Command::Check { offset: 0, len }).await else {
                panic!("no check")
            };
            checks += 1;
            if crc == crc32(&resumed[..len as usize]) {
                good = mid;
            } else {
                bad = mid - 1;
            }
        }
        let first_bad = good;
        let page = first_bad * 64 / 2048;
        let rewritten = master.write_pages(&resumed, page..resumed.len() / 2048).await;
        assert!(matches!(master.finish(&resumed).await, Reply::Done { .. }));
        (first_bad, checks, rewritten)
    });
    assert_eq!(first_bad, 150, "the torn chunk is the first that differs");
    assert!(checks <= 9, "{checks} checks");
    assert_eq!(rewritten, 256 - 4 * 32, "from the torn chunk's page on");
    assert_eq!(&dfu.contents()[..image.len()], &image[..]);
    assert_eq!(bench.boot_state(), State::Swap);
}

#[test]
fn bad_extension_frames_are_ignored_and_change_nothing() {
    let mut bench = stalling();
    let image = payload(1, 4096);
    let io = bench.io.clone();
    let (status, seq, pending, status_after) = bench.script(move |mut master| async move {
        master.order(0).await;
        master.begin(&image).await;
        let address = Family::SeaBotix.address();
        // An erase whose CRC is wrong: discarded; the read after it is the status.
        let mut bad = CommandFrame {
            seq: 50,
            command: Command::Erase { page: 0 },
        }
        .encode()
        .as_bytes()
        .to_vec();
        *bad.last_mut().unwrap() ^= 1;
        master.master.write(address, &bad).await.unwrap();
        let status = master.read(CommandKind::Erase).await.unwrap();
        // A good erase, then a torn frame before its reply is read: the reply stands.
        let seq = master.send(Command::Erase { page: 1 }).await;
        Timer::after_millis(30).await;
        let mut torn = CommandFrame {
            seq: 51,
            command: Command::Write {
                offset: 0,
                data: Chunk::new(&[0; 64]).unwrap(),
            },
        }
        .encode()
        .as_bytes()
        .to_vec();
        torn.truncate(40);
        master.master.write(address, &torn).await.unwrap();
        // And one with a wrong guard, and a command from a later version.
        let mut guard = CommandFrame {
            seq: 52,
            command: Command::Reboot,
        }
        .encode()
        .as_bytes()
        .to_vec();
        guard[3] ^= 0x80;
        master.master.write(address, &guard).await.unwrap();
        let mut unknown = vec![ext::EXT_MT, 0x40, 53, ext::guard(ext::EXT_MT, 0x40, 53)];
        unknown.extend(crc32(&unknown).to_le_bytes());
        master.master.write(address, &unknown).await.unwrap();
        let pending = master.read(CommandKind::Erase).await.unwrap().unwrap();
        let status_after = master.status().await;
        assert!(io.bridge.get().1 == Duty::ZERO);
        (status, seq, pending, status_after)
    });
    assert!(
        matches!(
            status,
            Err(FrameError::MessageType {
                expected: 0x81,
                actual: 0x53
            })
        ),
        "the status answers a read after a bad frame: {status:?}"
    );
    assert_eq!(
        pending,
        Reply::Done {
            seq,
            body: ReplyBody::Erase { page: 1 }
        }
    );
    assert!(Status::decode(Family::SeaBotix, &status_after).is_ok());
    assert_eq!(bench.dfu.stats().erases, 1, "only the good erase");
    assert_eq!(bench.dfu.stats().programmed, 0);
    assert_eq!(bench.reboots.get(), 0);
}

#[test]
fn the_status_read_and_orders_work_as_ever_between_extension_exchanges() {
    for family in Family::ALL {
        let mut bench = Bench::new(family);
        let io = bench.io.clone();
        let image = payload(Target::thruster(family).to_byte(), 4096);
        bench.script(move |mut master| async move {
            master.order(0).await;
            master.begin(&image).await;
            for page in 0..2 {
                let status = master.status().await;
                let status = Status::decode(family, &status).expect("a status between exchanges");
                assert!(status.status.faults().is_empty());
                master.order(0).await;
                master.write_pages(&image, page..page + 1).await;
            }
            // A command, then an order and its duty before the reply is read: the order is taken, and the read
            // after it is the reply (one pending reply: the read after a command gets it).
            let seq = master.send(Command::Check { offset: 0, len: 4096 }).await;
            master.order(0).await;
            let reply = master.read(CommandKind::Check).await.unwrap().unwrap();
            assert_eq!(reply.seq(), seq);
            let status = master.status().await;
            assert!(Status::decode(family, &status).is_ok());
            assert!(matches!(master.finish(&image).await, Reply::Done { .. }));
            // Orders drive the motor as before.
            master.order(50).await;
            Timer::after_millis(20).await;
            assert!(io.bridge.get().1.value() > 0);
        });
        assert_eq!(bench.boot_state(), State::Swap, "{family:?}");
        let link = bench.shared.link.try_get().unwrap();
        assert_eq!(link.order.speed.step(), 50);
    }
}

#[test]
fn an_ids_only_controller_discards_every_extension_frame() {
    // The IDS path as it was before the extension (`MasterLink::accept`), for both families, on every command: the
    // whole frame, and its first four bytes as a 4-byte buffer keeps them. Nothing is taken; the checksum fails
    // whenever the type is let through.
    let image = payload(1, 4096);
    let commands = [
        Command::Version,
        Command::Begin {
            payload_len: 4096,
            target: 1,
        },
        Command::Erase { page: 0 },
        Command::Write {
            offset: 0,
            data: Chunk::new(&image[..64]).unwrap(),
        },
        Command::Check { offset: 0, len: 4096 },
        Command::Finish {
            payload_len: 4096,
            signature: sign(&image),
        },
        Command::Reboot,
    ];
    for family in Family::ALL {
        let mut link = crate::MasterLink::new(family);
        for (seq, command) in (0..=255u8).flat_map(|seq| commands.map(|command| (seq, command))) {
            let frame = CommandFrame { seq, command }.encode();
            let bytes = frame.as_bytes();
            assert!(link.accept(bytes).is_err());
            assert!(link.accept(&bytes[..4]).is_err());
            // Were MT its own type, the checksum would still fail.
            let as_own_type = [family.order_type(), bytes[1], bytes[2], bytes[3]];
            assert!(matches!(
                link.accept(&as_own_type),
                Err(tmc_proto::DecodeError::Checksum { .. })
            ));
        }
        assert_eq!(link.orders(), 0);
        assert_eq!(link.order(), Order::STOP);
    }
}
