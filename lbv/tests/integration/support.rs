//! Flying `lbv bench --udp` from a Python ground-station script, for the pymavlink and MAVProxy tests: the bench
//! runs in real time on loopback ports while the script flies it and prints a JSON summary.
#![allow(dead_code, reason = "each test uses what it needs of these")]

use std::collections::BTreeSet;
use std::io::Read as _;
use std::net::UdpSocket;
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;

/// The bench process, killed when the test ends however it ends.
pub struct Bench(Child);

impl Bench {
    /// Its resident memory now, KiB (`VmRSS` in /proc), `None` where there is no /proc.
    pub fn rss_kib(&self) -> Option<u64> {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.0.id())).ok()?;
        let line = status.lines().find(|line| line.starts_with("VmRSS:"))?;
        line.split_whitespace().nth(1)?.parse().ok()
    }

    /// Stop it and return what it printed.
    pub fn stop(mut self) -> String {
        let _ = self.0.kill();
        let _ = self.0.wait();
        let mut out = String::new();
        if let Some(mut stdout) = self.0.stdout.take() {
            let _ = stdout.read_to_string(&mut out);
        }
        if let Some(mut stderr) = self.0.stderr.take() {
            let _ = stderr.read_to_string(&mut out);
        }
        out
    }
}

impl Drop for Bench {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A fresh directory under the system's temporary one, removed when dropped.
pub struct TempDir(pub std::path::PathBuf);

impl TempDir {
    /// `lbv-<name>-<pid>`, empty.
    pub fn new(name: &str) -> Self {
        let path = std::env::temp_dir().join(format!("lbv-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&path);
        std::fs::create_dir_all(&path).expect("create a temporary directory");
        Self(path)
    }

    /// `name` in it, as a string for a command line.
    pub fn join(&self, name: &str) -> String {
        self.0.join(name).display().to_string()
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// `N` free loopback UDP ports, none handed out before in this process: the tests run side by side, and a port one
/// test was given and let go of may be free again when the next asks.
pub fn free_ports<const N: usize>() -> [u16; N] {
    static GIVEN: Mutex<BTreeSet<u16>> = Mutex::new(BTreeSet::new());
    let mut given = GIVEN.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    // Held until all are chosen, so that they differ from one another.
    let mut held = Vec::new();
    let mut ports = [0; N];
    for port in &mut ports {
        *port = loop {
            let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
            let candidate = socket.local_addr().unwrap().port();
            held.push(socket);
            if given.insert(candidate) {
                break candidate;
            }
        };
    }
    ports
}

/// Run `lbv bench --udp` for `bench_seconds`, sending to 127.0.0.1:`gcs` and listening on 127.0.0.1:`listen`,
/// while `python3 script args...` flies it. Returns the script's JSON summary, which must say `"passed": true`,
/// and what the bench printed. `needs` names the Python packages the script needs (it exits 3 without them).
pub fn fly(
    script: &str,
    args: &[String],
    bench_seconds: &str,
    gcs: u16,
    listen: u16,
    needs: &str,
) -> (serde_json::Value, String) {
    fly_with(script, args, bench_seconds, gcs, listen, needs, &[])
}

/// As [`fly`], with `bench_args` added to the bench's command line.
pub fn fly_with(
    script: &str,
    args: &[String],
    bench_seconds: &str,
    gcs: u16,
    listen: u16,
    needs: &str,
    bench_args: &[&str],
) -> (serde_json::Value, String) {
    let bench = start_bench(bench_seconds, gcs, listen, bench_args);

    let pilot = match Command::new("python3")
        .arg(script)
        .args(args)
        .stdin(Stdio::null())
        .output()
    {
        Ok(output) => output,
        Err(error) => panic!("cannot run python3 ({error}): install Python 3 and `pip install {needs}`"),
    };
    let bench_output = bench.stop();
    let stdout = String::from_utf8_lossy(&pilot.stdout);
    let stderr = String::from_utf8_lossy(&pilot.stderr);
    if pilot.status.code() == Some(3) {
        panic!("{script} needs {needs} (`pip install {needs}`): {stderr}");
    }
    assert!(
        pilot.status.success(),
        "{script} failed ({}):\n{stderr}\nits summary: {stdout}\nthe bench printed:\n{bench_output}",
        pilot.status
    );
    let summary: serde_json::Value = serde_json::from_str(stdout.trim()).expect("the pilot's JSON summary");
    assert_eq!(summary["passed"], true, "{summary}");
    (summary, bench_output)
}

/// Start `lbv bench --udp` for `bench_seconds`, sending to 127.0.0.1:`gcs` and listening on 127.0.0.1:`listen`,
/// with `bench_args` added.
pub fn start_bench(bench_seconds: &str, gcs: u16, listen: u16, bench_args: &[&str]) -> Bench {
    let bench = Command::new(env!("CARGO_BIN_EXE_lbv"))
        .args(["bench", "--udp", "--duration", bench_seconds])
        .args(["--udp-send", &format!("127.0.0.1:{gcs}")])
        .args(["--udp-listen", &format!("127.0.0.1:{listen}")])
        .args(bench_args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start lbv bench --udp");
    Bench(bench)
}

/// A SeaBotix thruster's update file at 0.2.0, signed with the development key (keys/dev.key), as `lbv image sign
/// --allow-dev-key` makes one: a 4096-byte made-up payload with its image info at 0x200 and the key after it.
pub fn signed_update_file() -> Vec<u8> {
    signed_update_file_for(update_image::Target::ThrusterSeabotix)
}

/// The same for `target` (the master's: `Target::Master`).
#[allow(dead_code, reason = "not every test that includes this module updates the master")]
pub fn signed_update_file_for(target: update_image::Target) -> Vec<u8> {
    update_file(target, update_image::Version::new(0, 2, 0), None)
}

/// An update file for `target` at `version`, signed with the development key; with `flip`, that byte of the
/// payload has a bit flipped after signing (a file its bootloader refuses).
#[allow(dead_code, reason = "not every test that includes this module needs other versions")]
pub fn update_file(target: update_image::Target, version: update_image::Version, flip: Option<usize>) -> Vec<u8> {
    use update_image::{DEV_PUBLIC_KEY, HEADER_LEN, INFO_OFFSET, ImageInfo, image_record, key_from_hex};
    let mut payload: Vec<u8> = (0..4096u32)
        .map(|n| (n.wrapping_mul(2_654_435_761) >> 7) as u8)
        .collect();
    let record = image_record(ImageInfo::new(target, version), &DEV_PUBLIC_KEY);
    payload[INFO_OFFSET..INFO_OFFSET + record.len()].copy_from_slice(&record);
    let seed = key_from_hex(include_str!("../../../keys/dev.key")).unwrap();
    let mut file = update_image::sign(&payload, &seed).unwrap();
    if let Some(at) = flip {
        file[HEADER_LEN + at] ^= 0x04;
    }
    file
}

/// The texts of a summary's list that name an update file: the master also says a thruster is offline ("T3
/// offline") while it restarts into its new image.
pub fn file_texts(texts: &serde_json::Value) -> serde_json::Value {
    let texts = texts.as_array().into_iter().flatten();
    texts
        .filter(|text| text.as_str().is_some_and(|text| !text.starts_with('T')))
        .cloned()
        .collect()
}
