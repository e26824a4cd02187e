//! The courier's decisions, exchange by exchange, on explicit time; the whole path over the bus runs in the bench's
//! `field-update` scenario.

use super::*;
use crate::shared::{MAV_CMD_LBV_APPLY_UPDATE, MAV_CMD_LBV_QUERY_VERSION};
use tmc_proto::Family;
use tmc_proto::ext::CommandKind;
use update_image::{DEV_PUBLIC_KEY, IMAGE_RECORD_LEN, image_record};

const GCS: Sender = Sender {
    system: 255,
    component: 190,
};

fn t(ms: u64) -> Instant {
    Instant::from_millis(ms)
}

/// The shortest payload: its image info and key, and no more.
const SMALL: usize = MIN_PAYLOAD as usize;

/// A file header: target 1, version 0.2.0, a signature of 0x5A.
fn header(payload_len: u32) -> [u8; FILE_HEADER_LEN] {
    header_of(payload_len, [0, 2, 0, 0])
}

/// A file header: target 1, `version`, a signature of 0x5A.
fn header_of(payload_len: u32, version: [u8; 4]) -> [u8; FILE_HEADER_LEN] {
    let mut header = [0x5A; FILE_HEADER_LEN];
    header[..8].copy_from_slice(&[b'L', b'B', b'V', b'U', 1, 1, 0, 0]);
    header[8..12].copy_from_slice(&payload_len.to_le_bytes());
    header[12..16].copy_from_slice(&version);
    header
}

/// The image info of a SeaBotix image at `version`.
fn info_of(version: [u8; 4]) -> ImageInfo {
    ImageInfo::new(Target::ThrusterSeabotix, Version::from_bytes(version))
}

/// A courier with a transfer of `payload` begun for slot 0 and every byte handed on (at most a page and a write).
fn courier_with(payload: &[u8]) -> Courier {
    let mut courier = Courier::new();
    courier
        .begin(0, 1, payload.len() as u32, &header(payload.len() as u32))
        .unwrap();
    for (n, block) in payload.chunks(MAX_WRITE).enumerate() {
        courier.write((n * MAX_WRITE) as u32, block).unwrap();
    }
    courier.finish(true).unwrap();
    courier
}

fn done(exchange: &Exchange, body: ReplyBody) -> Result<Reply, ExchangeError> {
    Ok(Reply::Done {
        seq: exchange.frame.seq,
        body,
    })
}

fn refused(exchange: &Exchange, refusal: Refusal) -> Result<Reply, ExchangeError> {
    Ok(Reply::Refused {
        seq: exchange.frame.seq,
        command: exchange.frame.command.kind(),
        refusal,
    })
}

fn version(checks_signatures: bool, version: [u8; 4]) -> ReplyBody {
    running_info(checks_signatures, info_of(version))
}

/// A thruster's `Version` reply, its running image's info `info`.
fn running_info(checks_signatures: bool, info: ImageInfo) -> ReplyBody {
    ReplyBody::Version {
        protocol: 1,
        on_trial: false,
        checks_signatures,
        marked: false,
        dev_key: false,
        verdict: 0,
        max_payload: 58 * 1024,
        info: info.to_bytes(),
    }
}

/// What a thruster holding `dfu` and running `running` answers to `exchange` (and does: erases, writes).
fn answer(dfu: &mut [u8], exchange: &Exchange, running: [u8; 4]) -> Result<Reply, ExchangeError> {
    answer_as(dfu, exchange, info_of(running))
}

/// As [`answer`], the running image's info `running`.
fn answer_as(dfu: &mut [u8], exchange: &Exchange, running: ImageInfo) -> Result<Reply, ExchangeError> {
    let body = match exchange.frame.command {
        Command::Version => running_info(true, running),
        Command::Begin { payload_len, .. } => ReplyBody::Begin { payload_len },
        Command::Erase { page } => {
            let start = usize::from(page) * PAGE;
            dfu[start..start + PAGE].fill(0xFF);
            ReplyBody::Erase { page }
        }
        Command::Write { offset, data } => {
            let (at, bytes) = (offset as usize, data.as_slice());
            dfu[at..at + bytes.len()].copy_from_slice(bytes);
            ReplyBody::Write {
                offset,
                len: data.len(),
                crc: ext::crc32(&dfu[at..at + bytes.len()]),
            }
        }
        Command::Check { offset, len } => ReplyBody::Check {
            offset,
            len,
            crc: ext::crc32(&dfu[offset as usize..(offset + len) as usize]),
        },
        Command::Finish { payload_len, .. } => ReplyBody::Finish { payload_len },
        Command::Reboot => ReplyBody::Reboot,
        Command::PostMortem { offset } => ReplyBody::PostMortem {
            len: 0,
            offset,
            data: [0; MAX_CHUNK],
        },
    };
    done(exchange, body)
}

/// Hand `image` to the courier as the sink does (a write whenever there is room) while a thruster holding `dfu`
/// answers every exchange, one per 20 ms, until the courier has nothing more to send; returns what it said and
/// the commands it sent.
fn carry(courier: &mut Courier, image: &[u8], dfu: &mut [u8], running: [u8; 4]) -> (Vec<Outgoing>, Vec<CommandKind>) {
    carry_as(courier, image, dfu, info_of(running))
}

/// As [`carry`], the running image's info `running`.
fn carry_as(
    courier: &mut Courier,
    image: &[u8],
    dfu: &mut [u8],
    running: ImageInfo,
) -> (Vec<Outgoing>, Vec<CommandKind>) {
    let (mut said, mut sent) = (Vec::new(), Vec::new());
    let mut offset = 0;
    for ms in (0..1_000_000).step_by(20) {
        while offset < image.len() && courier.has_room() && courier.transfer(0).is_some() {
            let end = (offset + MAX_WRITE).min(image.len());
            courier.write(offset as u32, &image[offset..end]).unwrap();
            offset = end;
            if offset == image.len() {
                courier.finish(true).unwrap();
            }
        }
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            if courier.transfer(0).is_some_and(|t| matches!(t.step, Step::Restart(_))) {
                continue;
            }
            break;
        };
        sent.push(exchange.frame.command.kind());
        let result = answer_as(dfu, &exchange, running);
        courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
    }
    (said, sent)
}

fn begun(image: &[u8]) -> Courier {
    let mut courier = Courier::new();
    courier
        .begin(0, 1, image.len() as u32, &header(image.len() as u32))
        .unwrap();
    courier
}

fn texts(said: &[Outgoing]) -> Vec<String> {
    said.iter()
        .filter_map(|o| match o {
            Outgoing::Text(_, text) => Some(text.as_str().to_owned()),
            _ => None,
        })
        .collect()
}

/// A SeaBotix image of `len` bytes at version 0.2.0 (at least [`SMALL`]).
fn payload(len: usize) -> Vec<u8> {
    image(info_of([0, 2, 0, 0]), len)
}

/// An image of `len` bytes whose image info is `info` (at least [`SMALL`]).
fn image(info: ImageInfo, len: usize) -> Vec<u8> {
    let mut payload: Vec<u8> = (0..len).map(|i| (i * 7 + 1) as u8).collect();
    payload[INFO_OFFSET..INFO_OFFSET + IMAGE_RECORD_LEN].copy_from_slice(&image_record(info, &DEV_PUBLIC_KEY));
    payload
}

#[test]
fn an_image_is_written_page_by_page_verified_then_applied() {
    let image = payload(5000);
    let mut courier = begun(&image);
    let mut dfu = vec![0u8; 8 * PAGE];
    let (said, sent) = carry(&mut courier, &image, &mut dfu, [0, 1, 0, 0]);
    assert_eq!(&dfu[..image.len()], image.as_slice());
    assert_eq!(texts(&said), ["thruster0.lbvu: 5000 B verified, 0 pages kept"]);
    let count = |kind| sent.iter().filter(|k| **k == kind).count();
    // 3 pages: each checked and erased; 32 + 32 + 14 chunks; the whole payload checked once more.
    assert_eq!(
        [
            CommandKind::Version,
            CommandKind::Begin,
            CommandKind::Erase,
            CommandKind::Write,
            CommandKind::Check
        ]
        .map(count),
        [1, 1, 3, 79, 4]
    );
    assert_eq!(courier.apply(0, GCS), Ok(Applied::Started));
    let (said, sent) = carry(&mut courier, &[], &mut dfu, [0, 2, 0, 0]);
    assert_eq!(sent, [CommandKind::Finish, CommandKind::Reboot, CommandKind::Version]);
    assert_eq!(
        texts(&said),
        [
            "thruster0.lbvu: marked, restarting into its update",
            "thruster0.lbvu: 0.2.0 confirmed"
        ]
    );
    assert!(said.contains(&Outgoing::CommandAck {
        command: MAV_CMD_LBV_APPLY_UPDATE,
        result: AckResult::Accepted,
        to: GCS
    }));
    assert!(courier.transfer(0).is_none());
}

#[test]
fn a_thruster_that_comes_back_on_its_old_image_fails_the_apply() {
    let image = payload(SMALL);
    let mut courier = begun(&image);
    let mut dfu = vec![0u8; 8 * PAGE];
    carry(&mut courier, &image, &mut dfu, [0, 1, 0, 0]);
    assert_eq!(courier.apply(0, GCS), Ok(Applied::Started));
    let (said, _) = carry(&mut courier, &[], &mut dfu, [0, 1, 0, 0]);
    assert_eq!(
        texts(&said),
        [
            "thruster0.lbvu: marked, restarting into its update",
            "thruster0.lbvu: still runs 0.1.0"
        ]
    );
    assert!(said.contains(&Outgoing::CommandAck {
        command: MAV_CMD_LBV_APPLY_UPDATE,
        result: AckResult::Failed,
        to: GCS
    }));
}

