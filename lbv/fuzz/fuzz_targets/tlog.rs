//! `lbv decode tlog`'s reader on arbitrary input: never panics, and what it skips and the frames it reads account
//! for no more than the input. Half the runs frame the input first: each piece becomes a whole frame (a timestamp,
//! a MAVLink 2 header naming a message the master's black box logs, the piece as its payload, a CRC that checks),
//! so that the messages' fields reach the trace with any value; every one of those frames must then be read.
#![no_main]

use lbv::decode::tlog::read_trace;
use lbv_master_fw::console::lbv::MavMessage;
use libfuzzer_sys::fuzz_target;
use mavlink_core::Message;

/// HEARTBEAT, SERVO_OUTPUT_RAW, BATTERY_STATUS, ESC_INFO, ESC_STATUS, STATUSTEXT, ESC_TELEMETRY_1_TO_4 and _5_TO_8.
const IDS: [u32; 8] = [0, 36, 147, 290, 291, 253, 11030, 11031];

fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    let (input, framed) = if mode & 1 == 0 {
        (rest.to_vec(), None)
    } else {
        let mut file = Vec::new();
        let mut frames = 0u64;
        for (n, piece) in rest.chunks(64).enumerate() {
            let (&pick, payload) = piece.split_first().unwrap_or((&0, &[]));
            let id = IDS[usize::from(pick) % IDS.len()];
            file.extend_from_slice(&(n as u64 * 100_000).to_be_bytes());
            let [a, b, c, _] = id.to_le_bytes();
            let mut frame = vec![0xFD, payload.len() as u8, 0, 0, n as u8, 1, 1, a, b, c];
            frame.extend_from_slice(payload);
            let crc = mavlink_core::calculate_crc(&frame[1..], MavMessage::extra_crc(id));
            frame.extend_from_slice(&crc.to_le_bytes());
            file.extend_from_slice(&frame);
            frames += 1;
        }
        (file, Some(frames))
    };
    let mut items = 0u64;
    let Ok((trace, stats)) = read_trace(&input[..], |_| {
        items += 1;
        Ok(())
    }) else {
        panic!("reading from memory cannot fail");
    };
    // A frame is 16 bytes at least: its timestamp and a MAVLink 1 frame without payload.
    assert!(stats.skipped + stats.frames * 16 <= input.len() as u64, "{stats:?} of {} bytes", input.len());
    assert!(trace.samples.len() as u64 <= stats.frames && items >= trace.samples.len() as u64);
    if let Some(frames) = framed {
        assert_eq!((stats.frames, stats.skipped), (frames, 0));
    }
});
