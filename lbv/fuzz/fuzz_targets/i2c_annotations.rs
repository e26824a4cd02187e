//! `lbv decode i2c` on arbitrary input, in both output forms: never panics, prints exactly one line per
//! transfer it counts, and every JSON line it prints parses.
#![no_main]

use lbv::decode::i2c::{Args, run};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    for (json, samplerate) in [(true, Some(1e6)), (false, None)] {
        let args = Args {
            json,
            samplerate,
            ..Args::default()
        };
        let (mut out, mut err) = (Vec::new(), Vec::new());
        let Ok(counts) = run(data, &mut out, &mut err, &args) else {
            panic!("reading from and writing to memory cannot fail");
        };
        let printed: Vec<&[u8]> = out.split(|&byte| byte == b'\n').filter(|line| !line.is_empty()).collect();
        assert_eq!(printed.len() as u64, counts.transfers);
        if json {
            for line in printed {
                assert!(serde_json::from_slice::<serde_json::Value>(line).is_ok(), "{line:?}");
            }
        }
    }
});