#[test]
fn pages_the_thruster_holds_are_kept() {
    let image = payload(3 * PAGE);
    let mut dfu = vec![0u8; 8 * PAGE];
    dfu[..2 * PAGE].copy_from_slice(&image[..2 * PAGE]);
    let mut courier = begun(&image);
    let (said, sent) = carry(&mut courier, &image, &mut dfu, [0, 1, 0, 0]);
    assert_eq!(
        sent.iter().filter(|k| **k == CommandKind::Erase).count(),
        1,
        "only the page it did not hold"
    );
    assert_eq!(texts(&said), ["thruster0.lbvu: 6144 B verified, 2 pages kept"]);
    assert_eq!(&dfu[..image.len()], image.as_slice());
}

#[test]
fn an_ids_only_controller_or_one_without_signatures_is_refused_before_anything_is_written() {
    let mut courier = courier_with(&payload(SMALL));
    let hello = courier.next(t(0), |_| true).unwrap();
    assert_eq!(hello.frame.command, Command::Version);
    let status_frame = Err(ExchangeError::Frame(FrameError::MessageType {
        expected: ext::EXT_REPLY_MT,
        actual: 0x53,
    }));
    let mut said = Vec::new();
    courier.on_result(t(0), &hello, status_frame, &mut |o| said.push(o));
    assert_eq!(texts(&said), ["thruster0.lbvu: the thruster does not take updates"]);
    assert!(courier.next(t(20), |_| true).is_none());
    assert_eq!(courier.write(SMALL as u32, &[0; 8]), Err(NotTaken));

    let mut courier = courier_with(&payload(SMALL));
    let hello = courier.next(t(0), |_| true).unwrap();
    let mut said = Vec::new();
    courier.on_result(t(0), &hello, done(&hello, version(false, [0; 4])), &mut |o| {
        said.push(o)
    });
    // A sentence too long for one text goes on in a second.
    assert_eq!(
        texts(&said),
        [
            "thruster0.lbvu: this thruster's firmware cannot",
            "thruster0.lbvu: check signatures: it takes no upda"
        ]
    );
    assert!(courier.transfer(0).is_none());
}

#[test]
fn a_failed_exchange_is_sent_again_with_its_sequence_number_until_the_thruster_is_silent_too_long() {
    let mut courier = courier_with(&payload(SMALL));
    let first = courier.next(t(0), |_| true).unwrap();
    let mut said = Vec::new();
    let mut ms = 0;
    while ms < SILENCE_LIMIT.as_millis() {
        let again = courier.next(t(ms), |_| true).unwrap();
        assert_eq!(again.frame, first.frame);
        courier.on_result(t(ms), &again, Err(ExchangeError::Bus), &mut |o| said.push(o));
        assert!(said.is_empty(), "given up after {ms} ms");
        ms += 20;
    }
    let last = courier.next(t(ms), |_| true).unwrap();
    courier.on_result(t(ms), &last, Err(ExchangeError::Busy), &mut |o| said.push(o));
    assert_eq!(texts(&said), ["thruster0.lbvu: the thruster stopped answering"]);
    assert!(courier.transfer(0).is_none());
}

#[test]
fn a_thruster_reset_mid_page_is_begun_again_and_the_page_written_again() {
    let image = payload(PAGE);
    let mut courier = courier_with(&image);
    let mut dfu = vec![0u8; 8 * PAGE];
    let mut said = Vec::new();
    let mut begins = 0;
    let mut reset = false;
    for ms in (0..200_000).step_by(20) {
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            break;
        };
        begins += usize::from(matches!(exchange.frame.command, Command::Begin { .. }));
        let result = match exchange.frame.command {
            // The third chunk finds the thruster reset: it has forgotten the update.
            Command::Write { offset: 128, .. } if !reset => {
                reset = true;
                refused(&exchange, Refusal::NotBegun)
            }
            _ => answer(&mut dfu, &exchange, [0, 1, 0, 0]),
        };
        courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
    }
    assert_eq!(begins, 2);
    assert_eq!(&dfu[..PAGE], image.as_slice());
    assert_eq!(texts(&said), ["thruster0.lbvu: 2048 B verified, 0 pages kept"]);
}

#[test]
fn a_read_back_that_differs_or_a_refusal_ends_the_transfer_with_its_reason() {
    let mut courier = courier_with(&payload(PAGE));
    let mut dfu = vec![0u8; 8 * PAGE];
    let mut said = Vec::new();
    for ms in (0..100_000).step_by(20) {
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            break;
        };
        let result = match exchange.frame.command {
            Command::Write { offset, data } => done(
                &exchange,
                ReplyBody::Write {
                    offset,
                    len: data.len(),
                    crc: 0xDEAD_BEEF,
                },
            ),
            _ => answer(&mut dfu, &exchange, [0, 1, 0, 0]),
        };
        courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
    }
    assert_eq!(texts(&said), ["thruster0.lbvu: the flash read back differs"]);
    assert_eq!(courier.apply(0, GCS), Err(NotTaken));

    let mut courier = courier_with(&payload(SMALL));
    let hello = courier.next(t(0), |_| true).unwrap();
    courier.on_result(t(0), &hello, done(&hello, version(true, [0; 4])), &mut |_| {});
    let begin = courier.next(t(20), |_| true).unwrap();
    let mut said = Vec::new();
    courier.on_result(t(20), &begin, refused(&begin, Refusal::WrongFamily), &mut |o| {
        said.push(o)
    });
    assert_eq!(texts(&said), ["thruster0.lbvu: the image is for another target"]);
}

#[test]
fn a_thruster_of_another_bus_is_not_served_and_a_stale_reply_is_not_taken() {
    let mut courier = courier_with(&payload(SMALL));
    assert!(courier.next(t(0), |slot| slot != 0).is_none());
    let hello = courier.next(t(0), |_| true).unwrap();
    let stale = Ok(Reply::Done {
        seq: hello.frame.seq.wrapping_sub(1),
        body: version(true, [0; 4]),
    });
    courier.on_result(t(0), &hello, stale, &mut |_| {});
    assert_eq!(courier.next(t(20), |_| true).map(|e| e.frame), Some(hello.frame));
}

/// A Version reply running `running`, on trial or not.
fn running(exchange: &Exchange, running: [u8; 4], on_trial: bool) -> Result<Reply, ExchangeError> {
    let mut body = version(true, running);
    if let ReplyBody::Version { on_trial: trial, .. } = &mut body {
        *trial = on_trial;
    }
    done(exchange, body)
}

/// A courier whose transfer has been applied and whose thruster has just been told to reboot, at `t(0)`.
fn rebooting() -> Courier {
    let image = payload(SMALL);
    let mut courier = begun(&image);
    let mut dfu = vec![0u8; 8 * PAGE];
    carry(&mut courier, &image, &mut dfu, [0, 1, 0, 0]);
    courier.apply(0, GCS).unwrap();
    for command in [CommandKind::Finish, CommandKind::Reboot] {
        let exchange = courier.next(t(0), |_| true).unwrap();
        assert_eq!(exchange.frame.command.kind(), command);
        let result = answer(&mut dfu, &exchange, [0, 1, 0, 0]);
        courier.on_result(t(0), &exchange, result, &mut |_| {});
    }
    courier
}

/// The thruster restarts on its Reboot before the master has read the reply whole (the reset tears the read): the
/// courier, still at Reboot, waits out the swap as for a restart, rather than ending after 3 s of silence.
#[test]
fn a_reboot_whose_reply_the_restart_tore_waits_for_the_swap() {
    let image = payload(SMALL);
    let mut courier = begun(&image);
    let mut dfu = vec![0u8; 8 * PAGE];
    carry(&mut courier, &image, &mut dfu, [0, 1, 0, 0]);
    courier.apply(0, GCS).unwrap();
    let finish = courier.next(t(0), |_| true).unwrap();
    let result = answer(&mut dfu, &finish, [0, 1, 0, 0]);
    courier.on_result(t(0), &finish, result, &mut |_| {});
    let mut said = Vec::new();
    for ms in (0..10_000).step_by(20) {
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            continue;
        };
        let result = match ms {
            // The reply to Reboot torn, then silence for 5 s while the bootloader swaps (more than the 3 s a
            // thruster may otherwise stay silent), then the new image on trial, then confirmed.
            ..5_000 => Err(ExchangeError::Bus),
            5_000..6_000 => match exchange.frame.command.kind() {
                CommandKind::Reboot => refused(&exchange, Refusal::OnTrial),
                _ => running(&exchange, [0, 2, 0, 0], true),
            },
            _ => running(&exchange, [0, 2, 0, 0], false),
        };
        courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
    }
    assert!(
        !texts(&said).iter().any(|t| t.contains("stopped answering")),
        "{:?}",
        texts(&said)
    );
    assert_eq!(
        said.last(),
        Some(&Outgoing::CommandAck {
            command: MAV_CMD_LBV_APPLY_UPDATE,
            result: AckResult::Accepted,
            to: GCS
        }),
        "{:?}",
        texts(&said)
    );
}

#[test]
fn the_apply_is_accepted_only_once_the_new_image_has_confirmed_itself() {
    let mut courier = rebooting();
    let mut said = Vec::new();
    // Silent while its bootloader swaps, then on trial for a while, then confirmed.
    let mut asked = Vec::new();
    for ms in (20..10_000).step_by(20) {
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            continue;
        };
        asked.push(ms);
        let result = match ms {
            ..3_000 => Err(ExchangeError::Bus),
            3_000..6_000 => running(&exchange, [0, 2, 0, 0], true),
            _ => running(&exchange, [0, 2, 0, 0], false),
        };
        courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
    }
    assert_eq!(
        texts(&said),
        [
            "thruster0.lbvu: runs 0.2.0, on trial",
            "thruster0.lbvu: 0.2.0 confirmed"
        ]
    );
    assert_eq!(
        said.last(),
        Some(&Outgoing::CommandAck {
            command: MAV_CMD_LBV_APPLY_UPDATE,
            result: AckResult::Accepted,
            to: GCS
        })
    );
    // Every cycle from 200 ms after the reboot until it answers; twice a second while it is on trial.
    let on_trial = asked.iter().filter(|ms| (3_000..6_000).contains(*ms)).count();
    assert_eq!((asked.first(), on_trial), (Some(&200), 6));
    assert!(courier.transfer(0).is_none());
}

