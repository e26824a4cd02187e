//! An update file's header as the update server routes by it: update-image reads it ([`parse_header`]), and the
//! server keeps the fields it needs with the bytes as received ([`ImageHeader`]).

use update_image::HeaderError;

/// The update file's header (the `update-image` crate's format).
pub const HEADER_LEN: usize = update_image::HEADER_LEN;

/// What an update file's header says (the fields the server routes by; `update-image` checks the rest).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct ImageHeader {
    /// The target byte: 1 SeaBotix thruster, 2 Legacy thruster, 3 master.
    pub target: u8,
    /// The payload's length after the header.
    pub payload_len: u32,
    /// The header as received.
    pub bytes: [u8; HEADER_LEN],
}

impl ImageHeader {
    /// The whole file's length: header and payload.
    pub fn file_len(&self) -> u32 {
        self.payload_len.saturating_add(HEADER_LEN as u32)
    }
}

/// The header of an update file, as update-image reads it (magic `LBVU`, its format, a target, the reserved field
/// zero), with the fields the server routes by and its bytes as received.
pub(crate) fn parse_header(bytes: &[u8; HEADER_LEN]) -> Result<ImageHeader, HeaderError> {
    let header = update_image::Header::parse(bytes)?;
    Ok(ImageHeader {
        target: header.target.to_byte(),
        payload_len: header.payload_len,
        bytes: *bytes,
    })
}
