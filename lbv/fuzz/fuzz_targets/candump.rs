//! `lbv decode can` on arbitrary input, in both output forms: never panics, counts every line, prints one line
//! per BAT frame (decoded or not), and every JSON line it prints parses.
#![no_main]

use lbv::decode::can::run;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let lines = data.split(|&byte| byte == b'\n').count() - usize::from(data.is_empty() || data.ends_with(b"\n"));
    for json in [false, true] {
        let (mut out, mut err) = (Vec::new(), Vec::new());
        let Ok(summary) = run(data, &mut out, &mut err, json) else {
            panic!("reading from and writing to memory cannot fail");
        };
        assert_eq!(summary.lines, lines as u64);
        let printed: Vec<&[u8]> = out.split(|&byte| byte == b'\n').filter(|line| !line.is_empty()).collect();
        assert_eq!(printed.len() as u64, summary.decoded + summary.decode_errors);
        if json {
            for line in printed {
                assert!(serde_json::from_slice::<serde_json::Value>(line).is_ok(), "{line:?}");
            }
        }
    }
});