#[test]
fn a_new_image_reset_before_it_confirms_is_reverted_and_the_apply_fails() {
    let mut courier = rebooting();
    let mut said = Vec::new();
    for ms in (200..20_000).step_by(20) {
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            continue;
        };
        let result = match ms {
            ..1_000 => running(&exchange, [0, 2, 0, 0], true),
            // Reset: silent while the bootloader swaps the old image back, then the old image answers.
            1_000..4_000 => Err(ExchangeError::Bus),
            _ => running(&exchange, [0, 1, 0, 0], false),
        };
        courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
    }
    assert_eq!(
        texts(&said),
        [
            "thruster0.lbvu: runs 0.2.0, on trial",
            "thruster0.lbvu: reverted to 0.1.0"
        ]
    );
    assert!(said.contains(&Outgoing::CommandAck {
        command: MAV_CMD_LBV_APPLY_UPDATE,
        result: AckResult::Failed,
        to: GCS
    }));
}

#[test]
fn a_new_image_kept_on_trial_past_the_confirm_limit_is_watched_and_its_confirmation_accepted() {
    // A thruster kept from confirming (driven, unwell) for 75 s, then confirmed: the apply's final answer is what it
    // did, not a FAILED at the limit.
    let mut courier = rebooting();
    let mut said = Vec::new();
    for ms in (200..80_000).step_by(20) {
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            continue;
        };
        let result = running(&exchange, [0, 2, 0, 0], ms < 75_000);
        courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
    }
    assert_eq!(
        texts(&said),
        [
            "thruster0.lbvu: runs 0.2.0, on trial",
            "thruster0.lbvu: 0.2.0 still on trial",
            "thruster0.lbvu: 0.2.0 still on trial",
            "thruster0.lbvu: 0.2.0 confirmed"
        ]
    );
    assert_eq!(acks(&said), [(MAV_CMD_LBV_APPLY_UPDATE, AckResult::Accepted)]);
    assert_eq!(courier.hold(), None, "confirmed: nothing holds the vehicle");

    // Kept on trial, then reset: the bootloader reverts it, and the apply fails saying so.
    let mut courier = rebooting();
    let mut said = Vec::new();
    for ms in (200..60_000).step_by(20) {
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            continue;
        };
        let result = match ms {
            ..45_000 => running(&exchange, [0, 2, 0, 0], true),
            45_000..48_000 => Err(ExchangeError::Bus),
            _ => running(&exchange, [0, 1, 0, 0], false),
        };
        courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
    }
    assert_eq!(texts(&said).last().unwrap(), "thruster0.lbvu: reverted to 0.1.0");
    assert_eq!(acks(&said), [(MAV_CMD_LBV_APPLY_UPDATE, AckResult::Failed)]);
}

/// The answer of a thruster whose running image is on trial until `confirmed_at` ms: `Begin` refused until then.
fn on_trial_until(dfu: &mut [u8], exchange: &Exchange, ms: u64, confirmed_at: u64) -> Result<Reply, ExchangeError> {
    match exchange.frame.command {
        Command::Begin { .. } if ms < confirmed_at => refused(exchange, Refusal::OnTrial),
        _ => answer(dfu, exchange, [0, 2, 0, 0]),
    }
}

#[test]
fn an_upload_to_a_thruster_on_trial_waits_for_it_to_confirm_or_gives_up() {
    let image = payload(SMALL);
    let mut courier = courier_with(&image);
    let mut dfu = vec![0u8; 8 * PAGE];
    let (mut said, mut begins) = (Vec::new(), Vec::new());
    for ms in (0..20_000).step_by(20) {
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            continue;
        };
        if matches!(exchange.frame.command, Command::Begin { .. }) {
            begins.push(ms);
        }
        let result = on_trial_until(&mut dfu, &exchange, ms, 3_000);
        courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
    }
    // Asked twice a second until it had confirmed itself, then written.
    assert_eq!(begins.len(), 7, "{begins:?}");
    assert!(begins.windows(2).all(|w| w[1] - w[0] >= 500), "{begins:?}");
    assert_eq!(texts(&said), ["thruster0.lbvu: 576 B verified, 0 pages kept"]);

    let mut courier = courier_with(&image);
    let mut said = Vec::new();
    for ms in (0..40_000).step_by(20) {
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            continue;
        };
        let result = on_trial_until(&mut dfu, &exchange, ms, u64::MAX);
        courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
    }
    assert_eq!(
        texts(&said),
        [
            "thruster0.lbvu: the running image is on trial and",
            "thruster0.lbvu: has not confirmed itself yet"
        ]
    );
    assert!(courier.transfer(0).is_none());
}

#[test]
fn a_finished_update_left_by_a_master_reset_is_started_and_the_new_upload_goes_on() {
    let image = payload(SMALL);
    let mut courier = courier_with(&image);
    let mut dfu = vec![0u8; 8 * PAGE];
    let mut said = Vec::new();
    let mut sent = Vec::new();
    let mut rebooted_at = None;
    for ms in (0..20_000).step_by(20) {
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            continue;
        };
        sent.push(exchange.frame.command.kind());
        let result = match (exchange.frame.command, rebooted_at) {
            // A finished update waits in it; after the reboot it runs that image on trial for 3 s.
            (Command::Begin { .. }, None) => refused(&exchange, Refusal::Finished),
            (Command::Reboot, _) => {
                rebooted_at = Some(ms);
                answer(&mut dfu, &exchange, [0, 1, 0, 0])
            }
            (_, Some(at)) => on_trial_until(&mut dfu, &exchange, ms, at + 3_000),
            _ => answer(&mut dfu, &exchange, [0, 1, 0, 0]),
        };
        courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
    }
    assert_eq!(
        sent[..4],
        [
            CommandKind::Version,
            CommandKind::Begin,
            CommandKind::Reboot,
            CommandKind::Version
        ]
    );
    assert_eq!(
        texts(&said),
        [
            "thruster0.lbvu: starting the update it holds",
            "thruster0.lbvu: 576 B verified, 0 pages kept"
        ]
    );
    assert_eq!(&dfu[..SMALL], image.as_slice());
}

/// The COMMAND_ACKs in `said`: command, result.
fn acks(said: &[Outgoing]) -> Vec<(u16, AckResult)> {
    said.iter()
        .filter_map(|o| match o {
            Outgoing::CommandAck { command, result, .. } => Some((*command, *result)),
            _ => None,
        })
        .collect()
}

#[test]
fn a_version_query_asks_version_tells_what_runs_and_sends_nothing_else() {
    const QUERY: u16 = MAV_CMD_LBV_QUERY_VERSION;
    let mut courier = Courier::new();
    courier.query(3, GCS).unwrap();
    // One at a time; an image begun meanwhile waits for its end, on every bus.
    assert_eq!(courier.query(2, GCS), Err("wait: another query is under way"));
    courier.begin(0, 1, 64, &header(64)).unwrap();
    assert!(courier.next(t(0), |slot| slot != 3).is_none(), "another bus's task");
    let ask = courier.next(t(0), |_| true).unwrap();
    assert_eq!((ask.slot, ask.frame.command), (3, Command::Version));
    let mut said = Vec::new();
    let mut on_trial = version(true, [0, 4, 2, 0]);
    if let ReplyBody::Version { on_trial: trial, .. } = &mut on_trial {
        *trial = true;
    }
    courier.on_result(t(5), &ask, done(&ask, on_trial), &mut |o| said.push(o));
    assert_eq!(texts(&said), ["thruster3.lbvu: runs 0.4.2, on trial"]);
    assert_eq!(acks(&said), [(QUERY, AckResult::Accepted)]);
    let hello = courier.next(t(20), |_| true).unwrap();
    assert_eq!(
        (hello.slot, hello.frame.command),
        (0, Command::Version),
        "the transfer goes on"
    );
    // Not while the transfer has an exchange to make.
    assert_eq!(courier.query(1, GCS), Err("wait: an update is under way"));

    // A thruster that cannot check signatures says so; an IDS-only one, and a silent one, fail the query.
    let mut courier = Courier::new();
    courier.query(0, GCS).unwrap();
    let ask = courier.next(t(0), |_| true).unwrap();
    let mut said = Vec::new();
    courier.on_result(t(0), &ask, done(&ask, version(false, [1, 0, 0, 0])), &mut |o| {
        said.push(o)
    });
    assert_eq!(texts(&said), ["thruster0.lbvu: runs 1.0.0, no updates"]);
    courier.query(0, GCS).unwrap();
    let ask = courier.next(t(0), |_| true).unwrap();
    let status_frame = Err(ExchangeError::Frame(FrameError::MessageType {
        expected: ext::EXT_REPLY_MT,
        actual: 0x53,
    }));
    let mut said = Vec::new();
    courier.on_result(t(0), &ask, status_frame, &mut |o| said.push(o));
    assert_eq!(texts(&said), ["thruster0.lbvu: the thruster does not take updates"]);
    assert_eq!(acks(&said), [(QUERY, AckResult::Failed)]);
    courier.query(0, GCS).unwrap();
    let mut said = Vec::new();
    for ms in [0, 1000, 2000, 3000] {
        let ask = courier.next(t(ms), |_| true).unwrap();
        courier.on_result(t(ms), &ask, Err(ExchangeError::Bus), &mut |o| said.push(o));
    }
    assert_eq!(texts(&said), ["thruster0.lbvu: the thruster stopped answering"]);
    assert_eq!(acks(&said), [(QUERY, AckResult::Failed)]);
    assert!(courier.transfer(0).is_none());
}

