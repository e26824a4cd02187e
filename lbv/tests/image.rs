//! `lbv image`: the payload a firmware ELF puts in flash (from ELFs written here with the object crate), and the
//! commands run as a user would: keygen, sign, inspect, a tampered or truncated file refused, the development
//! key refused without --allow-dev-key, and no panic on any file.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use lbv::image::{ElfError, MAX_UPDATE_FILE, payload_from_elf};
use object::Endianness;
use object::elf::{EF_ARM_EABI_VER5, ELFOSABI_NONE, EM_386, EM_ARM, ET_EXEC, PF_R, PT_LOAD};
use object::write::elf::{FileHeader, ProgramHeader, Writer};
use update_image::{HEADER_LEN, INFO_OFFSET, ImageInfo, InfoError, Target, Version};

/// The ACTIVE partition's start in these tests: after a 10 KiB bootloader.
const BASE: u32 = 0x0800_2800;
const INFO: ImageInfo = ImageInfo::new(Target::ThrusterLegacy, Version::new(0, 7, 12));

/// A loadable segment: where it loads (physical) and runs (virtual), its bytes in the file, its size in memory.
struct Segment {
    paddr: u32,
    vaddr: u32,
    bytes: Vec<u8>,
    memsz: u32,
}

impl Segment {
    fn flash(paddr: u32, bytes: Vec<u8>) -> Segment {
        let memsz = bytes.len() as u32;
        Segment {
            paddr,
            vaddr: paddr,
            bytes,
            memsz,
        }
    }
}

/// A 32-bit ELF of `machine` with these segments, as a linker writes an executable.
fn elf_for(machine: object::elf::Machine, segments: &[Segment]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut writer = Writer::new(Endianness::Little, false, &mut out);
    writer.reserve_file_header();
    writer.reserve_program_headers(segments.len() as u32);
    let offsets: Vec<u64> = segments
        .iter()
        .map(|segment| writer.reserve(segment.bytes.len() as u64, 4))
        .collect();
    writer
        .write_file_header(&FileHeader {
            os_abi: ELFOSABI_NONE,
            abi_version: 0,
            e_type: ET_EXEC,
            e_machine: machine,
            e_entry: u64::from(BASE) + 0x401,
            e_flags: EF_ARM_EABI_VER5,
        })
        .unwrap();
    writer.write_align_program_headers();
    for (segment, offset) in segments.iter().zip(&offsets) {
        writer.write_program_header(&ProgramHeader {
            p_type: PT_LOAD,
            p_flags: PF_R,
            p_offset: *offset,
            p_vaddr: segment.vaddr.into(),
            p_paddr: segment.paddr.into(),
            p_filesz: segment.bytes.len() as u64,
            p_memsz: segment.memsz.into(),
            p_align: 4,
        });
    }
    for (segment, offset) in segments.iter().zip(&offsets) {
        writer.pad_until(*offset);
        writer.write(&segment.bytes);
    }
    out
}

fn elf(segments: &[Segment]) -> Vec<u8> {
    elf_for(EM_ARM, segments)
}

/// What a firmware's flash holds at the ACTIVE partition's start: a vector table, its image info at 0x200, code.
fn text(len: usize, info: Option<ImageInfo>) -> Vec<u8> {
    let mut text: Vec<u8> = (0..len).map(|i| (i * 7 + 3) as u8).collect();
    if let Some(info) = info {
        text[INFO_OFFSET..INFO_OFFSET + 32].copy_from_slice(&info.to_bytes());
    }
    text
}

/// A firmware image's segments: code in flash, .data run in RAM but loaded after the code, .bss in RAM only.
fn firmware(info: Option<ImageInfo>) -> Vec<Segment> {
    vec![
        Segment::flash(BASE, text(3001, info)),
        Segment {
            paddr: BASE + 3004,
            vaddr: 0x2000_0000,
            bytes: vec![0xD1; 13],
            memsz: 13,
        },
        Segment {
            paddr: 0x2000_0010,
            vaddr: 0x2000_0010,
            bytes: Vec::new(),
            memsz: 4096,
        },
    ]
}

