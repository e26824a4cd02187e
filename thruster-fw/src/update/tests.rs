//! The receiver's rules command by command, on lbv-sim's flash with embassy-boot's updater (the bus and the tasks
//! around it: `tasks/tests/update.rs`).

use super::*;
use crate::control::LinkUpdate;
use crate::shared::Replies;
use crate::sim::{BootUpdater, DFU_PAGES, info_record};
use embassy_futures::block_on;
use embassy_time::Instant;
use lbv_sim::flash::Flash;
use tmc_proto::ext::Chunk;
use tmc_proto::ext::CommandKind;
use tmc_proto::{Order, Speed};
use update_image::{ImageInfo, Target, Verdict, Version};

const REST: Motion = Motion {
    at_rest: true,
    turning_orders: 0,
};

struct Rig {
    receiver: Receiver,
    dfu: Flash<8, 2048>,
    updater: BootUpdater,
    seq: u8,
}

impl Rig {
    fn new() -> Self {
        let dfu = Flash::new(DFU_PAGES);
        let updater = BootUpdater::new(Family::SeaBotix, Flash::new(1), Flash::new(1));
        Self {
            receiver: Receiver::new(Family::SeaBotix),
            dfu,
            updater,
            seq: 0,
        }
    }

    fn run(&mut self, command: Command, motion: Motion) -> Result<ReplyBody, Refusal> {
        self.seq = self.seq.wrapping_add(1);
        let frame = CommandFrame { seq: self.seq, command };
        let mut dfu = self.dfu.clone();
        let outcome = block_on(self.receiver.handle(frame, motion, false, &mut dfu, &mut self.updater));
        assert_eq!(
            (outcome.reply.seq(), outcome.reply.command()),
            (self.seq, command.kind())
        );
        match outcome.reply {
            Reply::Done { body, .. } => Ok(body),
            Reply::Refused { refusal, .. } => Err(refusal),
            Reply::Busy { .. } => panic!("the receiver never answers busy itself"),
        }
    }

    fn at_rest(&mut self, command: Command) -> Result<ReplyBody, Refusal> {
        self.run(command, REST)
    }

    fn begin(&mut self, payload_len: u32) -> Result<ReplyBody, Refusal> {
        self.at_rest(Command::Begin { payload_len, target: 1 })
    }
}

fn write(offset: u32, data: &[u8]) -> Command {
    Command::Write {
        offset,
        data: Chunk::new(data).unwrap(),
    }
}

#[test]
fn a_short_last_chunk_is_padded_with_erased_bytes_and_its_crc_is_of_the_chunk() {
    let mut rig = Rig::new();
    rig.begin(4096).unwrap();
    rig.at_rest(Command::Erase { page: 1 }).unwrap();
    let data = [0x11, 0x22, 0x33];
    assert_eq!(
        rig.at_rest(write(4088, &data)),
        Ok(ReplyBody::Write {
            offset: 4088,
            len: 3,
            crc: crc32(&data)
        })
    );
    assert_eq!(
        &rig.dfu.contents()[4088..4096],
        &[0x11, 0x22, 0x33, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]
    );
    assert_eq!(rig.dfu.stats().programmed, 8);
}

use tmc_proto::ext::crc32;

#[test]
fn a_write_sent_again_is_answered_again_without_writing() {
    let mut rig = Rig::new();
    rig.begin(4096).unwrap();
    rig.at_rest(Command::Erase { page: 0 }).unwrap();
    let first = rig.at_rest(write(64, &[7; 64]));
    assert_eq!(rig.at_rest(write(64, &[7; 64])), first);
    assert_eq!(rig.dfu.stats().programmed, 64);
    assert_eq!(rig.at_rest(write(64, &[8; 64])), Err(Refusal::NotErased));
}