#[test]
fn a_version_query_rides_out_a_noisy_bus_and_stale_replies_short_of_the_silence_limit() {
    let mut courier = Courier::new();
    courier.query(1, GCS).unwrap();
    let mut said = Vec::new();
    // 2.9 s of a noisy bus: failed transfers, replies that do not decode, busy, and one for another sequence number.
    let noise = [
        Err(ExchangeError::Bus),
        Err(ExchangeError::Frame(FrameError::Crc { expected: 1, actual: 2 })),
        Err(ExchangeError::Busy),
    ];
    for (n, ms) in (0..2900).step_by(20).enumerate() {
        let ask = courier.next(t(ms), |_| true).unwrap();
        assert_eq!(ask.frame.command, Command::Version);
        let result = match n % 4 {
            3 => Ok(Reply::Done {
                seq: ask.frame.seq.wrapping_add(1),
                body: version(true, [9, 9, 9, 0]),
            }),
            k => noise[k],
        };
        courier.on_result(t(ms), &ask, result, &mut |o| said.push(o));
    }
    assert!(said.is_empty(), "{:?}", texts(&said));
    let ask = courier.next(t(2900), |_| true).unwrap();
    courier.on_result(t(2900), &ask, done(&ask, version(true, [0, 2, 0, 0])), &mut |o| {
        said.push(o)
    });
    assert_eq!(texts(&said), ["thruster1.lbvu: runs 0.2.0"]);
    assert_eq!(acks(&said), [(MAV_CMD_LBV_QUERY_VERSION, AckResult::Accepted)]);
}

/// A Version reply of a thruster back on `running` after its bootloader refused the image: verdict `code`.
fn back_refused(exchange: &Exchange, running: [u8; 4], code: u8) -> Result<Reply, ExchangeError> {
    let mut body = version(true, running);
    if let ReplyBody::Version { verdict, .. } = &mut body {
        *verdict = code;
    }
    done(exchange, body)
}

#[test]
fn a_thruster_whose_bootloader_refused_the_image_fails_the_apply_with_the_verdict() {
    for (code, said_as) in [
        (1, &["T1: refused by its bootloader: signature"][..]),
        // Too long for one text: the verdict is not cut short.
        (
            4,
            &[
                "T1: refused by its bootloader:",
                "T1: security counter below the vehicle's",
            ],
        ),
        (14, &["T1: refused by its bootloader (code 14)"]),
    ] {
        let mut courier = rebooting();
        let mut said = Vec::new();
        // Silent a moment (no swap: the bootloader refused, wrote its verdict and started the old image).
        for ms in (20..2_000).step_by(20) {
            let Some(exchange) = courier.next(t(ms), |_| true) else {
                continue;
            };
            let result = match ms {
                ..500 => Err(ExchangeError::Bus),
                _ => back_refused(&exchange, [0, 1, 0, 0], code),
            };
            courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
        }
        assert_eq!(texts(&said), said_as, "code {code}");
        assert_eq!(acks(&said), [(MAV_CMD_LBV_APPLY_UPDATE, AckResult::Failed)]);
        assert!(courier.transfer(0).is_none());
    }
    // Back on the old image with no verdict: as before, it still runs it.
    let mut courier = rebooting();
    let mut said = Vec::new();
    let exchange = courier.next(t(200), |_| true).unwrap();
    courier.on_result(t(200), &exchange, back_refused(&exchange, [0, 1, 0, 0], 0), &mut |o| {
        said.push(o)
    });
    assert_eq!(texts(&said), ["thruster0.lbvu: still runs 0.1.0"]);
}

/// Carry `payload` under a header of `header_version` to a thruster running `running`: what was said and sent.
fn carry_image(payload: &[u8], header_version: [u8; 4], running: ImageInfo) -> (Vec<String>, Vec<CommandKind>) {
    let mut courier = Courier::new();
    let len = payload.len() as u32;
    courier.begin(0, 1, len, &header_of(len, header_version)).unwrap();
    let mut dfu = vec![0u8; 8 * PAGE];
    let (said, sent) = carry_as(&mut courier, payload, &mut dfu, running);
    (texts(&said), sent)
}

#[test]
fn an_image_is_held_to_its_header_and_to_the_running_image_before_anything_is_written() {
    let running = info_of([0, 3, 0, 0]).with_security_counter(5);
    let nothing_written = |sent: &[CommandKind]| sent == [CommandKind::Version, CommandKind::Begin, CommandKind::Check];
    let newer = info_of([0, 4, 0, 0]).with_security_counter(5);
    // A relabelled header: its version is not the signed image's.
    let (said, sent) = carry_image(&image(newer, 3 * PAGE), [0, 5, 0, 0], running);
    assert_eq!(
        said,
        [
            "thruster0.lbvu: the header says version 0.5.0,",
            "thruster0.lbvu: the payload is version 0.4.0"
        ]
    );
    assert!(nothing_written(&sent), "{sent:?}");
    // An image info of format 1: no key for the update after it.
    let mut format_1 = image(newer, 3 * PAGE);
    format_1[INFO_OFFSET + 4] = 1;
    format_1[INFO_OFFSET + 12..INFO_OFFSET + 16].fill(0);
    let (said, sent) = carry_image(&format_1, [0, 4, 0, 0], running);
    assert_eq!(
        said,
        [
            "thruster0.lbvu: an image of info format 1 names no",
            "thruster0.lbvu: update key: nothing after it could"
        ]
    );
    assert!(nothing_written(&sent), "{sent:?}");
    // Older than what runs, not signed as a rollback.
    let older = info_of([0, 2, 0, 0]).with_security_counter(5);
    let (said, sent) = carry_image(&image(older, 3 * PAGE), [0, 2, 0, 0], running);
    assert_eq!(
        said,
        [
            "thruster0.lbvu: 0.2.0 is older than the 0.3.0 that",
            "thruster0.lbvu: runs (not a rollback)"
        ]
    );
    assert!(nothing_written(&sent), "{sent:?}");
    // A security counter below the running image's, even signed as a rollback.
    let below = info_of([0, 4, 0, 0]).with_security_counter(4);
    let (said, sent) = carry_image(&image(below.with_rollback(true), 3 * PAGE), [0, 4, 0, 0], running);
    assert_eq!(
        said,
        [
            "thruster0.lbvu: security counter 4 is below the",
            "thruster0.lbvu: vehicle's 5"
        ]
    );
    assert!(nothing_written(&sent), "{sent:?}");
    // The same image already on the thruster (a transfer resumed) is refused all the same.
    let mut courier = Courier::new();
    let payload = image(older, 3 * PAGE);
    courier
        .begin(
            0,
            1,
            payload.len() as u32,
            &header_of(payload.len() as u32, [0, 2, 0, 0]),
        )
        .unwrap();
    let mut dfu = vec![0u8; 8 * PAGE];
    dfu[..payload.len()].copy_from_slice(&payload);
    let (said, _) = carry_as(&mut courier, &payload, &mut dfu, running);
    assert_eq!(texts(&said)[0], "thruster0.lbvu: 0.2.0 is older than the 0.3.0 that");
    // Signed as a rollback, an older image goes on; so do a newer one and the same one again.
    for (info, version) in [
        (older.with_rollback(true), [0, 2, 0, 0]),
        (newer, [0, 4, 0, 0]),
        (running, [0, 3, 0, 0]),
    ] {
        let (said, sent) = carry_image(&image(info, 3 * PAGE), version, running);
        assert_eq!(said, ["thruster0.lbvu: 6144 B verified, 0 pages kept"], "{info:?}");
        assert_eq!(sent.iter().filter(|k| **k == CommandKind::Erase).count(), 3);
    }
}

#[test]
fn a_version_query_says_what_the_thruster_holds_and_takes() {
    let mut courier = Courier::new();
    courier.query(0, GCS).unwrap();
    let ask = courier.next(t(0), |_| true).unwrap();
    let mut body = version(true, [0, 2, 0, 0]);
    if let ReplyBody::Version { marked, dev_key, .. } = &mut body {
        (*marked, *dev_key) = (true, true);
    }
    let mut said = Vec::new();
    courier.on_result(t(0), &ask, done(&ask, body), &mut |o| said.push(o));
    assert_eq!(texts(&said), ["thruster0.lbvu: runs 0.2.0, update marked, dev key"]);
}

/// A Version reply of a thruster running 0.2.0, on trial and marked as said.
fn standing(exchange: &Exchange, on_trial: bool, marked: bool) -> Result<Reply, ExchangeError> {
    let mut body = version(true, [0, 2, 0, 0]);
    if let ReplyBody::Version {
        on_trial: trial,
        marked: mark,
        ..
    } = &mut body
    {
        (*trial, *mark) = (on_trial, marked);
    }
    done(exchange, body)
}

