//! BAT DCDC status frame, ID 0x629, and its 12 status bits.

use core::fmt;

use crate::{DecodeError, FRAME_LEN, STATUS_ID, frame_bytes};

/// One of the 12 status bits of the combined word `(B << 8) | A` (docs/interface.md, bits 0..=11).
///
/// Bits 0-7 come from DCDC_status_A (byte 0), bits 8-11 from DCDC_status_B (byte 1). The seed says "only the
/// first 10 bits are valid" but lists 12; the firmware uses 12, so all 12 are named here (docs/decisions.md D24).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum StatusBit {
    /// Bit 0, `HSM_broken`: hot swap manager MOSFETs probably damaged (fault).
    HsmBroken = 0,
    /// Bit 1, `HSM_F`: hot swap manager overcurrent / overvoltage fault.
    HsmFault = 1,
    /// Bit 2, `HSM_PG`: hot swap manager power good (output stable).
    HsmPowerGood = 2,
    /// Bit 3, `HSM`: hot swap manager on.
    Hsm = 3,
    /// Bit 4, `V12motor_F`: 12 V motor regulator overcurrent (fault).
    V12MotorFault = 4,
    /// Bit 5, `V12motor`: 12 V motor regulator on.
    V12Motor = 5,
    /// Bit 6, `V12board_F`: 12 V board regulator overcurrent (fault).
    V12BoardFault = 6,
    /// Bit 7, `V12board`: 12 V board regulator on.
    V12Board = 7,
    /// Bit 8, `PB2_restart`: push button 2 in start-up phase.
    Pb2Restart = 8,
    /// Bit 9, `PB1_restart`: push button 1 in start-up phase.
    Pb1Restart = 9,
    /// Bit 10, `HSM_HW_F`: HSM overcurrent fault from the HSM's FLT pin.
    HsmHwFault = 10,
    /// Bit 11, `HSM_SW_F`: HSM overcurrent fault from the firmware threshold.
    HsmSwFault = 11,
}

impl StatusBit {
    /// All 12 bits, in bit order 0..=11.
    pub const ALL: [StatusBit; 12] = [
        Self::HsmBroken,
        Self::HsmFault,
        Self::HsmPowerGood,
        Self::Hsm,
        Self::V12MotorFault,
        Self::V12Motor,
        Self::V12BoardFault,
        Self::V12Board,
        Self::Pb2Restart,
        Self::Pb1Restart,
        Self::HsmHwFault,
        Self::HsmSwFault,
    ];

    /// Bit position in the combined word, 0..=11.
    pub const fn bit(self) -> u8 {
        self as u8
    }

    /// Mask of this bit in the combined word `(B << 8) | A`.
    pub const fn mask(self) -> u16 {
        1 << self.bit()
    }

    /// The seed's name of the bit, e.g. `"HSM_PG"`.
    pub const fn name(self) -> &'static str {
        match self {
            Self::HsmBroken => "HSM_broken",
            Self::HsmFault => "HSM_F",
            Self::HsmPowerGood => "HSM_PG",
            Self::Hsm => "HSM",
            Self::V12MotorFault => "V12motor_F",
            Self::V12Motor => "V12motor",
            Self::V12BoardFault => "V12board_F",
            Self::V12Board => "V12board",
            Self::Pb2Restart => "PB2_restart",
            Self::Pb1Restart => "PB1_restart",
            Self::HsmHwFault => "HSM_HW_F",
            Self::HsmSwFault => "HSM_SW_F",
        }
    }

    /// What the bit means when set (`set == true`) or clear, condensed from the table in docs/interface.md.
    pub const fn meaning(self, set: bool) -> &'static str {
        match (self, set) {
            (Self::HsmBroken, true) => "hot swap manager MOSFETs probably damaged",
            (Self::HsmFault, true) => "hot swap manager overcurrent / overvoltage fault",
            (Self::HsmPowerGood, true) => "hot swap manager power good (output stable)",
            (Self::HsmPowerGood, false) => "output voltage not guaranteed",
            (Self::Hsm, true) => "hot swap manager on",
            (Self::V12MotorFault, true) => "12 V motor regulator overcurrent",
            (Self::V12Motor, true) => "12 V motor regulator on",
            (Self::V12BoardFault, true) => "12 V board regulator overcurrent",
            (Self::V12Board, true) => "12 V board regulator on",
            (Self::Pb2Restart, true) => "push button 2 in start-up phase",
            (Self::Pb1Restart, true) => "push button 1 in start-up phase",
            (Self::HsmHwFault, true) => "HSM overcurrent fault from the HSM's FLT pin",
            (Self::HsmSwFault, true) => "HSM overcurrent fault from the firmware threshold",
            (Self::HsmBroken | Self::HsmFault | Self::V12MotorFault | Self::V12BoardFault, false) => "normal",
            (Self::Hsm | Self::V12Motor | Self::V12Board, false) => "off",
            (Self::Pb2Restart | Self::Pb1Restart, false) => "stable operation",
            (Self::HsmHwFault | Self::HsmSwFault, false) => "no fault",
        }
    }

    /// Whether a set bit signals a fault: `HSM_broken`, `HSM_F`, `V12motor_F`, `V12board_F`, `HSM_HW_F`,
    /// `HSM_SW_F`. The others report states (on / off, power good, start-up phase).
    pub const fn is_fault(self) -> bool {
        matches!(
            self,
            Self::HsmBroken
                | Self::HsmFault
                | Self::V12MotorFault
                | Self::V12BoardFault
                | Self::HsmHwFault
                | Self::HsmSwFault
        )
    }
}