#[test]
fn the_payload_is_the_flash_from_the_lowest_load_address() {
    let payload = payload_from_elf(&elf(&firmware(Some(INFO))), None).unwrap();
    assert_eq!(payload.base, BASE);
    // Code, one 0xFF to .data's load address, .data, 0xFF to a whole double word; .bss is not in it.
    let mut expected = text(3001, Some(INFO));
    expected.extend([0xFF; 3]);
    expected.extend([0xD1; 13]);
    expected.extend([0xFF; 7]);
    assert_eq!(payload.bytes.len(), 3024);
    assert_eq!(payload.bytes, expected);
    assert_eq!(payload.info(), Ok(INFO));
}

#[test]
fn a_master_image_larger_than_the_thruster_s_flash_is_taken() {
    // The master's ACTIVE partition on its G474 (0x0800_3000), 136 KiB of code: more than the G431's whole flash.
    let info = ImageInfo::new(Target::Master, Version::new(0, 2, 0));
    let master = [Segment::flash(0x0800_3000, text(136 * 1024, Some(info)))];
    let payload = payload_from_elf(&elf(&master), None).unwrap();
    assert_eq!((payload.base, payload.bytes.len()), (0x0800_3000, 136 * 1024));
    assert_eq!(payload.info(), Ok(info));
}

#[test]
fn segments_are_placed_by_address_whatever_their_order_in_the_file() {
    let mut segments = firmware(Some(INFO));
    segments.reverse();
    let reversed = payload_from_elf(&elf(&segments), None).unwrap();
    assert_eq!(reversed, payload_from_elf(&elf(&firmware(Some(INFO))), None).unwrap());
}

#[test]
fn a_base_moves_the_start_and_a_segment_below_it_is_refused() {
    let elf = elf(&firmware(Some(INFO)));
    let lower = payload_from_elf(&elf, Some(BASE - 0x200)).unwrap();
    assert_eq!(lower.base, BASE - 0x200);
    assert!(lower.bytes[..0x200].iter().all(|byte| *byte == 0xFF));
    // The info is then looked for at the new base + 0x200, where the vector table is.
    assert!(matches!(lower.info(), Err(ElfError::NoInfo { at, .. }) if at == u64::from(BASE)));
    assert_eq!(
        payload_from_elf(&elf, Some(BASE + 8)),
        Err(ElfError::BelowBase {
            segment: BASE.into(),
            base: BASE + 8
        })
    );
}

#[test]
fn an_image_without_info_is_said_to_be_one() {
    let payload = payload_from_elf(&elf(&firmware(None)), None).unwrap();
    let error = payload.info().unwrap_err();
    assert!(matches!(
        error,
        ElfError::NoInfo {
            error: InfoError::Magic(_),
            ..
        }
    ));
    assert!(
        error
            .to_string()
            .starts_with("no image info at 0x08002A00: is this image built for field update?"),
        "{error}"
    );
}

#[test]
fn what_is_not_a_firmware_elf_is_refused() {
    let good = elf(&firmware(Some(INFO)));
    assert!(matches!(payload_from_elf(b"LBVU", None), Err(ElfError::NotElf(_))));
    assert!(matches!(payload_from_elf(&[], None), Err(ElfError::NotElf(_))));
    assert_eq!(
        payload_from_elf(&elf_for(EM_386, &firmware(Some(INFO))), None),
        Err(ElfError::NotArm)
    );
    let mut elf64 = good.clone();
    elf64[4] = 2;
    assert_eq!(payload_from_elf(&elf64, None), Err(ElfError::NotArm));
    assert_eq!(payload_from_elf(&elf(&[]), None), Err(ElfError::NoSegments));
    // A segment loaded in RAM with bytes: the span is not flash.
    let mut in_ram = firmware(Some(INFO));
    in_ram[2].bytes = vec![0; 4];
    assert!(matches!(
        payload_from_elf(&elf(&in_ram), None),
        Err(ElfError::TooLarge { .. })
    ));
    let overlapping = [
        Segment::flash(BASE, text(0x400, Some(INFO))),
        Segment::flash(BASE + 0x3FC, vec![0; 8]),
    ];
    assert_eq!(
        payload_from_elf(&elf(&overlapping), None),
        Err(ElfError::Overlap {
            at: u64::from(BASE) + 0x3FC
        })
    );
}

