//! Reading text input one line at a time in bounded memory: a line costs at most its cap, however long it is,
//! and bytes that are not UTF-8 are a line's business, not the reader's.

use std::io::{self, BufRead};

/// One line as read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Line<'a> {
    /// The whole line, without its end of line (`\n` or `\r\n`).
    Whole(&'a [u8]),
    /// A line longer than the cap: its first `cap` bytes (the rest was skipped) and its full length.
    TooLong {
        /// The first bytes of the line.
        start: &'a [u8],
        /// Its length, end of line excluded.
        length: u64,
    },
}

impl<'a> Line<'a> {
    /// The bytes kept of the line.
    pub fn bytes(self) -> &'a [u8] {
        match self {
            Line::Whole(bytes) | Line::TooLong { start: bytes, .. } => bytes,
        }
    }
}

/// Reads `input` line by line, keeping at most `cap` bytes of any line.
#[derive(Debug)]
pub struct Lines<R> {
    input: R,
    cap: usize,
    line: Vec<u8>,
    number: u64,
}

impl<R: BufRead> Lines<R> {
    /// A reader that keeps at most `cap` bytes of a line.
    pub fn new(input: R, cap: usize) -> Self {
        Self {
            input,
            cap,
            line: Vec::new(),
            number: 0,
        }
    }

    /// The input.
    pub fn get_ref(&self) -> &R {
        &self.input
    }

    /// How many lines were read.
    pub fn number(&self) -> u64 {
        self.number
    }

    /// The next line and its number (from 1), `None` at the end of the input.
    pub fn next_line(&mut self) -> io::Result<Option<(u64, Line<'_>)>> {
        self.line.clear();
        let mut length = 0_u64;
        let mut last = None;
        let mut read_any = false;
        loop {
            let buffer = match self.input.fill_buf() {
                Ok(buffer) => buffer,
                Err(error) if error.kind() == io::ErrorKind::Interrupted => continue,
                Err(error) => return Err(error),
            };
            if buffer.is_empty() {
                break;
            }
            read_any = true;
            let (chunk, used, ended) = match buffer.iter().position(|&byte| byte == b'\n') {
                Some(end) => (buffer.get(..end).unwrap_or_default(), end + 1, true),
                None => (buffer, buffer.len(), false),
            };
            let room = self.cap.saturating_sub(self.line.len());
            self.line
                .extend_from_slice(chunk.get(..room.min(chunk.len())).unwrap_or_default());
            length += chunk.len() as u64;
            last = chunk.last().copied().or(last);
            self.input.consume(used);
            if ended {
                break;
            }
        }
        if !read_any {
            return Ok(None);
        }
        self.number += 1;
        // A CR at the end belongs to the end of line (CRLF files).
        if last == Some(b'\r') {
            length -= 1;
            self.line.truncate(usize::try_from(length).unwrap_or(usize::MAX));
        }
        let line = if length <= self.cap as u64 {
            Line::Whole(&self.line)
        } else {
            Line::TooLong {
                start: &self.line,
                length,
            }
        };
        Ok(Some((self.number, line)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn all(input: &[u8], cap: usize) -> Vec<(Option<Vec<u8>>, u64)> {
        // A tiny buffer, so that lines span many fills.
        let mut lines = Lines::new(io::BufReader::with_capacity(3, input), cap);
        let mut out = Vec::new();
        while let Some((number, line)) = lines.next_line().unwrap() {
            assert_eq!(number, out.len() as u64 + 1);
            out.push(match line {
                Line::Whole(bytes) => (Some(bytes.to_vec()), bytes.len() as u64),
                Line::TooLong { start, length } => {
                    assert_eq!(start.len(), cap);
                    (None, length)
                }
            });
        }
        out
    }

    #[test]
    fn lines_end_at_lf_or_crlf_or_the_end_of_input() {
        let lines = all(b"one\r\ntwo\n\nlast", 10);
        let texts: Vec<&[u8]> = lines.iter().map(|(text, _)| text.as_deref().unwrap()).collect();
        assert_eq!(texts, [&b"one"[..], b"two", b"", b"last"]);
        assert!(all(b"", 10).is_empty());
        assert_eq!(all(b"\n", 10), [(Some(Vec::new()), 0)]);
        // Not UTF-8: bytes all the same.
        assert_eq!(all(b"\xff\xfe\n", 10), [(Some(b"\xff\xfe".to_vec()), 2)]);
    }

    #[test]
    fn a_line_over_the_cap_is_cut_and_the_next_one_is_whole() {
        let lines = all(b"0123456789abc\nnext\n0123456789\n0123456789\r\n01234567890\r\n", 10);
        assert_eq!(lines[0], (None, 13));
        assert_eq!(lines[1], (Some(b"next".to_vec()), 4));
        assert_eq!(lines[2], (Some(b"0123456789".to_vec()), 10), "exactly the cap");
        assert_eq!(lines[3], (Some(b"0123456789".to_vec()), 10), "the cap and a CRLF");
        assert_eq!(lines[4], (None, 11), "one over");
    }

    #[test]
    fn a_huge_line_costs_only_the_cap() {
        let huge = io::Read::take(io::repeat(b'x'), 50_000_000);
        let mut lines = Lines::new(io::BufReader::new(huge), 100);
        let Some((1, Line::TooLong { start, length })) = lines.next_line().unwrap() else {
            panic!("cut")
        };
        assert_eq!((start.len(), length), (100, 50_000_000));
        assert!(lines.line.capacity() < 4096, "{}", lines.line.capacity());
        assert_eq!(lines.number(), 1);
        assert!(lines.next_line().unwrap().is_none());
    }
}