#[test]
fn a_thruster_that_answers_again_is_asked_what_it_runs_and_holds_arming_until_it_has_confirmed() {
    let mut courier = Courier::new();
    assert_eq!(courier.hold(), None, "nothing answers yet");
    // T3 answers its polls (the master's start, or back from being offline): it may have come up on trial.
    courier.seen(2, true);
    assert_eq!(courier.hold(), Some(UpdateHold::Unasked(2)));
    assert!(courier.next(t(0), |slot| slot != 2).is_none(), "another bus's task");
    let ask = courier.next(t(0), |_| true).unwrap();
    assert_eq!((ask.slot, ask.frame.command), (2, Command::Version));
    // The same look asked again (the reply lost): the same frame; a stale reply is not taken.
    courier.on_result(t(0), &ask, Err(ExchangeError::Bus), &mut |_| {
        panic!("a look says nothing")
    });
    assert_eq!(courier.hold(), Some(UpdateHold::Unasked(2)));
    let again = courier.next(t(20), |_| true).unwrap();
    assert_eq!(again.frame.command, Command::Version);
    let stale = Ok(Reply::Done {
        seq: again.frame.seq.wrapping_sub(1),
        body: version(true, [0; 4]),
    });
    courier.on_result(t(20), &again, stale, &mut |_| panic!("a look says nothing"));
    assert_eq!(courier.hold(), Some(UpdateHold::Unasked(2)));
    // On trial: held, and asked again twice a second, not at every cycle.
    let ask = courier.next(t(40), |_| true).unwrap();
    courier.on_result(t(40), &ask, standing(&ask, true, false), &mut |_| {
        panic!("a look says nothing")
    });
    assert_eq!(courier.hold(), Some(UpdateHold::OnTrial(2)));
    let asked: Vec<u64> = (60..2_000)
        .step_by(20)
        .filter(|ms| {
            let Some(ask) = courier.next(t(*ms), |_| true) else {
                return false;
            };
            courier.on_result(t(*ms), &ask, standing(&ask, true, false), &mut |_| {});
            true
        })
        .collect();
    assert_eq!(asked, [540, 1040, 1540]);
    // Offline meanwhile (reset, say): what it said holds until it answers again, and is asked again then.
    courier.seen(2, false);
    assert_eq!(courier.hold(), Some(UpdateHold::OnTrial(2)));
    courier.seen(2, true);
    assert_eq!(courier.hold(), Some(UpdateHold::Unasked(2)));
    // Confirmed: nothing holds, and nothing is asked.
    let ask = courier.next(t(2_000), |_| true).unwrap();
    courier.on_result(t(2_000), &ask, standing(&ask, false, false), &mut |_| {});
    assert_eq!(courier.hold(), None);
    assert!(
        (2_020..10_000)
            .step_by(20)
            .all(|ms| courier.next(t(ms), |_| true).is_none())
    );
    // One that holds a mark (the master was reset between Finish and Reboot) holds until it restarts.
    courier.seen(5, true);
    let ask = courier.next(t(10_000), |_| true).unwrap();
    courier.on_result(t(10_000), &ask, standing(&ask, false, true), &mut |_| {});
    assert_eq!(courier.hold(), Some(UpdateHold::Marked(5)));
    assert!(
        courier.next(t(10_020), |_| true).is_none(),
        "marked: asked again only once it answers again"
    );
    // One never asked that stops answering (missing) is not waited for; an IDS-only one takes no update.
    courier.seen(5, true);
    courier.seen(5, false);
    courier.seen(6, true);
    let ask = courier.next(t(11_000), |_| true).unwrap();
    let status_frame = Err(ExchangeError::Frame(FrameError::MessageType {
        expected: ext::EXT_REPLY_MT,
        actual: 0x53,
    }));
    courier.on_result(t(11_000), &ask, status_frame, &mut |_| panic!("a look says nothing"));
    assert_eq!(courier.hold(), None);
}

#[test]
fn a_thruster_is_looked_at_only_when_no_transfer_has_an_exchange_to_make() {
    let image = payload(3 * PAGE);
    let mut courier = begun(&image);
    courier.seen(1, true);
    // The transfer's Version and Begin come first.
    for (ms, command) in [(0, CommandKind::Version), (20, CommandKind::Begin)] {
        let exchange = courier.next(t(ms), |_| true).unwrap();
        assert_eq!((exchange.slot, exchange.frame.command.kind()), (0, command));
        let result = answer(&mut [0; 8 * PAGE], &exchange, [0, 1, 0, 0]);
        courier.on_result(t(ms), &exchange, result, &mut |_| {});
    }
    // Waiting for its first page: T2 is asked, and the page that comes meanwhile waits for the answer.
    let ask = courier.next(t(40), |_| true).unwrap();
    assert_eq!((ask.slot, ask.frame.command), (1, Command::Version));
    for (n, block) in image[..PAGE + MAX_WRITE].chunks(MAX_WRITE).enumerate() {
        courier.write((n * MAX_WRITE) as u32, block).unwrap();
    }
    assert!(courier.next(t(50), |slot| slot == 0).is_none(), "T1's bus waits");
    courier.on_result(t(60), &ask, standing(&ask, false, false), &mut |_| {});
    let check = courier.next(t(60), |_| true).unwrap();
    assert_eq!((check.slot, check.frame.command.kind()), (0, CommandKind::Check));
    // With a page to write, nobody else is asked.
    courier.seen(1, true);
    courier.on_result(
        t(60),
        &check,
        answer(&mut [0; 8 * PAGE], &check, [0, 1, 0, 0]),
        &mut |_| {},
    );
    assert_eq!(courier.next(t(80), |_| true).unwrap().slot, 0);
}

#[test]
fn a_version_query_is_answered_while_an_image_written_whole_waits_for_its_apply() {
    let image = payload(SMALL);
    let mut courier = begun(&image);
    let mut dfu = vec![0u8; 8 * PAGE];
    carry(&mut courier, &image, &mut dfu, [0, 1, 0, 0]);
    assert!(courier.transfer(0).is_some_and(|t| t.step == Step::Written));
    // Of the thruster that holds it, and of another.
    for slot in [0, 3] {
        courier.query(slot, GCS).unwrap();
        let ask = courier.next(t(0), |_| true).unwrap();
        assert_eq!((ask.slot, ask.frame.command), (slot, Command::Version));
        let mut said = Vec::new();
        courier.on_result(t(0), &ask, running(&ask, [0, 1, 0, 0], false), &mut |o| said.push(o));
        assert_eq!(texts(&said), [format!("thruster{slot}.lbvu: runs 0.1.0")]);
        assert_eq!(acks(&said), [(MAV_CMD_LBV_QUERY_VERSION, AckResult::Accepted)]);
    }
    // An apply taken while a query runs waits for its end, then goes on.
    courier.query(0, GCS).unwrap();
    assert_eq!(courier.apply(0, GCS), Ok(Applied::Started));
    let ask = courier.next(t(0), |_| true).unwrap();
    assert_eq!(ask.frame.command, Command::Version);
    courier.on_result(t(0), &ask, running(&ask, [0, 1, 0, 0], false), &mut |_| {});
    let (said, sent) = carry(&mut courier, &[], &mut dfu, [0, 2, 0, 0]);
    assert_eq!(sent[..2], [CommandKind::Finish, CommandKind::Reboot]);
    assert_eq!(texts(&said).last().unwrap(), "thruster0.lbvu: 0.2.0 confirmed");
}

#[test]
fn an_apply_holds_the_vehicle_from_the_command_to_the_confirmation_or_until_the_thruster_is_asked_again() {
    let image = payload(SMALL);
    let mut courier = begun(&image);
    let mut dfu = vec![0u8; 8 * PAGE];
    carry(&mut courier, &image, &mut dfu, [0, 1, 0, 0]);
    assert_eq!(courier.hold(), None, "written, not applied");
    assert_eq!(courier.applier(0), None);
    assert_eq!(courier.apply(0, GCS), Ok(Applied::Started));
    // The same apply again while it runs: the one under way, for its applier; the transfer stays where it is.
    assert_eq!(courier.applier(0), Some(GCS));
    assert_eq!(courier.applier(1), None);
    assert_eq!(courier.hold(), Some(UpdateHold::Applying(0)));
    // At every step of the apply, until the new image has confirmed.
    let mut holds = Vec::new();
    let mut said = Vec::new();
    for ms in (0..6_000).step_by(20) {
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            holds.push(courier.hold());
            continue;
        };
        let result = match exchange.frame.command {
            Command::Version if ms < 3_000 => running(&exchange, [0, 2, 0, 0], true),
            Command::Version => running(&exchange, [0, 2, 0, 0], false),
            _ => answer(&mut dfu, &exchange, [0, 1, 0, 0]),
        };
        holds.push(courier.hold());
        courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
        if courier.transfer(0).is_some() {
            assert_eq!(courier.hold(), Some(UpdateHold::Applying(0)), "at {ms} ms");
        }
    }
    assert!(holds.contains(&Some(UpdateHold::Applying(0))));
    assert_eq!(acks(&said), [(MAV_CMD_LBV_APPLY_UPDATE, AckResult::Accepted)]);
    assert_eq!(courier.hold(), None);

    // An apply that ends without an answer (the thruster silent since its reboot): it may be anywhere in its swap,
    // so it is asked again before the vehicle arms.
    let mut courier = rebooting();
    for ms in (200..20_000).step_by(20) {
        if let Some(exchange) = courier.next(t(ms), |slot| slot != 0) {
            panic!("only T1 is on the bus: {exchange:?}");
        }
        if let Some(exchange) = courier.next(t(ms), |_| true) {
            courier.on_result(t(ms), &exchange, Err(ExchangeError::Bus), &mut |_| {});
        }
        if courier.transfer(0).is_none() {
            break;
        }
    }
    assert!(courier.transfer(0).is_none());
    assert_eq!(courier.hold(), Some(UpdateHold::Unasked(0)));
}