#[test]
fn nothing_touches_the_flash_outside_the_payload() {
    let mut rig = Rig::new();
    rig.begin(4096).unwrap();
    for command in [
        Command::Erase { page: 2 },
        Command::Erase { page: u16::MAX },
        write(4096, &[0; 8]),
        write(4090 - 2, &[0; 16]),
        write(u32::MAX - 7, &[0; 8]),
        Command::Check { offset: 0, len: 4097 },
        Command::Check {
            offset: u32::MAX,
            len: u32::MAX,
        },
    ] {
        assert_eq!(rig.at_rest(command), Err(Refusal::OutOfRange), "{command:?}");
    }
    assert_eq!(rig.at_rest(write(4092, &[0; 4])), Err(Refusal::Unaligned));
    assert_eq!(rig.dfu.stats().erases, 0);
    assert_eq!(rig.dfu.stats().programmed, 0);
}

#[test]
fn begin_checks_the_payload_and_the_state() {
    let mut rig = Rig::new();
    assert_eq!(
        rig.at_rest(Command::Begin {
            payload_len: 4096,
            target: 2
        }),
        Err(Refusal::WrongFamily)
    );
    assert_eq!(
        rig.at_rest(Command::Begin {
            payload_len: 4096,
            target: 3
        }),
        Err(Refusal::WrongFamily)
    );
    assert_eq!(rig.begin(4100), Err(Refusal::Unaligned));
    assert_eq!(rig.begin(MAX_PAYLOAD + 8), Err(Refusal::TooLarge));
    assert_eq!(rig.begin(INFO_END - 8), Err(Refusal::Truncated));
    assert_eq!(rig.receiver.begun(), None);
    assert_eq!(
        rig.begin(MAX_PAYLOAD),
        Ok(ReplyBody::Begin {
            payload_len: MAX_PAYLOAD
        })
    );
    assert_eq!(rig.receiver.begun(), Some(MAX_PAYLOAD));
    // Begin again: a new payload length, nothing erased.
    assert_eq!(rig.begin(INFO_END), Ok(ReplyBody::Begin { payload_len: INFO_END }));
    assert_eq!(rig.dfu.stats().erases, 0);
    // On trial: refused, whatever the rest.
    let frame = CommandFrame {
        seq: 1,
        command: Command::Begin {
            payload_len: 4096,
            target: 1,
        },
    };
    let mut dfu = rig.dfu.clone();
    let outcome = block_on(rig.receiver.handle(frame, REST, true, &mut dfu, &mut rig.updater));
    assert!(matches!(
        outcome.reply,
        Reply::Refused {
            refusal: Refusal::OnTrial,
            ..
        }
    ));
}

#[test]
fn a_turning_order_or_a_duty_refuses_everything_but_version_and_drops_the_update() {
    let mut rig = Rig::new();
    rig.begin(4096).unwrap();
    let braking = Motion {
        at_rest: false,
        turning_orders: 0,
    };
    // Still braking after a zero order: refused, but the update stands.
    assert_eq!(rig.run(Command::Erase { page: 0 }, braking), Err(Refusal::Driving));
    assert_eq!(rig.receiver.begun(), Some(4096));
    assert!(rig.run(Command::Version, braking).is_ok());
    // A non-zero order came, even if zero followed it: dropped.
    let ordered_and_back = Motion {
        at_rest: true,
        turning_orders: 1,
    };
    assert_eq!(
        rig.run(Command::Erase { page: 0 }, ordered_and_back),
        Err(Refusal::NotBegun)
    );
    assert_eq!(rig.receiver.begun(), None);
    assert_eq!(rig.dfu.stats().erases, 0);
}

