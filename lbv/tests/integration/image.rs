//! `lbv image`: the payload a firmware ELF puts in flash (from ELFs written here with the object crate), and the
//! commands run as a user would: keygen, sign, inspect, a tampered or truncated file refused, the development
//! key refused without --allow-dev-key, the security counter and the rollback flag signed into the payload, an
//! ELF that embeds another key than the signing one refused without --rotate-key, and no panic on any file.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use lbv::image::{ElfError, MAX_UPDATE_FILE, payload_from_elf};
use object::Endianness;
use object::elf::{EF_ARM_EABI_VER5, ELFOSABI_NONE, EM_386, EM_ARM, ET_EXEC, PF_R, PT_LOAD};
use object::write::elf::{FileHeader, ProgramHeader, Writer};
use update_image::{
    DEV_PUBLIC_KEY, HEADER_LEN, Header, INFO_LEN, INFO_OFFSET, ImageInfo, InfoError, KEY_OFFSET, Refusal, Target,
    VerifyError, Version, check_upgrade, image_record,
};

/// The ACTIVE partition's start in these tests: after a 10 KiB bootloader.
const BASE: u32 = 0x0800_2800;
const INFO: ImageInfo = ImageInfo::new(Target::ThrusterLegacy, Version::new(0, 7, 12));
/// The update key the ELFs of the payload tests embed.
const KEY: [u8; 32] = DEV_PUBLIC_KEY;

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

/// What a firmware's flash holds at the ACTIVE partition's start: a vector table, its image info at 0x200 and the
/// update key `key` after it, code.
fn text(len: usize, info: Option<ImageInfo>, key: &[u8; 32]) -> Vec<u8> {
    let mut text: Vec<u8> = (0..len).map(|i| (i * 7 + 3) as u8).collect();
    if let Some(info) = info {
        let record = image_record(info, key);
        text[INFO_OFFSET..INFO_OFFSET + record.len()].copy_from_slice(&record);
    }
    text
}

