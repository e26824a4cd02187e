//! The courier's decisions, exchange by exchange, on explicit time; the whole path over the bus runs in the bench's
//! `field-update` scenario.

use super::*;
use crate::shared::{MAV_CMD_LBV_APPLY_UPDATE, MAV_CMD_LBV_QUERY_VERSION};
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
        while offset < image.len() && courier.has_room() && courier.transfer.is_some() {
            let end = (offset + MAX_WRITE).min(image.len());
            courier.write(offset as u32, &image[offset..end]).unwrap();
            offset = end;
            if offset == image.len() {
                courier.finish(true).unwrap();
            }
        }
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            if courier.transfer.is_some_and(|t| matches!(t.step, Step::Restart(_))) {
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
    assert_eq!(courier.apply(0, GCS), Ok(true));
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
    assert!(courier.transfer.is_none());
}

#[test]
fn a_thruster_that_comes_back_on_its_old_image_fails_the_apply() {
    let image = payload(SMALL);
    let mut courier = begun(&image);
    let mut dfu = vec![0u8; 8 * PAGE];
    carry(&mut courier, &image, &mut dfu, [0, 1, 0, 0]);
    assert_eq!(courier.apply(0, GCS), Ok(true));
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
    assert!(courier.transfer.is_none());
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
    assert!(courier.transfer.is_none());
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
    assert!(courier.transfer.is_none());
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
fn a_new_image_that_never_confirms_fails_the_apply() {
    let mut courier = rebooting();
    let mut said = Vec::new();
    for ms in (200..40_000).step_by(20) {
        let Some(exchange) = courier.next(t(ms), |_| true) else {
            continue;
        };
        let result = running(&exchange, [0, 2, 0, 0], true);
        courier.on_result(t(ms), &exchange, result, &mut |o| said.push(o));
    }
    assert_eq!(
        texts(&said),
        [
            "thruster0.lbvu: runs 0.2.0, on trial",
            "thruster0.lbvu: the new image did not confirm"
        ]
    );
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
    assert!(courier.transfer.is_none());
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
    // One at a time, and no image begins meanwhile.
    assert_eq!(courier.query(2, GCS), Err(NotTaken));
    assert_eq!(courier.begin(0, 1, 64, &header(64)), Err(NotTaken));
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
    assert!(courier.transfer.is_none() && courier.next(t(20), |_| true).is_none());

    // A thruster that cannot check signatures says so; an IDS-only one, and a silent one, fail the query.
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
    assert!(courier.transfer.is_none());
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
        assert!(courier.transfer.is_none());
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