#[test]
fn the_post_mortem_record_is_read_in_parts_whatever_the_motor_does() {
    let mut rig = Rig::new();
    let driving = Motion {
        at_rest: false,
        turning_orders: 3,
    };
    // None held: a record of length 0, and nothing to read past its start.
    assert_eq!(
        rig.run(Command::PostMortem { offset: 0 }, driving),
        Ok(ReplyBody::PostMortem {
            len: 0,
            offset: 0,
            data: [0; MAX_CHUNK]
        })
    );
    assert_eq!(rig.at_rest(Command::PostMortem { offset: 1 }), Err(Refusal::OutOfRange));
    let record: [u8; RECORD_LEN] = core::array::from_fn(|i| i as u8 + 1);
    rig.updater.post_mortem = Some(record);
    let part = |rig: &mut Rig, offset: u8| match rig.run(Command::PostMortem { offset }, driving) {
        Ok(ReplyBody::PostMortem { len, offset: at, data }) => {
            assert_eq!((len, at), (RECORD_LEN as u8, offset));
            Ok(data)
        }
        other => other.map(|_| unreachable!("{other:?}")),
    };
    assert_eq!(part(&mut rig, 0).unwrap(), record[..64]);
    assert_eq!(part(&mut rig, 64).unwrap(), record[64..]);
    // The last bytes, zero past the end; the end itself is empty; past it is refused.
    assert_eq!(part(&mut rig, 100).unwrap()[..28], record[100..]);
    assert_eq!(part(&mut rig, 100).unwrap()[28..], [0; 36]);
    assert_eq!(part(&mut rig, 128).unwrap(), [0; MAX_CHUNK]);
    assert_eq!(part(&mut rig, 129), Err(Refusal::OutOfRange));
    assert_eq!(rig.dfu.stats().erases, 0);
}

#[test]
fn motion_comes_from_the_last_order_and_the_duty() {
    let shared = Shared::new();
    assert_eq!(Motion::of(&shared), REST, "stopped before any order");
    let link = |step: i8, orders, zero_orders| LinkUpdate {
        order: Order::new(Speed::new(step).unwrap()),
        orders,
        zero_orders,
        at: Instant::from_ticks(0),
        refused_since: None,
    };
    shared.link.sender().send(link(30, 2, 1));
    assert_eq!(
        Motion::of(&shared),
        Motion {
            at_rest: false,
            turning_orders: 1
        }
    );
    shared.link.sender().send(link(0, 3, 2));
    shared.duty.sender().send(Duty::new_saturating(-40));
    assert!(!Motion::of(&shared).at_rest, "braking");
    shared.duty.sender().send(Duty::ZERO);
    assert_eq!(
        Motion::of(&shared),
        Motion {
            at_rest: true,
            turning_orders: 1
        }
    );
}

#[test]
fn finish_and_reboot_need_their_predecessors() {
    let mut rig = Rig::new();
    let finish = Command::Finish {
        payload_len: 4096,
        signature: [0; 64],
    };
    assert_eq!(rig.at_rest(finish), Err(Refusal::NotBegun));
    assert_eq!(rig.at_rest(Command::Reboot), Err(Refusal::NotFinished));
    rig.begin(4096).unwrap();
    // Erased DFU: no record.
    assert_eq!(rig.at_rest(finish), Err(Refusal::NoImageInfo));
    rig.at_rest(Command::Erase { page: 0 }).unwrap();
    let mut record = info_record(Family::Legacy, Version::new(0, 0, 0));
    for (n, piece) in record.chunks(8).enumerate() {
        rig.at_rest(write(INFO_OFFSET + 8 * n as u32, piece)).unwrap();
    }
    assert_eq!(rig.at_rest(finish), Err(Refusal::WrongFamily));
    // A master's record: the wrong target too.
    rig.at_rest(Command::Erase { page: 0 }).unwrap();
    record[5] = 3;
    rig.at_rest(write(INFO_OFFSET, &record)).unwrap();
    assert_eq!(rig.at_rest(finish), Err(Refusal::WrongFamily));
    // This family's record, older than the 0.1.0 that runs.
    rig.at_rest(Command::Erase { page: 0 }).unwrap();
    rig.at_rest(write(
        INFO_OFFSET,
        &info_record(Family::SeaBotix, Version::new(0, 0, 0)),
    ))
    .unwrap();
    assert_eq!(rig.at_rest(finish), Err(Refusal::Older));
    assert!(!rig.receiver.finished());
    assert_eq!(rig.at_rest(Command::Reboot), Err(Refusal::NotFinished));
    // A newer one: marked, its ticket written for the bootloader, which checks the signature.
    rig.at_rest(Command::Erase { page: 0 }).unwrap();
    rig.at_rest(write(
        INFO_OFFSET,
        &info_record(Family::SeaBotix, Version::new(0, 2, 0)),
    ))
    .unwrap();
    assert_eq!(rig.at_rest(finish), Ok(ReplyBody::Finish { payload_len: 4096 }));
    assert!(rig.receiver.finished());
    assert_eq!(
        update_image::Ticket::parse(&rig.updater.ticket.contents()),
        Some(update_image::Ticket {
            payload_len: 4096,
            signature: [0; 64]
        })
    );
    assert_eq!(rig.at_rest(Command::Reboot), Ok(ReplyBody::Reboot));
}

