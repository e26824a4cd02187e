//! A file made again at each read: the writer that keeps the bytes the read asks for.

use core::fmt;

/// A writer that keeps the bytes from `skip` on that fit `into`, and counts every byte.
pub(crate) struct Window<'a> {
    skip: u32,
    into: &'a mut [u8],
    /// Bytes kept.
    pub(crate) filled: usize,
    /// Bytes written, kept or not.
    pub(crate) total: u32,
}

impl<'a> Window<'a> {
    pub(crate) fn new(skip: u32, into: &'a mut [u8]) -> Self {
        Self {
            skip,
            into,
            filled: 0,
            total: 0,
        }
    }

    pub(crate) fn put(&mut self, bytes: &[u8]) {
        for byte in bytes {
            if self.total >= self.skip
                && let Some(slot) = self.into.get_mut(self.filled)
            {
                *slot = *byte;
                self.filled += 1;
            }
            self.total = self.total.saturating_add(1);
        }
    }

    /// The bytes it can keep.
    pub(crate) fn capacity(&self) -> usize {
        self.into.len()
    }

    pub(crate) fn zeros(&mut self, n: u32) {
        for _ in 0..n {
            self.put(&[0]);
        }
    }
}

impl fmt::Write for Window<'_> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        self.put(s.as_bytes());
        Ok(())
    }
}