#[test]
fn the_ground_stations_query_takes_the_place_of_a_look_under_way_whose_late_answer_is_not_taken() {
    let mut courier = Courier::new();
    courier.seen(1, true);
    let look = courier.next(t(0), |_| true).unwrap();
    assert_eq!(look.slot, 1);
    courier.query(4, GCS).unwrap();
    // A second query meanwhile waits for this one.
    assert_eq!(courier.query(4, GCS), Err("wait: another query is under way"));
    // The look's answer comes late: it is not the query's, and T2 is asked again later.
    let mut said = Vec::new();
    courier.on_result(t(5), &look, standing(&look, true, false), &mut |o| said.push(o));
    assert!(said.is_empty());
    assert_eq!(courier.hold(), Some(UpdateHold::Unasked(1)));
    let ask = courier.next(t(20), |_| true).unwrap();
    assert_eq!(ask.slot, 4);
    courier.on_result(t(20), &ask, running(&ask, [0, 2, 0, 0], false), &mut |o| said.push(o));
    assert_eq!(texts(&said), ["thruster4.lbvu: runs 0.2.0"]);
    let look = courier.next(t(40), |_| true).unwrap();
    assert_eq!(look.slot, 1);
    courier.on_result(t(40), &look, standing(&look, false, false), &mut |_| {});
    assert_eq!(courier.hold(), None);
}

/// Hand `image` to the courier as the sink does while the thrusters of `slots` (each holding its `dfu`, running
/// 0.1.0 until it restarts into the update, `silent` ones answering nothing) answer every exchange, one per 20 ms,
/// applying the image to all of them once each has it written; returns what was said and the slots exchanged with,
/// in order.
fn carry_family(courier: &mut Courier, image: &[u8], slots: &mut [(u8, Vec<u8>, bool)]) -> (Vec<Outgoing>, Vec<u8>) {
    let (said, exchanges) = carry_family_with(courier, image, slots, 1, &mut |_, _| false);
    (said, exchanges.iter().map(|exchange| exchange.slot).collect())
}

/// As [`carry_family`], each exchange shared by up to `most` thrusters at the same step (each thruster's reply then
/// read alone; `misses` says which thruster missed which shared write: it answers what it held before); returns
/// what was said and the exchanges.
fn carry_family_with(
    courier: &mut Courier,
    image: &[u8],
    slots: &mut [(u8, Vec<u8>, bool)],
    most: u32,
    misses: &mut dyn FnMut(u8, &Exchange) -> bool,
) -> (Vec<Outgoing>, Vec<Exchange>) {
    let (mut said, mut exchanges) = (Vec::new(), Vec::new());
    let mask = slots.iter().fold(0, |mask, (slot, ..)| mask | 1 << slot);
    let (mut offset, mut applied) = (0, false);
    for ms in (0..200_000).step_by(20) {
        while offset < image.len() && courier.has_room() {
            let end = (offset + MAX_WRITE).min(image.len());
            if courier.write(offset as u32, &image[offset..end]).is_err() {
                break;
            }
            offset = end;
            if offset == image.len() {
                courier.finish(true).unwrap();
            }
        }
        if !applied && courier.apply_to(mask, GCS) == Ok(Applied::Started) {
            applied = true;
        }
        let Some(exchange) = courier.next_cast(t(ms), |_| true, |_| true, most) else {
            if courier.image.is_none() {
                break;
            }
            continue;
        };
        exchanges.push(exchange);
        for slot in exchange.slots() {
            let (_, dfu, silent) = slots.iter_mut().find(|(s, ..)| *s == slot).unwrap();
            let result = if *silent {
                Err(ExchangeError::Bus)
            } else if exchange.with != 0 && misses(slot, &exchange) {
                // Its last reply was read: it answers with its status frame.
                Err(ExchangeError::Frame(FrameError::MessageType {
                    expected: 0x60,
                    actual: 0x53,
                }))
            } else {
                let running = if applied { [0, 2, 0, 0] } else { [0, 1, 0, 0] };
                answer(dfu, &exchange, running)
            };
            courier.on_result(t(ms), exchange.sent_to(slot), result, &mut |o| said.push(o));
        }
    }
    (said, exchanges)
}

/// A courier with a SeaBotix family's `image` begun for the slots that are bits of `slots`.
fn family_courier(slots: u8, image: &[u8]) -> Courier {
    let mut courier = Courier::new();
    let len = image.len() as u32;
    courier
        .begin_to(slots, File::Family(Family::SeaBotix), 1, len, &header(len))
        .unwrap();
    courier
}

#[test]
fn a_family_file_goes_to_each_of_its_thrusters_page_by_page_in_turn_and_one_apply_applies_it_to_all() {
    let image = payload(5000);
    let mut courier = family_courier(0b1_0101, &image);
    let mut slots: Vec<(u8, Vec<u8>, bool)> = [0, 2, 4].map(|slot| (slot, vec![0u8; 8 * PAGE], false)).into();
    let (said, order) = carry_family(&mut courier, &image, &mut slots);
    for (slot, dfu, _) in &slots {
        assert_eq!(&dfu[..image.len()], image.as_slice(), "T{}", slot + 1);
    }
    // In turn: no thruster gets two exchanges in a row while the others have one to make.
    let runs = order.windows(2).filter(|pair| pair[0] == pair[1]).count();
    assert!(runs < order.len() / 10, "{runs} repeats in {order:?}");
    let texts = texts(&said);
    for who in ["T1", "T3", "T5"] {
        assert!(
            texts.contains(&format!("{who}: 5000 B verified, 0 pages kept")),
            "{texts:?}"
        );
        assert!(texts.contains(&format!("{who}: 0.2.0 confirmed")), "{texts:?}");
    }
    // One final answer, once the last has confirmed; before it, the progress at most once a second.
    assert_eq!(acks(&said), [(MAV_CMD_LBV_APPLY_UPDATE, AckResult::Accepted)]);
    let progress: Vec<u8> = said
        .iter()
        .filter_map(|o| match o {
            Outgoing::Progress { command, progress, to } => {
                assert_eq!((*command, *to), (MAV_CMD_LBV_APPLY_UPDATE, GCS));
                Some(*progress)
            }
            _ => None,
        })
        .collect();
    assert!(
        progress.windows(2).all(|pair| pair[0] <= pair[1]) && progress.last() < Some(&100),
        "{progress:?}"
    );
    let told: Vec<&String> = texts.iter().filter(|text| text.contains(" done, T")).collect();
    assert_eq!(told.len(), progress.len());
    assert_eq!(
        told.first().map(|t| t.as_str()),
        Some("thrusters-seabotix.lbvu: 0 of 3 done, T1 10 %")
    );
    assert!(courier.image.is_none() && courier.hold().is_none());
}

#[test]
fn a_thruster_of_the_family_that_stops_answering_is_left_behind_and_the_apply_fails_naming_it() {
    let image = payload(5000);
    let mut courier = family_courier(0b101, &image);
    // T3 is silent: the buffer waits for it up to the silence limit, then moves on without it.
    let mut slots = vec![(0, vec![0u8; 8 * PAGE], false), (2, vec![0u8; 8 * PAGE], true)];
    let (said, _) = carry_family(&mut courier, &image, &mut slots);
    assert_eq!(&slots[0].1[..image.len()], image.as_slice());
    let texts = texts(&said);
    assert!(
        texts.contains(&"T3: the thruster stopped answering".to_owned()),
        "{texts:?}"
    );
    assert!(texts.contains(&"T1: 0.2.0 confirmed".to_owned()), "{texts:?}");
    assert_eq!(texts.last().unwrap(), "thrusters-seabotix.lbvu: failed: T3");
    assert_eq!(acks(&said), [(MAV_CMD_LBV_APPLY_UPDATE, AckResult::Failed)]);
    assert!(courier.image.is_none());
    // T3 answers its polls again, on its old image: the master's look tells the operator what to do, once.
    let mut said = Vec::new();
    for _ in 0..2 {
        courier.seen(2, true);
        let look = courier.next(t(300_000), |_| true).unwrap();
        assert_eq!((look.slot, look.frame.command), (2, Command::Version));
        courier.on_result(t(300_000), &look, running(&look, [0, 1, 0, 0], false), &mut |o| {
            said.push(o)
        });
    }
    assert_eq!(
        super::tests::texts(&said),
        ["T3: runs 0.1.0, put thrusters-seabotix.lbvu again"]
    );
}

#[test]
fn a_family_image_is_dropped_once_every_thruster_has_ended_and_the_upload_is_refused() {
    let image = payload(5000);
    let mut courier = family_courier(0b11, &image);
    let mut said = Vec::new();
    for ms in (0..10_000).step_by(20) {
        if let Some(exchange) = courier.next(t(ms), |_| true) {
            courier.on_result(t(ms), &exchange, Err(ExchangeError::Bus), &mut |o| said.push(o));
        }
    }
    assert_eq!(
        texts(&said),
        [
            "T1: the thruster stopped answering",
            "T2: the thruster stopped answering"
        ]
    );
    assert!(courier.image.is_none());
    assert_eq!(courier.write(0, &image[..MAX_WRITE]), Err(NotTaken));
}

/// Carry a SeaBotix family's `image` to the thrusters of `slots`, each `(slot, running)` running `running` (its
/// image info) until it restarts into the update, one exchange per 20 ms, each thruster by its own write; apply it
/// once every one has it; returns what was said, the apply's answer and the slots written to.
fn carry_to_runners(image: &[u8], slots: &[(u8, ImageInfo)]) -> (Vec<Outgoing>, Option<Applied>, u8) {
    let mask = slots.iter().fold(0, |mask, (slot, _)| mask | bit(*slot));
    let mut courier = family_courier(mask, image);
    let mut dfus = vec![vec![0u8; 8 * PAGE]; MAX_THRUSTERS];
    let (mut said, mut applied, mut written, mut offset) = (Vec::new(), None, 0, 0);
    for ms in (0..100_000).step_by(20) {
        while offset < image.len() && courier.has_room() {
            let end = (offset + MAX_WRITE).min(image.len());
            courier.write(offset as u32, &image[offset..end]).unwrap();
            offset = end;
            if offset == image.len() {
                courier.finish(true).unwrap();
            }
        }
        if applied.is_none() && offset == image.len() {
            applied = courier.apply_to(mask, GCS).ok().filter(|a| *a != Applied::Pending);
        }
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            if courier.image.is_none() {
                break;
            }
            continue;
        };
        if exchange.frame.command.kind() == CommandKind::Write {
            written |= bit(exchange.slot);
        }
        let running = match applied {
            Some(Applied::Started) => info_of([0, 2, 0, 0]),
            _ => slots.iter().find(|(slot, _)| *slot == exchange.slot).unwrap().1,
        };
        let result = answer_as(&mut dfus[usize::from(exchange.slot)], &exchange, running);
        courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
    }
    assert!(courier.image.is_none(), "the image is done with");
    (said, applied, written)
}