/// A firmware image's segments: code in flash, .data run in RAM but loaded after the code, .bss in RAM only.
fn firmware(info: Option<ImageInfo>, key: &[u8; 32]) -> Vec<Segment> {
    vec![
        Segment::flash(BASE, text(3001, info, key)),
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
    let payload = payload_from_elf(&elf(&firmware(Some(INFO), &KEY)), None).unwrap();
    assert_eq!(payload.base, BASE);
    // Code, one 0xFF to .data's load address, .data, 0xFF to a whole double word; .bss is not in it.
    let mut expected = text(3001, Some(INFO), &KEY);
    expected.extend([0xFF; 3]);
    expected.extend([0xD1; 13]);
    expected.extend([0xFF; 7]);
    assert_eq!(payload.bytes.len(), 3024);
    assert_eq!(payload.bytes, expected);
    assert_eq!(payload.info(), Ok(INFO));
    assert_eq!(payload.key(), Some(KEY));
}

#[test]
fn a_master_image_larger_than_the_thruster_s_flash_is_taken() {
    // The master's ACTIVE partition on its G474 (0x0800_4000), 136 KiB of code: more than the G431's whole flash.
    let info = ImageInfo::new(Target::Master, Version::new(0, 2, 0));
    let master = [Segment::flash(0x0800_4000, text(136 * 1024, Some(info), &KEY))];
    let payload = payload_from_elf(&elf(&master), None).unwrap();
    assert_eq!((payload.base, payload.bytes.len()), (0x0800_4000, 136 * 1024));
    assert_eq!(payload.info(), Ok(info));
}

#[test]
fn segments_are_placed_by_address_whatever_their_order_in_the_file() {
    let mut segments = firmware(Some(INFO), &KEY);
    segments.reverse();
    let reversed = payload_from_elf(&elf(&segments), None).unwrap();
    assert_eq!(
        reversed,
        payload_from_elf(&elf(&firmware(Some(INFO), &KEY)), None).unwrap()
    );
}

#[test]
fn a_base_moves_the_start_and_a_segment_below_it_is_refused() {
    let elf = elf(&firmware(Some(INFO), &KEY));
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
    let payload = payload_from_elf(&elf(&firmware(None, &KEY)), None).unwrap();
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
    let good = elf(&firmware(Some(INFO), &KEY));
    assert!(matches!(payload_from_elf(b"LBVU", None), Err(ElfError::NotElf(_))));
    assert!(matches!(payload_from_elf(&[], None), Err(ElfError::NotElf(_))));
    assert_eq!(
        payload_from_elf(&elf_for(EM_386, &firmware(Some(INFO), &KEY)), None),
        Err(ElfError::NotArm)
    );
    let mut elf64 = good.clone();
    elf64[4] = 2;
    assert_eq!(payload_from_elf(&elf64, None), Err(ElfError::NotArm));
    assert_eq!(payload_from_elf(&elf(&[]), None), Err(ElfError::NoSegments));
    // A segment loaded in RAM with bytes: the span is not flash.
    let mut in_ram = firmware(Some(INFO), &KEY);
    in_ram[2].bytes = vec![0; 4];
    assert!(matches!(
        payload_from_elf(&elf(&in_ram), None),
        Err(ElfError::TooLarge { .. })
    ));
    let overlapping = [
        Segment::flash(BASE, text(0x400, Some(INFO), &KEY)),
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
    let good = elf(&firmware(Some(INFO), &KEY));
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

/// `lbv image keygen --out DIR/NAME`: the secret's path, the public key's path and the public key.
fn keygen(dir: &Path, name: &str) -> (String, String, [u8; 32]) {
    let made = lbv(&["image", "keygen", "--out", &path(dir, name)]);
    assert_eq!(status(&made), Some(0), "{}", said(&made));
    let public = path(dir, &format!("{name}.pub"));
    let key = update_image::key_from_hex(&std::fs::read_to_string(&public).unwrap()).unwrap();
    (path(dir, &format!("{name}.key")), public, key)
}

/// A firmware ELF at DIR/NAME, with the image info `info` and the update key `key`.
fn write_elf(dir: &Path, name: &str, info: ImageInfo, key: &[u8; 32]) -> String {
    let elf_path = path(dir, name);
    std::fs::write(&elf_path, elf(&firmware(Some(info), key))).unwrap();
    elf_path
}

/// Lower-case hex, as lbv prints keys.
fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|byte| format!("{byte:02x}")).collect()
}

#[test]
fn keygen_sign_inspect() {
    let dir = scratch("flow");
    let elf_path = path(&dir, "thruster.elf");
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
    // The image embeds the public key it was built with: this one.
    let mine = update_image::key_from_hex(&std::fs::read_to_string(&public).unwrap()).unwrap();
    std::fs::write(&elf_path, elf(&firmware(Some(INFO), &mine))).unwrap();

    let signed = lbv(&["image", "sign", &elf_path, "--key", &key, "--out", &file]);
    assert_eq!(status(&signed), Some(0), "{}", said(&signed));
    let out = said(&signed);
    assert!(out.contains("Aveox/Legacy family (0x54/0x55), version 0.7.12"), "{out}");
    assert!(out.contains("3024 bytes from 0x08002800"), "{out}");
    // Nothing set, nothing rotated: nothing more to say.
    assert_eq!(out.lines().count(), 1, "{out}");
    let bytes = std::fs::read(&file).unwrap();
    assert_eq!(bytes.len(), HEADER_LEN + 3024);

    let inspected = lbv(&["image", "inspect", &file, "--key", &public]);
    assert_eq!(status(&inspected), Some(0), "{}", said(&inspected));
    let out = said(&inspected);
    for line in [
        "update file, format 1",
        "target     thruster, Aveox/Legacy family (0x54/0x55)",
        "version    0.7.12",
        "info       format 2",
        "counter    0",
        "rollback   no",
        "payload    3024 bytes, SHA-512 ",
        "signature  verifies with",
        &format!("key        {}\n", hex(&mine)),
        "the key that signed it: the vehicle goes on taking files signed with it",
        "not signed with the development key",
    ] {
        assert!(out.contains(line), "{line:?} in {out}");
    }
    // Without a key it can only say that it is not the development key's: not verified.
    let unchecked = lbv(&["image", "inspect", &file]);
    assert_eq!(status(&unchecked), Some(1), "{}", said(&unchecked));
    assert!(said(&unchecked).contains("not the development key's"));
    // It shows the key the image embeds, but cannot say whether that is the one that signed it.
    assert!(said(&unchecked).contains(&hex(&mine)), "{}", said(&unchecked));
    assert!(!said(&unchecked).contains("signed it"), "{}", said(&unchecked));
    // The ELF itself: its info, the payload it makes, the same digest.
    let elf_inspected = lbv(&["image", "inspect", &elf_path]);
    assert_eq!(status(&elf_inspected), Some(0), "{}", said(&elf_inspected));
    let out = said(&elf_inspected);
    for line in [
        "firmware ELF",
        "version    0.7.12",
        "info       format 2",
        "counter    0",
        "rollback   no",
        &format!("key        {}\n", hex(&mine)),
        "once this image runs, the vehicle takes only files signed with this key",
    ] {
        assert!(out.contains(line), "{line:?} in {out}");
    }
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
    let (_, _, public) = keygen(&dir, "k");
    let info = ImageInfo::new(Target::Master, Version::new(1, 0, 0));
    let elf_path = write_elf(&dir, "master.elf", info, &public);
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
    std::fs::write(&elf_path, elf(&firmware(Some(INFO), &KEY))).unwrap();
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
    assert!(
        said(&inspected).contains(&format!("key        {} (the development key)", hex(&DEV_PUBLIC_KEY))),
        "{}",
        said(&inspected)
    );
    assert!(
        said(&inspected).contains("the key that signed it"),
        "{}",
        said(&inspected)
    );
}

/// The payload and image info of the update file at `path`.
fn signed(path: &str) -> (Header, Vec<u8>, ImageInfo) {
    let bytes = std::fs::read(path).unwrap();
    let header = Header::parse(&bytes).unwrap();
    let payload = bytes[HEADER_LEN..].to_vec();
    let info = ImageInfo::parse(&payload[INFO_OFFSET..]).unwrap();
    (header, payload, info)
}

#[test]
fn the_security_counter_and_the_rollback_flag_are_signed_in() {
    let dir = scratch("counter");
    let (key, public, public_key) = keygen(&dir, "k");
    // A build's counter is 0; this ELF's own is 4, to show that it stays when none is given.
    let built = INFO.with_security_counter(4);
    let elf_path = write_elf(&dir, "t.elf", built, &public_key);
    let sign = |name: &str, more: &[&str]| {
        let file = path(&dir, name);
        let mut args = vec!["image", "sign", &elf_path, "--key", &key, "--out", &file];
        args.extend_from_slice(more);
        let output = lbv(&args);
        assert_eq!(status(&output), Some(0), "{}", said(&output));
        (file, said(&output))
    };
    let inspect = |file: &str| {
        let output = lbv(&["image", "inspect", file, "--key", &public]);
        assert_eq!(status(&output), Some(0), "{}", said(&output));
        said(&output)
    };

    let (kept, out) = sign("kept.lbvu", &[]);
    assert!(out.contains("security counter 4: once it confirms"), "{out}");
    assert!(!out.contains("rollback"), "{out}");
    assert_eq!(signed(&kept).2, built);
    let out = inspect(&kept);
    assert!(
        out.contains("counter    4\n") && out.contains("rollback   no\n"),
        "{out}"
    );

    let (set, out) = sign("set.lbvu", &["--security-counter", "9", "--allow-rollback"]);
    assert!(
        out.contains("security counter 9: once it confirms, the vehicle takes no image with a lower one"),
        "{out}"
    );
    assert!(
        out.contains("signed as a rollback: the vehicle takes it over a newer version"),
        "{out}"
    );
    let (header, payload, info) = signed(&set);
    assert_eq!(info, INFO.with_security_counter(9).with_rollback(true));
    // Only the info changed, and the signature covers it.
    let mut expected = payload_from_elf(&std::fs::read(&elf_path).unwrap(), None)
        .unwrap()
        .bytes;
    expected[INFO_OFFSET..INFO_OFFSET + INFO_LEN].copy_from_slice(&info.to_bytes());
    assert_eq!(payload, expected);
    assert_eq!(update_image::verify(&header, &payload, &public_key), Ok(()));
    // What the vehicle makes of it: over a newer version, held to the counter.
    let newer = ImageInfo::new(INFO.target, Version::new(0, 8, 0)).with_security_counter(9);
    assert_eq!(check_upgrade(&info, Some(&newer), 9), Ok(()));
    assert_eq!(
        check_upgrade(&info, Some(&newer), 10),
        Err(Refusal::CounterBelow { image: 9, floor: 10 })
    );
    let out = inspect(&set);
    for line in [
        "info       format 2\n",
        "counter    9\n",
        "rollback   yes: signed to replace a newer version\n",
    ] {
        assert!(out.contains(line), "{line:?} in {out}");
    }

    // The largest counter, and 0 over the ELF's own.
    let (top, _) = sign("top.lbvu", &["--security-counter", "4294967295"]);
    assert_eq!(signed(&top).2.security_counter, u32::MAX);
    let (zero, out) = sign("zero.lbvu", &["--security-counter", "0"]);
    assert_eq!(signed(&zero).2, INFO);
    assert!(!out.contains("security counter"), "{out}");

    // The ELF says what it was built with.
    let output = lbv(&["image", "inspect", &elf_path]);
    assert_eq!(status(&output), Some(0), "{}", said(&output));
    assert!(said(&output).contains("counter    4\n"), "{}", said(&output));
}

#[test]
fn an_elf_with_another_key_is_signed_only_as_a_rotation() {
    let dir = scratch("rotate");
    let (old, old_pub, _) = keygen(&dir, "old");
    let (_, new_pub, new) = keygen(&dir, "new");
    let elf_path = write_elf(&dir, "t.elf", INFO, &new);
    let file = path(&dir, "t.lbvu");
    let sign = |elf_path: &str, more: &[&str]| {
        let mut args = vec!["image", "sign", elf_path, "--key", &old, "--out", &file];
        args.extend_from_slice(more);
        lbv(&args)
    };

    let refused = sign(&elf_path, &[]);
    assert_eq!(status(&refused), Some(2), "{}", said(&refused));
    let out = said(&refused);
    assert!(
        out.contains(&format!(
            "t.elf embeds the update key {}, not the public half of",
            hex(&new)
        )),
        "{out}"
    );
    assert!(
        out.contains("once installed, the vehicle would take only files signed with the key it embeds"),
        "{out}"
    );
    assert!(out.contains("--rotate-key"), "{out}");
    assert!(!out.contains("development key"), "{out}");
    assert!(!Path::new(&file).exists());

    let rotated = sign(&elf_path, &["--rotate-key"]);
    assert_eq!(status(&rotated), Some(0), "{}", said(&rotated));
    assert!(
        said(&rotated).contains(&format!(
            "key rotation: once this image confirms, the vehicle takes only files signed with the key it embeds, {}, \
             and no longer files signed with",
            hex(&new)
        )),
        "{}",
        said(&rotated)
    );
    // It is the old key's signature, over an image that embeds the new one.
    let inspected = lbv(&["image", "inspect", &file, "--key", &old_pub]);
    assert_eq!(status(&inspected), Some(0), "{}", said(&inspected));
    let out = said(&inspected);
    assert!(out.contains(&format!("key        {}\n", hex(&new))), "{out}");
    assert!(
        out.contains("a rotation to another key than the one that signed it: once this image confirms"),
        "{out}"
    );
    let with_new = lbv(&["image", "inspect", &file, "--key", &new_pub]);
    assert_eq!(status(&with_new), Some(1), "{}", said(&with_new));
    assert!(said(&with_new).contains("DOES NOT VERIFY"));
    assert!(!said(&with_new).contains("rotation"), "{}", said(&with_new));

    // An ELF built with the development key: said so, and a rotation to it needs --allow-dev-key too.
    let dev_elf = write_elf(&dir, "dev.elf", INFO, &DEV_PUBLIC_KEY);
    let refused = sign(&dev_elf, &[]);
    assert_eq!(status(&refused), Some(2), "{}", said(&refused));
    assert!(
        said(&refused).contains(&format!("{} (the development key)", hex(&DEV_PUBLIC_KEY))),
        "{}",
        said(&refused)
    );
    let refused = sign(&dev_elf, &["--rotate-key"]);
    assert_eq!(status(&refused), Some(2), "{}", said(&refused));
    assert!(
        said(&refused).contains("--rotate-key would move the vehicle to a key whose secret is published"),
        "{}",
        said(&refused)
    );
    let rotated = sign(&dev_elf, &["--rotate-key", "--allow-dev-key"]);
    assert_eq!(status(&rotated), Some(0), "{}", said(&rotated));
    assert!(
        said(&rotated).contains(&format!(
            "the key it embeds, {} (the development key)",
            hex(&DEV_PUBLIC_KEY)
        )),
        "{}",
        said(&rotated)
    );

    // A key no signature verifies with is refused even as a rotation: nothing could follow the image.
    let (header, payload, _) = signed(&file);
    let not_a_key = (0..=255u8)
        .map(|byte| [byte; 32])
        .find(|key| update_image::verify(&header, &payload, key) == Err(VerifyError::PublicKey))
        .unwrap();
    std::fs::remove_file(&file).unwrap();
    let broken = write_elf(&dir, "broken.elf", INFO, &not_a_key);
    let refused = sign(&broken, &["--rotate-key"]);
    assert_eq!(status(&refused), Some(2), "{}", said(&refused));
    assert!(
        said(&refused).contains(&format!(
            "embeds {} as its update key, which is not an ed25519 public key",
            hex(&not_a_key)
        )),
        "{}",
        said(&refused)
    );
    assert!(!Path::new(&file).exists());
}

#[test]
fn an_image_without_an_update_key_is_refused() {
    let dir = scratch("format1");
    let (key, public, public_key) = keygen(&dir, "k");
    let out = path(&dir, "o.lbvu");
    // Format 1: the same record but for its format byte, and no key after it (code is there).
    let mut bytes = text(3001, Some(INFO), &public_key);
    bytes[INFO_OFFSET + 4] = 1;
    bytes[KEY_OFFSET..KEY_OFFSET + 32].fill(0x5A);
    let old = path(&dir, "old.elf");
    std::fs::write(&old, elf(&[Segment::flash(BASE, bytes.clone())])).unwrap();
    let refused = lbv(&["image", "sign", &old, "--key", &key, "--out", &out]);
    assert_eq!(status(&refused), Some(2), "{}", said(&refused));
    assert!(
        said(&refused).contains("an image of info format 1 names no update key: nothing after it could be checked"),
        "{}",
        said(&refused)
    );
    assert!(!Path::new(&out).exists());
    let inspected = lbv(&["image", "inspect", &old]);
    assert_eq!(status(&inspected), Some(1), "{}", said(&inspected));
    assert!(
        said(&inspected).contains("info       format 1\n"),
        "{}",
        said(&inspected)
    );
    assert!(
        said(&inspected).contains("key        none: an image of info format 1 names no update key"),
        "{}",
        said(&inspected)
    );
    // An update file of one (update_image::sign signs any payload with an info): refused on inspection.
    let seed = update_image::key_from_hex(&std::fs::read_to_string(&key).unwrap()).unwrap();
    let file = path(&dir, "old.lbvu");
    std::fs::write(&file, update_image::sign(&bytes, &seed).unwrap()).unwrap();
    let inspected = lbv(&["image", "inspect", &file, "--key", &public]);
    assert_eq!(status(&inspected), Some(1), "{}", said(&inspected));
    assert!(
        said(&inspected).contains("refused    an image of info format 1 names no update key"),
        "{}",
        said(&inspected)
    );

    // Format 2, but the image ends inside its key.
    let short = path(&dir, "short.elf");
    let mut bytes = text(0x230, None, &public_key);
    bytes[INFO_OFFSET..INFO_OFFSET + INFO_LEN].copy_from_slice(&INFO.to_bytes());
    std::fs::write(&short, elf(&[Segment::flash(BASE, bytes)])).unwrap();
    let refused = lbv(&["image", "sign", &short, "--key", &key, "--out", &out]);
    assert_eq!(status(&refused), Some(2), "{}", said(&refused));
    assert!(
        said(&refused).contains("the image ends at 0x230, before the update key after its image info (0x220..0x240)"),
        "{}",
        said(&refused)
    );
    let inspected = lbv(&["image", "inspect", &short]);
    assert_eq!(status(&inspected), Some(1), "{}", said(&inspected));
    assert!(
        said(&inspected).contains("key        none: the image ends at 0x230"),
        "{}",
        said(&inspected)
    );
    assert!(!Path::new(&out).exists());
}

#[test]
fn sign_refuses_an_elf_without_image_info() {
    let dir = scratch("noinfo");
    let elf_path = path(&dir, "old.elf");
    std::fs::write(&elf_path, elf(&firmware(None, &KEY))).unwrap();
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
    let (key, public, public_key) = keygen(&dir, "k");
    let elf_path = write_elf(&dir, "t.elf", INFO, &public_key);
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
            vec![
                "image",
                "sign",
                &elf_path,
                "--key",
                &key,
                "--out",
                &out,
                "--security-counter",
                "4294967296",
            ],
            2,
            "\"4294967296\" is not a security counter: a whole number from 0 to 4294967295".into(),
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
                "--security-counter",
                "seven",
            ],
            2,
            "\"seven\" is not a security counter".into(),
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
                "--security-counter=-1",
            ],
            2,
            "\"-1\" is not a security counter".into(),
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
                "--security-counter",
            ],
            2,
            "--security-counter".into(),
        ),
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
    let (_, _, public) = keygen(&dir, "k");
    let elf_path = write_elf(&dir, "t.elf", INFO, &public);
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