/// The rig with a payload of 4096 bytes begun and `info` in its record (in the format `info` says).
fn holding(info: ImageInfo, running: ImageInfo) -> Rig {
    let mut rig = Rig::new();
    rig.updater.info = running.to_bytes();
    rig.begin(4096).unwrap();
    rig.at_rest(Command::Erase { page: 0 }).unwrap();
    let mut record = info.to_bytes();
    record[4] = info.format;
    rig.at_rest(write(INFO_OFFSET, &record)).unwrap();
    rig
}

const FINISH: Command = Command::Finish {
    payload_len: 4096,
    signature: [0x5A; 64],
};

#[test]
fn no_step_back_unless_signed_for_it_and_never_below_the_running_counter() {
    let at = |minor, counter| {
        ImageInfo::new(Target::ThrusterSeabotix, Version::new(0, minor, 0)).with_security_counter(counter)
    };
    let running = at(3, 3);
    let cases = [
        (at(2, 3), Err(Refusal::Older)),
        (
            at(2, 3).with_rollback(true),
            Ok(ReplyBody::Finish { payload_len: 4096 }),
        ),
        (at(4, 2), Err(Refusal::CounterBelow)),
        (at(2, 2).with_rollback(true), Err(Refusal::CounterBelow)),
        (at(3, 3), Ok(ReplyBody::Finish { payload_len: 4096 })),
        (
            ImageInfo { format: 1, ..at(4, 0) }.with_security_counter(0),
            Err(Refusal::NoKey),
        ),
    ];
    for (image, expected) in cases {
        let mut rig = holding(image, running);
        assert_eq!(rig.at_rest(FINISH), expected, "{image:?}");
        assert_eq!(rig.receiver.finished(), expected.is_ok(), "{image:?}");
    }
}

#[test]
fn the_version_says_what_is_marked_and_what_the_bootloader_refused() {
    let newer = ImageInfo::new(Target::ThrusterSeabotix, Version::new(0, 2, 0));
    let mut rig = holding(newer, ImageInfo::new(Target::ThrusterSeabotix, Version::new(0, 1, 0)));
    let flags = |rig: &mut Rig| match rig.at_rest(Command::Version) {
        Ok(ReplyBody::Version {
            marked,
            verdict,
            dev_key,
            ..
        }) => (marked, verdict, dev_key),
        other => panic!("{other:?}"),
    };
    assert_eq!(flags(&mut rig), (false, 0, update_image::UPDATE_KEY_IS_DEV));
    rig.at_rest(FINISH).unwrap();
    assert!(flags(&mut rig).0, "marked once finished");
    // The bootloader refused it (as it writes its verdict beside the ticket): the next start tells it.
    let mut page = rig.updater.ticket.clone();
    page.write(update_image::VERDICT_OFFSET, &Verdict::Signature.to_word())
        .unwrap();
    let mut restarted = Rig::new();
    restarted.updater.ticket = page;
    assert_eq!(
        flags(&mut restarted),
        (false, Verdict::Signature.code(), update_image::UPDATE_KEY_IS_DEV)
    );
}