#[test]
fn a_family_file_is_written_only_to_the_thrusters_that_do_not_run_it_yet() {
    let image = payload(5000);
    let (new, old) = (info_of([0, 2, 0, 0]), info_of([0, 1, 0, 0]));
    // T3 was off during the family's update: the file put again goes to it alone, and the apply restarts it alone.
    let (said, applied, written) = carry_to_runners(&image, &[(0, new), (2, old), (4, new)]);
    assert_eq!((applied, written), (Some(Applied::Started), bit(2)));
    let told = texts(&said);
    for expected in [
        "T1: runs 0.2.0 already",
        "T5: runs 0.2.0 already",
        "T3: 0.2.0 confirmed",
    ] {
        assert!(told.contains(&expected.to_owned()), "{told:?}");
    }
    assert!(
        !told
            .iter()
            .any(|t| t.starts_with("T1: marked") || t.starts_with("T5: marked")),
        "{told:?}"
    );
    assert_eq!(acks(&said), [(MAV_CMD_LBV_APPLY_UPDATE, AckResult::Accepted)]);

    // Every thruster runs it: nothing is written or applied, and the apply says so at once.
    let (said, applied, written) = carry_to_runners(&image, &[(0, new), (1, new)]);
    assert_eq!((applied, written), (Some(Applied::Runs), 0));
    assert_eq!(texts(&said), ["T1: runs 0.2.0 already", "T2: runs 0.2.0 already"]);
    assert!(acks(&said).is_empty(), "the server answers the apply");

    // Another image info (here the flag of an image signed as a rollback) is another image: written.
    let rolled_back = ImageInfo { rollback: true, ..new };
    let (_, applied, written) = carry_to_runners(&image, &[(0, rolled_back)]);
    assert_eq!((applied, written), (Some(Applied::Started), bit(0)));
}

#[test]
fn a_slots_own_file_is_written_even_to_a_thruster_that_runs_it() {
    let image = payload(SMALL);
    let mut courier = begun(&image);
    let mut dfu = vec![0u8; 8 * PAGE];
    let (said, sent) = carry(&mut courier, &image, &mut dfu, [0, 2, 0, 0]);
    assert!(sent.contains(&CommandKind::Write), "{sent:?}");
    assert_eq!(
        texts(&said),
        [format!("thruster0.lbvu: {SMALL} B verified, 0 pages kept")]
    );
    assert_eq!(courier.apply(0, GCS), Ok(Applied::Started));
}

#[test]
fn a_family_apply_sent_again_or_a_new_image_while_it_runs_starts_nothing() {
    let image = payload(SMALL);
    let mut courier = family_courier(0b11, &image);
    let mut dfus = [vec![0u8; 8 * PAGE], vec![0u8; 8 * PAGE]];
    for (offset, block) in (0..).step_by(MAX_WRITE).zip(image.chunks(MAX_WRITE)) {
        courier.write(offset, block).unwrap();
    }
    courier.finish(true).unwrap();
    for ms in (0..10_000).step_by(20) {
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            break;
        };
        let result = answer(&mut dfus[usize::from(exchange.slot)], &exchange, [0, 1, 0, 0]);
        courier.on_result(t(ms), &exchange, result, &mut |_| {});
    }
    assert_eq!(courier.apply_to(0b11, GCS), Ok(Applied::Started));
    // The same apply again: the one under way, whose applier each thruster names (the server answers IN_PROGRESS).
    assert_eq!(courier.apply_to(0b11, GCS), Err(NotTaken));
    assert_eq!([courier.applier(0), courier.applier(1)], [Some(GCS), Some(GCS)]);
    // A new image, for the family or one of its slots, waits for the apply's end.
    let len = image.len() as u32;
    assert_eq!(
        courier.begin_to(0b11, File::Family(Family::SeaBotix), 1, len, &header(len)),
        Err(NotTaken)
    );
    assert_eq!(courier.begin(1, 1, len, &header(len)), Err(NotTaken));
    assert_eq!(courier.hold(), Some(UpdateHold::Applying(0)));
}

#[test]
fn a_family_takes_each_page_check_erase_and_chunk_in_one_write_and_each_thruster_answers_for_itself() {
    let image = payload(5000);
    let mut courier = family_courier(0b1_0101, &image);
    let mut slots: Vec<(u8, Vec<u8>, bool)> = [0, 2, 4].map(|slot| (slot, vec![0u8; 8 * PAGE], false)).into();
    let (said, exchanges) = carry_family_with(&mut courier, &image, &mut slots, 3, &mut |_, _| false);
    for (slot, dfu, _) in &slots {
        assert_eq!(&dfu[..image.len()], image.as_slice(), "T{}", slot + 1);
    }
    let kinds = |with: bool| -> Vec<CommandKind> {
        exchanges
            .iter()
            .filter(|exchange| (exchange.with != 0) == with)
            .map(|exchange| exchange.frame.command.kind())
            .collect()
    };
    // Every chunk once for the three: 5000 B in 64-byte chunks; each page's check and erase, the verify.
    let shared = kinds(true);
    let count = |kinds: &[CommandKind], kind| kinds.iter().filter(|k| **k == kind).count();
    // Two whole pages and the last's 904 B.
    assert_eq!(count(&shared, CommandKind::Write), 2 * 32 + 904usize.div_ceil(64));
    assert_eq!(count(&shared, CommandKind::Erase), 3);
    assert_eq!(count(&shared, CommandKind::Check), 3 + 1);
    assert_eq!(count(&shared, CommandKind::Begin), 1);
    assert!(exchanges.iter().filter(|e| e.with != 0).all(|e| e.slots().count() == 3));
    // What is each thruster's own stays its own: what it runs, and the apply.
    let alone = kinds(false);
    assert!(
        alone
            .iter()
            .all(|kind| matches!(kind, CommandKind::Version | CommandKind::Finish | CommandKind::Reboot))
    );
    assert_eq!(acks(&said), [(MAV_CMD_LBV_APPLY_UPDATE, AckResult::Accepted)]);
}

#[test]
fn a_thruster_that_missed_a_shared_write_is_caught_by_its_own_reply_and_sent_the_chunk_alone() {
    let image = payload(5000);
    let mut courier = family_courier(0b111, &image);
    let mut slots: Vec<(u8, Vec<u8>, bool)> = [0, 1, 2].map(|slot| (slot, vec![0u8; 8 * PAGE], false)).into();
    // T2 misses the fifth chunk written to all three (its NACK hidden behind the others' ACK).
    let fifth = |exchange: &Exchange| matches!(exchange.frame.command, Command::Write { offset: 256, .. });
    let (said, exchanges) = carry_family_with(&mut courier, &image, &mut slots, 3, &mut |slot, exchange| {
        slot == 1 && fifth(exchange)
    });
    // Sent to T2 alone, then T2 joins the others again at the next page.
    let again = exchanges.iter().position(|e| e.with == 0 && e.slot == 1 && fifth(e));
    assert!(again.is_some());
    for (slot, dfu, _) in &slots {
        assert_eq!(&dfu[..image.len()], image.as_slice(), "T{}", slot + 1);
    }
    let rejoined = exchanges[again.unwrap()..]
        .iter()
        .any(|e| e.slots().count() == 3 && matches!(e.frame.command, Command::Erase { .. }));
    assert!(rejoined);
    assert_eq!(acks(&said), [(MAV_CMD_LBV_APPLY_UPDATE, AckResult::Accepted)]);
}

#[test]
fn a_shared_write_reaches_no_more_thrusters_than_the_bus_may_have_enabled_at_once() {
    let image = payload(5000);
    let mut courier = family_courier(0b1_1111, &image);
    let mut slots: Vec<(u8, Vec<u8>, bool)> = (0..5).map(|slot| (slot, vec![0u8; 8 * PAGE], false)).collect();
    let (said, exchanges) = carry_family_with(&mut courier, &image, &mut slots, 3, &mut |_, _| false);
    let most = exchanges.iter().map(|e| e.slots().count()).max();
    assert_eq!(most, Some(3));
    for (slot, dfu, _) in &slots {
        assert_eq!(&dfu[..image.len()], image.as_slice(), "T{}", slot + 1);
    }
    assert_eq!(acks(&said), [(MAV_CMD_LBV_APPLY_UPDATE, AckResult::Accepted)]);
}