/// Every prefix of a good ELF, and every byte of its headers changed: an answer, never a panic.
#[test]
fn no_elf_makes_it_panic() {
    let good = elf(&firmware(Some(INFO)));
    for len in 0..good.len() {
        let _ = payload_from_elf(&good[..len], None);
    }
    for at in 0..200.min(good.len()) {
        for value in [0x00, 0x01, 0x7F, 0x80, 0xFF] {
            let mut bytes = good.clone();
            bytes[at] = value;
            if let Ok(payload) = payload_from_elf(&bytes, None) {
                let _ = payload.info();
            }
        }
    }
}

// The commands.

fn lbv(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lbv"))
        .args(args)
        .output()
        .expect("lbv runs")
}

fn text_of(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// A directory of this test's own.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lbv-image-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn path(dir: &Path, name: &str) -> String {
    dir.join(name).display().to_string()
}

fn status(output: &Output) -> Option<i32> {
    output.status.code()
}

/// Everything it said, for assertion messages.
fn said(output: &Output) -> String {
    format!("{}{}", text_of(&output.stdout), text_of(&output.stderr))
}

#[test]
fn keygen_sign_inspect() {
    let dir = scratch("flow");
    let elf_path = path(&dir, "thruster.elf");
    std::fs::write(&elf_path, elf(&firmware(Some(INFO)))).unwrap();
    let (key, public, file) = (
        path(&dir, "mine.key"),
        path(&dir, "mine.pub"),
        path(&dir, "thruster.lbvu"),
    );

    let made = lbv(&["image", "keygen", "--out", &path(&dir, "mine")]);
    assert_eq!(status(&made), Some(0), "{}", said(&made));
    for written in [&key, &public] {
        let line = std::fs::read_to_string(written).unwrap();
        assert_eq!(line.len(), 65, "{line:?}");
        assert!(update_image::key_from_hex(&line).is_some());
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(&key).unwrap().permissions().mode();
        assert_eq!(mode & 0o077, 0, "the secret is its owner's alone: {mode:o}");
    }
    let again = lbv(&["image", "keygen", "--out", &path(&dir, "mine")]);
    assert_eq!(status(&again), Some(2));
    assert!(said(&again).contains("exists"), "{}", said(&again));

    let signed = lbv(&["image", "sign", &elf_path, "--key", &key, "--out", &file]);
    assert_eq!(status(&signed), Some(0), "{}", said(&signed));
    let out = said(&signed);
    assert!(out.contains("Aveox/Legacy family (0x54/0x55), version 0.7.12"), "{out}");
    assert!(out.contains("3024 bytes from 0x08002800"), "{out}");
    let bytes = std::fs::read(&file).unwrap();
    assert_eq!(bytes.len(), HEADER_LEN + 3024);

    let inspected = lbv(&["image", "inspect", &file, "--key", &public]);
    assert_eq!(status(&inspected), Some(0), "{}", said(&inspected));
    let out = said(&inspected);
    for line in [
        "update file, format 1",
        "target     thruster, Aveox/Legacy family (0x54/0x55)",
        "version    0.7.12",
        "payload    3024 bytes, SHA-512 ",
        "signature  verifies with",
        "not signed with the development key",
    ] {
        assert!(out.contains(line), "{line:?} in {out}");
    }
    // Without a key it can only say that it is not the development key's: not verified.
    let unchecked = lbv(&["image", "inspect", &file]);
    assert_eq!(status(&unchecked), Some(1), "{}", said(&unchecked));
    assert!(said(&unchecked).contains("not the development key's"));
    // The ELF itself: its info, the payload it makes, the same digest.
    let elf_inspected = lbv(&["image", "inspect", &elf_path]);
    assert_eq!(status(&elf_inspected), Some(0), "{}", said(&elf_inspected));
    let out = said(&elf_inspected);
    assert!(
        out.contains("firmware ELF") && out.contains("version    0.7.12"),
        "{out}"
    );
    let digest = |text: &str| text.split("SHA-512 ").nth(1).map(|rest| rest[..32].to_string());
    assert_eq!(digest(&out), digest(&said(&inspected)));

    // Another key does not verify it.
    assert_eq!(
        status(&lbv(&["image", "keygen", "--out", &path(&dir, "other")])),
        Some(0)
    );
    let other = lbv(&["image", "inspect", &file, "--key", &path(&dir, "other.pub")]);
    assert_eq!(status(&other), Some(1));
    assert!(said(&other).contains("DOES NOT VERIFY"), "{}", said(&other));
}

