//! What a run did: the counts behind the summary on standard error and the exit status.

use std::process::ExitCode;

use super::{MAX_INTERFACES, MAX_MESSAGES};

/// What a run did, for the summary and the exit status.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Summary {
    /// Lines read.
    pub lines: u64,
    /// BAT frames decoded.
    pub decoded: u64,
    /// Frames with a BAT ID that bat-proto rejected.
    pub decode_errors: u64,
    /// Bad lines skipped.
    pub bad: u64,
    /// candump's DROPCOUNT notes.
    pub drop_notes: u64,
    /// Frames of other IDs.
    pub other_ids: u64,
    /// Remote requests.
    pub remote: u64,
    /// CAN FD frames.
    pub fd: u64,
    /// Frames with extended IDs.
    pub extended: u64,
    /// Error frames.
    pub error_frames: u64,
    /// CAN XL frames.
    pub xl: u64,
    /// Interfaces' boards forgotten to keep at most [`MAX_INTERFACES`].
    pub forgotten: u64,
}

impl Summary {
    /// 0 when every line was good, 1 when lines were skipped or BAT frames did not decode.
    pub fn exit_code(&self) -> ExitCode {
        if self.bad == 0 && self.decode_errors == 0 {
            ExitCode::SUCCESS
        } else {
            ExitCode::FAILURE
        }
    }

    fn ignored(&self) -> u64 {
        self.other_ids + self.remote + self.fd + self.extended + self.error_frames + self.xl
    }
}

/// `n thing` or `n things`.
fn count(n: u64, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {} decoded, {} did not decode, {} ignored",
            count(self.lines, "line", "lines"),
            count(self.decoded, "BAT frame", "BAT frames"),
            self.decode_errors,
            count(self.ignored(), "other frame", "other frames"),
        )?;
        let kinds: Vec<String> = [
            (self.other_ids, "other ID", "other IDs"),
            (self.remote, "remote request", "remote requests"),
            (self.fd, "CAN FD", "CAN FD"),
            (self.extended, "extended ID", "extended IDs"),
            (self.error_frames, "error frame", "error frames"),
            (self.xl, "CAN XL", "CAN XL"),
        ]
        .into_iter()
        .filter(|(n, _, _)| *n > 0)
        .map(|(n, one, many)| count(n, one, many))
        .collect();
        if !kinds.is_empty() {
            write!(f, " ({})", kinds.join(", "))?;
        }
        write!(f, ", skipped {}", count(self.bad, "bad line", "bad lines"))?;
        if self.bad > MAX_MESSAGES {
            write!(f, " (the first {MAX_MESSAGES} shown)")?;
        }
        if self.forgotten > 0 {
            write!(
                f,
                "; BAT boards on more than {MAX_INTERFACES} interfaces: {} forgotten (a board heard again after \
                 that reports its status as at start-up)",
                self.forgotten
            )?;
        }
        if self.drop_notes > 0 {
            write!(
                f,
                "; the capture reported lost frames on {}",
                count(self.drop_notes, "line", "lines")
            )?;
        }
        Ok(())
    }
}