/// The 12 valid bits of the combined word.
const VALID_MASK: u16 = 0x0FFF;

/// The DCDC status of the BAT board, sent on [`STATUS_ID`] (0x629).
///
/// Byte 0 is DCDC_status_A (bits 0-7 of the combined word), byte 1 is DCDC_status_B (bits 8-11); the seed's
/// table labels byte 1 "DCDC status A", which is an erratum (docs/decisions.md D25). The combined word is
/// `(B << 8) | A`, as shown on the BAT display. Bits 12-15 are unused and always masked off, so a value of this
/// type holds only the 12 defined bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DcdcStatus(u16);

impl DcdcStatus {
    /// From the combined word `(B << 8) | A`; bits 12-15 are dropped.
    pub const fn from_word(word: u16) -> Self {
        Self(word & VALID_MASK)
    }

    /// From DCDC_status_A (byte 0) and DCDC_status_B (byte 1); bits 4-7 of B are dropped.
    pub const fn from_bytes(a: u8, b: u8) -> Self {
        Self::from_word(((b as u16) << 8) | a as u16)
    }

    /// The combined word `(B << 8) | A`, 12 bits.
    pub const fn word(self) -> u16 {
        self.0
    }

    /// DCDC_status_A, bits 0-7 (byte 0 of the frame).
    pub const fn a(self) -> u8 {
        (self.0 & 0x00FF) as u8
    }

    /// DCDC_status_B, bits 8-11 (byte 1 of the frame).
    pub const fn b(self) -> u8 {
        (self.0 >> 8) as u8
    }

    /// Whether `bit` is set.
    pub const fn is_set(self, bit: StatusBit) -> bool {
        self.0 & bit.mask() != 0
    }

    /// A copy with `bit` set (`on == true`) or cleared.
    #[must_use]
    pub const fn with(self, bit: StatusBit, on: bool) -> Self {
        if on {
            Self(self.0 | bit.mask())
        } else {
            Self(self.0 & !bit.mask())
        }
    }

    /// The set bits, in bit order.
    pub fn set_bits(self) -> impl Iterator<Item = StatusBit> {
        StatusBit::ALL.into_iter().filter(move |bit| self.is_set(*bit))
    }

    /// Whether any fault bit ([`StatusBit::is_fault`]) is set, including `HSM_HW_F` and `HSM_SW_F` of byte B.
    pub fn has_fault(self) -> bool {
        self.set_bits().any(StatusBit::is_fault)
    }

    /// Start-up report: every one of the 12 bits with its state, in bit order (the seed's last paragraph: at
    /// start-up the monitor reports the initial value of every bit in words).
    pub fn describe_all(self) -> impl Iterator<Item = BitReport> {
        StatusBit::ALL.into_iter().map(move |bit| BitReport {
            bit,
            set: self.is_set(bit),
        })
    }

    /// Change report: only the bits that differ between `previous` and `self`, with their new state, in bit
    /// order (the seed's last paragraph: on each change, describe only the bits that switched). Bits 10-11 are
    /// named like the others, never reported as "no faults".
    pub fn describe_changes(self, previous: DcdcStatus) -> impl Iterator<Item = BitReport> {
        let changed = DcdcStatus(self.0 ^ previous.0);
        self.describe_all().filter(move |report| changed.is_set(report.bit))
    }

    /// Encodes the 8 data bytes of a 0x629 frame: A, B, then six zero bytes.
    pub const fn encode(self) -> [u8; FRAME_LEN] {
        [self.a(), self.b(), 0, 0, 0, 0, 0, 0]
    }

    /// Decodes the data bytes of a 0x629 frame. Errors: [`DecodeError::Length`] unless exactly 8 bytes.
    /// Bytes 2-7 and bits 12-15 of the word are ignored.
    pub fn decode(data: &[u8]) -> Result<Self, DecodeError> {
        let [a, b, ..] = frame_bytes(STATUS_ID, data)?;
        Ok(Self::from_bytes(a, b))
    }
}

/// One status bit and its state, for the start-up and change reports of [`DcdcStatus`].
///
/// Displays as `NAME=STATE (MEANING)`, where STATE is `1` or `0` and MEANING is [`StatusBit::meaning`] for that
/// state, e.g. `HSM_PG=1 (hot swap manager power good (output stable))` or `HSM_SW_F=0 (no fault)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BitReport {
    /// The bit reported.
    pub bit: StatusBit,
    /// Its state: `true` when set.
    pub set: bool,
}

impl fmt::Display for BitReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}={} ({})",
            self.bit.name(),
            u8::from(self.set),
            self.bit.meaning(self.set)
        )
    }
}