#[test]
fn tampered_and_truncated_files_fail_inspect() {
    let dir = scratch("tampered");
    let elf_path = path(&dir, "master.elf");
    let info = ImageInfo::new(Target::Master, Version::new(1, 0, 0));
    std::fs::write(&elf_path, elf(&firmware(Some(info)))).unwrap();
    assert_eq!(status(&lbv(&["image", "keygen", "--out", &path(&dir, "k")])), Some(0));
    let file = path(&dir, "master.lbvu");
    let signed = lbv(&[
        "image",
        "sign",
        &elf_path,
        "--key",
        &path(&dir, "k.key"),
        "--out",
        &file,
    ]);
    assert_eq!(status(&signed), Some(0), "{}", said(&signed));
    let good = std::fs::read(&file).unwrap();
    let inspect = |bytes: &[u8], name: &str| {
        let tampered = path(&dir, name);
        std::fs::write(&tampered, bytes).unwrap();
        lbv(&["image", "inspect", &tampered, "--key", &path(&dir, "k.pub")])
    };
    assert_eq!(status(&inspect(&good, "good.lbvu")), Some(0));

    let mut flipped = good.clone();
    flipped[HEADER_LEN + 1000] ^= 0x04;
    let output = inspect(&flipped, "flipped.lbvu");
    assert_eq!(status(&output), Some(1));
    assert!(said(&output).contains("DOES NOT VERIFY"), "{}", said(&output));

    let mut newer = good.clone();
    newer[12] = 2;
    let output = inspect(&newer, "newer.lbvu");
    assert_eq!(status(&output), Some(1));
    assert!(
        said(&output).contains("refused    the header says version 2.0.0, the payload is version 1.0.0"),
        "{}",
        said(&output)
    );

    let output = inspect(&good[..good.len() - 8], "short.lbvu");
    assert_eq!(status(&output), Some(1));
    assert!(
        said(&output).contains("refused    truncated: the header announces a payload of"),
        "{}",
        said(&output)
    );

    let output = inspect(&good[..40], "stub.lbvu");
    assert_eq!(status(&output), Some(1));
    assert!(
        said(&output).contains("the header needs 80 bytes, there are 40"),
        "{}",
        said(&output)
    );
}

#[test]
fn the_development_key_signs_only_when_allowed() {
    let dir = scratch("devkey");
    let elf_path = path(&dir, "t.elf");
    std::fs::write(&elf_path, elf(&firmware(Some(INFO)))).unwrap();
    let dev_key = concat!(env!("CARGO_MANIFEST_DIR"), "/../keys/dev.key");
    let file = path(&dir, "t.lbvu");
    let refused = lbv(&["image", "sign", &elf_path, "--key", dev_key, "--out", &file]);
    assert_eq!(status(&refused), Some(2));
    assert!(
        said(&refused).contains("is the development key, whose secret is published"),
        "{}",
        said(&refused)
    );
    assert!(!Path::new(&file).exists());

    let allowed = lbv(&[
        "image",
        "sign",
        &elf_path,
        "--key",
        dev_key,
        "--out",
        &file,
        "--allow-dev-key",
    ]);
    assert_eq!(status(&allowed), Some(0), "{}", said(&allowed));
    assert!(said(&allowed).contains("(the development key)"));
    // Without --key, inspect checks it with the development key, and says so.
    let inspected = lbv(&["image", "inspect", &file]);
    assert_eq!(status(&inspected), Some(0), "{}", said(&inspected));
    assert!(said(&inspected).contains("verifies with the development key"));
    assert!(said(&inspected).contains("signed with the development key: anyone can sign"));
}