#[test]
fn a_mark_on_a_running_image_on_trial_is_refused_and_writes_nothing() {
    let newer = ImageInfo::new(Target::ThrusterSeabotix, Version::new(0, 2, 0));
    let mut rig = holding(newer, ImageInfo::new(Target::ThrusterSeabotix, Version::new(0, 1, 0)));
    let mut word = [0; 8];
    block_on(embassy_boot::FirmwareState::new(&mut rig.updater.state.clone(), &mut word).mark_updated()).unwrap();
    let before = rig.updater.ticket.stats();
    assert_eq!(rig.at_rest(FINISH), Err(Refusal::OnTrial));
    assert_eq!(rig.updater.ticket.stats(), before, "no ticket written");
}

#[test]
fn the_information_record_is_read_as_update_image_writes_it() {
    let record = info_record(Family::SeaBotix, Version::new(1, 2, 3));
    assert_eq!(info_family(&record), Ok(Some(Family::SeaBotix)));
    assert_eq!(
        info_family(&info_record(Family::Legacy, Version::new(0, 0, 0))),
        Ok(Some(Family::Legacy))
    );
    let mut other = record;
    other[5] = 3;
    assert_eq!(info_family(&other), Ok(None));
    for (at, byte) in [(0, b'X'), (4, 3), (5, 0), (5, 0xFF)] {
        let mut bad = record;
        bad[at] = byte;
        assert_eq!(info_family(&bad), Err(Refusal::NoImageInfo), "byte {at} = {byte:#x}");
    }
    assert_eq!(info_family(&[0xFF; 32]), Err(Refusal::NoImageInfo), "erased flash");
    for family in Family::ALL {
        let mut record = [0; 32];
        record[..6].copy_from_slice(&[b'L', b'B', b'V', b'I', 1, Target::thruster(family).to_byte()]);
        assert_eq!(info_family(&record), Ok(Some(family)));
    }
}

#[test]
fn a_controller_without_a_dfu_partition_refuses_every_update() {
    let mut receiver = Receiver::new(Family::Legacy);
    let run = |receiver: &mut Receiver, command| {
        let frame = CommandFrame { seq: 9, command };
        block_on(receiver.handle(frame, REST, false, &mut NoUpdate, &mut NoUpdate)).reply
    };
    assert!(matches!(
        run(&mut receiver, Command::Version),
        Reply::Done {
            body: ReplyBody::Version {
                info,
                checks_signatures: false,
                ..
            },
            ..
        } if info == [0xFF; 32]
    ));
    assert!(matches!(
        run(
            &mut receiver,
            Command::Begin {
                payload_len: 4096,
                target: 2
            }
        ),
        Reply::Refused {
            refusal: Refusal::TooLarge,
            ..
        }
    ));
}

#[test]
fn the_pending_reply_is_busy_until_done_gone_once_read_and_replaced_by_a_newer_command() {
    let replies = Replies::new();
    assert!(replies.for_read().is_none());
    let erase = CommandFrame {
        seq: 4,
        command: Command::Erase { page: 0 },
    };
    replies.command(erase);
    let busy = replies.for_read().unwrap();
    assert_eq!(
        Reply::decode(busy.frame().as_bytes()),
        Ok(Reply::Busy {
            seq: 4,
            command: CommandKind::Erase
        })
    );
    // A busy reply read stays.
    replies.sent(&busy);
    assert!(replies.for_read().is_some());
    let done = Reply::Done {
        seq: 4,
        body: ReplyBody::Erase { page: 0 },
    };
    replies.complete(done);
    let pending = replies.for_read().unwrap();
    assert_eq!(Reply::decode(pending.frame().as_bytes()), Ok(done));
    replies.sent(&pending);
    assert!(
        replies.for_read().is_none(),
        "read once, gone: the next read is the status"
    );

    // A newer command replaces the reply, and the older one's completion does not overwrite it.
    replies.command(erase);
    replies.command(CommandFrame {
        seq: 5,
        command: Command::Version,
    });
    replies.complete(done);
    let pending = replies.for_read().unwrap();
    assert!(matches!(
        Reply::decode(pending.frame().as_bytes()),
        Ok(Reply::Busy { seq: 5, .. })
    ));
}