#[test]
fn what_each_thruster_runs_is_kept_for_versions_txt() {
    let running = |courier: &Courier, slot: u8| {
        let board = courier.running(slot);
        (board.version, board.state)
    };
    let mut courier = Courier::new();
    assert_eq!(
        running(&courier, 0),
        (None, ImageState::Offline),
        "not in the table, or never heard"
    );
    // At the master's start: not asked yet, whether it answers its first poll or not yet.
    courier.expect(2);
    assert_eq!(running(&courier, 1), (None, ImageState::Unasked));
    courier.seen(1, true);
    let ask = courier.next(t(0), |slot| slot == 1).unwrap();
    courier.on_result(t(0), &ask, standing(&ask, true, false), &mut |_| {});
    assert_eq!(running(&courier, 1), (Some([0, 2, 0, 0]), ImageState::OnTrial));
    let ask = courier.next(t(1_000), |slot| slot == 1).unwrap();
    courier.on_result(t(1_000), &ask, standing(&ask, false, true), &mut |_| {});
    assert_eq!(running(&courier, 1), (Some([0, 2, 0, 0]), ImageState::Marked));
    // Away: offline, what it said last kept; back: not asked yet since; asked: what it runs now.
    courier.seen(1, false);
    assert_eq!(running(&courier, 1), (Some([0, 2, 0, 0]), ImageState::Offline));
    courier.seen(1, true);
    assert_eq!(running(&courier, 1), (Some([0, 2, 0, 0]), ImageState::Unasked));
    let ask = courier.next(t(2_000), |slot| slot == 1).unwrap();
    courier.on_result(t(2_000), &ask, standing(&ask, false, false), &mut |_| {});
    assert_eq!(running(&courier, 1), (Some([0, 2, 0, 0]), ImageState::Confirmed));
    // The ground station's query tells it too; an IDS-only controller takes no update.
    courier.seen(0, true);
    courier.query(0, GCS).unwrap();
    let ask = courier.next(t(3_000), |_| true).unwrap();
    courier.on_result(t(3_000), &ask, done(&ask, version(true, [0, 3, 1, 0])), &mut |_| {});
    assert_eq!(running(&courier, 0), (Some([0, 3, 1, 0]), ImageState::Confirmed));
    courier.seen(2, true);
    let ask = courier.next(t(4_000), |slot| slot == 2).unwrap();
    let status_frame = Err(ExchangeError::Frame(FrameError::MessageType {
        expected: ext::EXT_REPLY_MT,
        actual: 0x53,
    }));
    courier.on_result(t(4_000), &ask, status_frame, &mut |_| {});
    assert_eq!(running(&courier, 2), (None, ImageState::NoUpdates));
}

/// A thruster of protocol 2 (it takes `PostMortem`) answering a `Version`, confirmed.
fn version_2(exchange: &Exchange) -> Result<Reply, ExchangeError> {
    let mut body = version(true, [0, 3, 0, 0]);
    if let ReplyBody::Version { protocol, .. } = &mut body {
        *protocol = 2;
    }
    done(exchange, body)
}

/// What a thruster holding `record` answers a `PostMortem`.
fn part_of(exchange: &Exchange, record: Option<&[u8; RECORD_LEN]>) -> Result<Reply, ExchangeError> {
    let Command::PostMortem { offset } = exchange.frame.command else {
        panic!("{:?}", exchange.frame.command)
    };
    let held: &[u8] = record.map_or(&[], |record| record);
    let mut data = [0; MAX_CHUNK];
    for (to, from) in data.iter_mut().zip(&held[usize::from(offset)..]) {
        *to = *from;
    }
    done(
        exchange,
        ReplyBody::PostMortem {
            len: held.len() as u8,
            offset,
            data,
        },
    )
}

#[test]
fn a_thruster_back_is_asked_for_its_post_mortem_record_once_after_its_version() {
    let record: [u8; RECORD_LEN] = core::array::from_fn(|i| (i * 7) as u8);
    let mut courier = Courier::new();
    let quiet = |o: Outgoing| panic!("a fetch says nothing: {o:?}");
    courier.seen(4, true);
    let ask = courier.next(t(0), |_| true).unwrap();
    assert_eq!(ask.frame.command, Command::Version);
    assert_eq!(courier.on_result(t(0), &ask, version_2(&ask), &mut quiet.clone()), None);
    // Two parts, each retried with its own sequence number through a lost reply; the record comes back whole.
    let first = courier.next(t(20), |slot| slot == 4).unwrap();
    assert_eq!(
        (first.slot, first.frame.command),
        (4, Command::PostMortem { offset: 0 })
    );
    assert!(courier.next(t(20), |slot| slot != 4).is_none(), "another bus's task");
    assert_eq!(
        courier.on_result(t(20), &first, Err(ExchangeError::Bus), &mut quiet.clone()),
        None
    );
    let again = courier.next(t(40), |_| true).unwrap();
    assert_eq!(again.frame, first.frame);
    assert_eq!(
        courier.on_result(t(40), &again, part_of(&again, Some(&record)), &mut quiet.clone()),
        None
    );
    let second = courier.next(t(60), |_| true).unwrap();
    assert_eq!(second.frame.command, Command::PostMortem { offset: 64 });
    assert_ne!(second.frame.seq, first.frame.seq);
    let fetched = courier.on_result(t(60), &second, part_of(&second, Some(&record)), &mut quiet.clone());
    assert_eq!(fetched, Some(PostMortem { slot: 4, record }));
    // Once: nothing more is asked until it answers again.
    assert!(
        (80..5_000)
            .step_by(20)
            .all(|ms| courier.next(t(ms), |_| true).is_none())
    );
    courier.seen(4, false);
    courier.seen(4, true);
    let ask = courier.next(t(5_000), |_| true).unwrap();
    courier.on_result(t(5_000), &ask, version_2(&ask), &mut quiet.clone());
    // None held now (a power cycle): one exchange, nothing fetched.
    let first = courier.next(t(5_020), |_| true).unwrap();
    assert_eq!(
        courier.on_result(t(5_020), &first, part_of(&first, None), &mut quiet.clone()),
        None
    );
    assert!(courier.next(t(5_040), |_| true).is_none());
}

#[test]
fn a_post_mortem_fetch_is_not_asked_of_protocol_1_and_ends_on_anything_but_its_part() {
    let mut courier = Courier::new();
    // Protocol 1: the update's commands only.
    courier.seen(0, true);
    let ask = courier.next(t(0), |_| true).unwrap();
    courier.on_result(t(0), &ask, done(&ask, version(true, [0, 1, 0, 0])), &mut |_| {});
    assert!(courier.next(t(20), |_| true).is_none());
    let status_frame = Err(ExchangeError::Frame(FrameError::MessageType {
        expected: ext::EXT_REPLY_MT,
        actual: 0x53,
    }));
    let endings = [
        status_frame,
        Ok(Reply::Refused {
            seq: 0,
            command: CommandKind::PostMortem,
            refusal: Refusal::OutOfRange,
        }),
        // A length this master does not know.
        Ok(Reply::Done {
            seq: 0,
            body: ReplyBody::PostMortem {
                len: 200,
                offset: 0,
                data: [0; MAX_CHUNK],
            },
        }),
    ];
    for (n, ending) in endings.into_iter().enumerate() {
        let ms = 1_000 * (n as u64 + 1);
        courier.seen(1, false);
        courier.seen(1, true);
        let ask = courier.next(t(ms), |_| true).unwrap();
        courier.on_result(t(ms), &ask, version_2(&ask), &mut |_| {});
        let fetch = courier.next(t(ms + 20), |_| true).unwrap();
        let ending = ending.map(|reply| match reply {
            Reply::Refused { command, refusal, .. } => Reply::Refused {
                seq: fetch.frame.seq,
                command,
                refusal,
            },
            Reply::Done { body, .. } => Reply::Done {
                seq: fetch.frame.seq,
                body,
            },
            busy => busy,
        });
        assert_eq!(courier.on_result(t(ms + 20), &fetch, ending, &mut |_| {}), None);
        assert!(courier.next(t(ms + 40), |_| true).is_none(), "ending {n}");
    }
    // Silent: asked again until the silence limit, then given up; the transfers wait meanwhile.
    courier.seen(1, false);
    courier.seen(1, true);
    let ask = courier.next(t(10_000), |_| true).unwrap();
    courier.on_result(t(10_000), &ask, version_2(&ask), &mut |_| {});
    let mut asked = 0;
    let mut ms = 10_020;
    while let Some(fetch) = courier.next(t(ms), |_| true) {
        assert_eq!(fetch.frame.command, Command::PostMortem { offset: 0 });
        courier.on_result(t(ms), &fetch, Err(ExchangeError::Bus), &mut |_| {});
        asked += 1;
        ms += 100;
    }
    assert_eq!((asked, ms), (31, 13_120));
}

#[test]
fn a_version_query_in_the_middle_of_a_fetch_takes_its_place_and_the_fetch_starts_again() {
    let record: [u8; RECORD_LEN] = core::array::from_fn(|i| (i * 3) as u8);
    let mut courier = Courier::new();
    courier.seen(2, true);
    let ask = courier.next(t(0), |_| true).unwrap();
    courier.on_result(t(0), &ask, version_2(&ask), &mut |_| {});
    let first = courier.next(t(20), |_| true).unwrap();
    assert_eq!(
        courier.on_result(t(20), &first, part_of(&first, Some(&record)), &mut |_| {}),
        None
    );
    // The ground station asks what T3 runs: its query goes first, answered and told.
    courier.query(2, GCS).unwrap();
    let query = courier.next(t(40), |_| true).unwrap();
    assert_eq!(query.frame.command, Command::Version);
    let mut said = Vec::new();
    courier.on_result(t(40), &query, version_2(&query), &mut |o| said.push(o));
    assert_eq!(acks(&said), [(MAV_CMD_LBV_QUERY_VERSION, AckResult::Accepted)]);
    // Then the fetch again from its first part, and the record comes whole; a stale second part is not taken.
    let again = courier.next(t(60), |_| true).unwrap();
    assert_eq!(again.frame.command, Command::PostMortem { offset: 0 });
    let stale = courier.on_result(t(60), &again, part_of(&first, Some(&record)), &mut |_| {});
    assert_eq!(stale, None);
    let again = courier.next(t(80), |_| true).unwrap();
    assert_eq!(again.frame.command, Command::PostMortem { offset: 0 });
    courier.on_result(t(80), &again, part_of(&again, Some(&record)), &mut |_| {});
    let second = courier.next(t(100), |_| true).unwrap();
    let fetched = courier.on_result(t(100), &second, part_of(&second, Some(&record)), &mut |_| {});
    assert_eq!(fetched, Some(PostMortem { slot: 2, record }));
    assert!(courier.next(t(120), |_| true).is_none());
}