#[test]
fn sign_refuses_an_elf_without_image_info() {
    let dir = scratch("noinfo");
    let elf_path = path(&dir, "old.elf");
    std::fs::write(&elf_path, elf(&firmware(None))).unwrap();
    assert_eq!(status(&lbv(&["image", "keygen", "--out", &path(&dir, "k")])), Some(0));
    let output = lbv(&[
        "image",
        "sign",
        &elf_path,
        "--key",
        &path(&dir, "k.key"),
        "--out",
        &path(&dir, "o.lbvu"),
    ]);
    assert_eq!(status(&output), Some(2));
    assert!(
        said(&output).contains("no image info at 0x08002A00: is this image built for field update?"),
        "{}",
        said(&output)
    );
    let inspected = lbv(&["image", "inspect", &elf_path]);
    assert_eq!(status(&inspected), Some(1));
    assert!(
        said(&inspected).contains("no image info at 0x08002A00"),
        "{}",
        said(&inspected)
    );
}

/// Missing, huge, empty and wrong files, bad keys and bad values: exit status 2 (or 1 for what inspect finds),
/// a message, never a panic.
#[test]
fn bad_files_and_values_are_refused() {
    let dir = scratch("bad");
    let elf_path = path(&dir, "t.elf");
    std::fs::write(&elf_path, elf(&firmware(Some(INFO)))).unwrap();
    assert_eq!(status(&lbv(&["image", "keygen", "--out", &path(&dir, "k")])), Some(0));
    let (key, public) = (path(&dir, "k.key"), path(&dir, "k.pub"));
    let huge = path(&dir, "huge.lbvu");
    std::fs::File::create(&huge).unwrap().set_len(10 << 30).unwrap();
    let empty = path(&dir, "empty.lbvu");
    std::fs::write(&empty, b"").unwrap();
    let not_a_key = path(&dir, "junk.key");
    std::fs::write(&not_a_key, "not hex at all\n").unwrap();
    let missing = path(&dir, "missing");
    let missing_pub = path(&dir, "missing.pub");
    let out = path(&dir, "o.lbvu");
    let (no_dir_out, no_dir_keys) = (path(&dir, "no/such/dir.lbvu"), path(&dir, "no/such/dir"));
    let cases: Vec<(Vec<&str>, i32, String)> = vec![
        (vec!["image", "inspect", &missing], 2, "cannot open".into()),
        (
            vec!["image", "inspect", &huge],
            2,
            format!("is larger than {} KiB", MAX_UPDATE_FILE / 1024),
        ),
        (vec!["image", "inspect", &empty], 1, "there are 0".into()),
        (
            vec!["image", "inspect", &elf_path, "--key", &key],
            2,
            "is a secret key".into(),
        ),
        (
            vec!["image", "inspect", &elf_path, "--key", &missing_pub],
            2,
            "cannot open".into(),
        ),
        (
            vec!["image", "sign", &elf_path, "--key", &public, "--out", &out],
            2,
            "is a public key".into(),
        ),
        (
            vec!["image", "sign", &elf_path, "--key", &not_a_key, "--out", &out],
            2,
            "is not a key file".into(),
        ),
        (
            vec!["image", "sign", &missing, "--key", &key, "--out", &out],
            2,
            "cannot open".into(),
        ),
        (
            vec!["image", "sign", &huge, "--key", &key, "--out", &out],
            2,
            "is larger than 512 KiB".into(),
        ),
        (
            vec!["image", "sign", &empty, "--key", &key, "--out", &out],
            2,
            "not an ELF file".into(),
        ),
        (
            vec![
                "image",
                "sign",
                &elf_path,
                "--key",
                &key,
                "--out",
                &out,
                "--base",
                "0x1_0000_0000",
            ],
            2,
            "--base".into(),
        ),
        (
            vec![
                "image", "sign", &elf_path, "--key", &key, "--out", &out, "--base", "flash",
            ],
            2,
            "not a 32-bit address".into(),
        ),
        (vec!["image", "sign", &elf_path, "--out", &out], 2, "--key".into()),
        (
            vec!["image", "sign", &elf_path, "--key", &key, "--out", &no_dir_out],
            2,
            "cannot write".into(),
        ),
        (vec!["image", "keygen"], 2, "--out".into()),
        (
            vec!["image", "keygen", "--out", &no_dir_keys],
            2,
            "cannot create".into(),
        ),
    ];
    for (args, expected, message) in cases {
        let output = lbv(&args);
        let said = said(&output);
        assert_eq!(status(&output), Some(expected), "lbv {args:?}: {said}");
        assert!(said.contains(&message), "lbv {args:?}: {message:?} in {said}");
        assert!(!said.contains("panicked"), "lbv {args:?}: {said}");
    }
    assert!(!Path::new(&out).exists());
}

/// A third ed25519, not Rust: Python's `cryptography` (OpenSSL) verifies what `lbv image sign` writes, over
/// SHA-512 of the payload, and derives the same public key from the secret. Skipped, with a note, where python3
/// has no `cryptography`: the two Rust implementations and embassy-boot (update-image's tests) are the required
/// check.
#[test]
fn python_cryptography_verifies_what_lbv_signs() {
    const CHECK: &str = "\
import hashlib, struct, sys
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
update, key, public = (open(name, 'rb').read() for name in sys.argv[1:4])
header, payload = update[:80], update[80:]
assert header[:4] == b'LBVU' and struct.unpack('<I', header[8:12])[0] == len(payload)
seed, public = bytes.fromhex(key.decode().strip()), bytes.fromhex(public.decode().strip())
derived = Ed25519PrivateKey.from_private_bytes(seed).public_key().public_bytes(
    serialization.Encoding.Raw, serialization.PublicFormat.Raw)
assert derived == public, 'public key'
Ed25519PublicKey.from_public_bytes(public).verify(header[16:80], hashlib.sha512(payload).digest())
print('verifies')
";
    let has_it = Command::new("python3").args(["-c", "import cryptography"]).output();
    if !has_it.is_ok_and(|output| output.status.success()) {
        eprintln!("skipped: python3 with the cryptography package is not here");
        return;
    }
    let dir = scratch("python");
    let elf_path = path(&dir, "t.elf");
    std::fs::write(&elf_path, elf(&firmware(Some(INFO)))).unwrap();
    assert_eq!(status(&lbv(&["image", "keygen", "--out", &path(&dir, "k")])), Some(0));
    let file = path(&dir, "t.lbvu");
    let signed = lbv(&[
        "image",
        "sign",
        &elf_path,
        "--key",
        &path(&dir, "k.key"),
        "--out",
        &file,
    ]);
    assert_eq!(status(&signed), Some(0), "{}", said(&signed));
    let check = |update: &str| {
        Command::new("python3")
            .args(["-c", CHECK, update, &path(&dir, "k.key"), &path(&dir, "k.pub")])
            .output()
            .unwrap()
    };
    let output = check(&file);
    assert!(
        output.status.success() && said(&output).contains("verifies"),
        "{}",
        said(&output)
    );
    let mut flipped = std::fs::read(&file).unwrap();
    flipped[HEADER_LEN + 7] ^= 1;
    let tampered = path(&dir, "flipped.lbvu");
    std::fs::write(&tampered, flipped).unwrap();
    let output = check(&tampered);
    assert!(
        !output.status.success() && said(&output).contains("InvalidSignature"),
        "{}",
        said(&output)
    );
}
