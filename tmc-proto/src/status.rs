//! The status messages, thruster -> master (IDS 8.4).

use core::fmt;

use crate::{DecodeError, Family, Faults, MAX_STATUS_LEN, Speed, checksum};

/// A status field whose byte is outside the values its encoding defines. The frame is valid (length, message
/// type and checksum check out) and its fault bits are kept; only the odd field holds no reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FieldWarning {
    /// SeaBotix SPEED byte outside 0x19..=0xE6; `speed` reads [`Speed::ZERO`] in its place.
    Speed(u8),
    /// Legacy brushed MAX POWER byte outside the SPEED range; `max_power` holds it as [`MaxPower::Raw`].
    MaxPower(u8),
}

impl fmt::Display for FieldWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            FieldWarning::Speed(byte) => write!(f, "speed byte {byte:#04x} out of range 0x19..=0xe6"),
            FieldWarning::MaxPower(byte) => write!(f, "max power byte {byte:#04x} out of range 0x19..=0xe6"),
        }
    }
}

/// A decoded status and what was odd in it.
///
/// The IDS gives MAX POWER the whole byte (0-FF) and calls a brushed controller's SPEED a PWM value, so a valid
/// frame may carry a speed byte outside the order encoding's range. Such a frame is not thrown away: its faults
/// matter more than the odd field (a lost WATER bit is a lost warning), so the status is returned with the odd
/// field neutralised and a [`FieldWarning`] naming it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Decoded<T> {
    /// The status.
    pub status: T,
    /// The field that held no valid reading, if one did not.
    pub warning: Option<FieldWarning>,
}

impl<T> Decoded<T> {
    /// A status with nothing odd in it.
    pub const fn clean(status: T) -> Self {
        Decoded { status, warning: None }
    }

    /// The same, with the status mapped.
    pub fn map<U>(self, f: impl FnOnce(T) -> U) -> Decoded<U> {
        Decoded {
            status: f(self.status),
            warning: self.warning,
        }
    }
}

/// Motor technology a controller drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MotorKind {
    /// Brushless DC motor; speeds are rpm, full scale 4500 (IDS 8.3.2).
    Brushless,
    /// Brushed DC motor; speeds are PWM values (IDS 8.3.2).
    Brushed,
}

/// SeaBotix status, 7 bytes: MT=0x53 STATUS FAULT CURRENT SPEED TEMPERATURE CSUM (IDS 8.4.2).
///
/// STATUS bits 2-3 and FAULT bits 5-7 are reserved: sent as zero, ignored on decode (IDS 8.1). This project's
/// thruster sends two of the FAULT bits ([`SeaBotixStatus::FAULT_LINK_FAILSAFE`],
/// [`SeaBotixStatus::FAULT_OVERCURRENT`]); decode still masks them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SeaBotixStatus {
    /// Software revision, STATUS bits 4-7 (0..=15; 0 is the original brushless software). Encode keeps 4 bits.
    pub revision: u8,
    /// Motor kind, STATUS bit 1: 1 brushless, 0 brushed.
    pub motor: MotorKind,
    /// Current-limited software version: true when STATUS bit 0 is 0.
    pub current_limited: bool,
    /// FAULT byte, bits 0-4.
    pub faults: Faults,
    /// CURRENT, motor current in 0.1 A.
    pub current_deciamps: u8,
    /// SPEED, actual speed in the order's encoding (brushed: the PWM value).
    pub speed: Speed,
    /// TEMPERATURE in degrees C: the motor's (brushless) or the controller's (brushed).
    pub temperature_c: u8,
}

impl SeaBotixStatus {
    /// Message length in bytes.
    pub const LEN: usize = 7;

    /// FAULT bit 5, one of the IDS's "future growth" bits (8.4.2), which this project gives to its link failsafe
    /// (docs/decisions.md D9, D19: 1 s of silence, or of refused orders only, stops the motor): set from the
    /// failsafe stopping the motor until a new order restarts it, and carried by at least one read. A master that
    /// follows IDS 8.1 ignores it; [`SeaBotixStatus::decode`] masks it like the other reserved bits (read it with
    /// [`SeaBotixStatus::link_failsafe_in`]).
    pub const FAULT_LINK_FAILSAFE: u8 = 1 << 5;

    /// FAULT bit 6, the next "future growth" bit (8.4.2), which this project gives to a sustained overcurrent: the
    /// power stage's comparator kept tripping the bridge's hardware break, so the thruster stopped driving with
    /// its outputs off until a zero order. Set while it is stopped, and carried by at least one read after the
    /// zero order. Bit 7 stays reserved. Masked by [`SeaBotixStatus::decode`] as bit 5 is (read it with
    /// [`SeaBotixStatus::overcurrent_in`]).
    pub const FAULT_OVERCURRENT: u8 = 1 << 6;

    /// The FAULT bits beyond the IDS's five that this project's thruster sends.
    pub const FAULT_EXTENSIONS: u8 = Self::FAULT_LINK_FAILSAFE | Self::FAULT_OVERCURRENT;

    /// The software revision (STATUS bits 4-7) a brushed build of this project's controller reports: 4, the
    /// number the IDS gives brushed software ("brushed DC software (revision 4)", 8.4.1), since 0 means the
    /// original brushless software (8.4.2). Brushless builds report 0 as the original does.
    pub const REVISION_BRUSHED: u8 = 4;

    /// Whether a 7-byte SeaBotix frame with a good checksum carries [`SeaBotixStatus::FAULT_LINK_FAILSAFE`];
    /// false for anything else.
    pub fn link_failsafe_in(bytes: &[u8]) -> bool {
        Self::extension_in(bytes, Self::FAULT_LINK_FAILSAFE)
    }

    /// Whether a 7-byte SeaBotix frame with a good checksum carries [`SeaBotixStatus::FAULT_OVERCURRENT`]; false
    /// for anything else.
    pub fn overcurrent_in(bytes: &[u8]) -> bool {
        Self::extension_in(bytes, Self::FAULT_OVERCURRENT)
    }

    fn extension_in(bytes: &[u8], bit: u8) -> bool {
        Self::decode(bytes).is_ok() && bytes.get(2).is_some_and(|fault| fault & bit != 0)
    }

    const STATUS_BRUSHLESS: u8 = 1 << 1;
    const STATUS_NOT_CURRENT_LIMITED: u8 = 1 << 0;

    /// Encode with MT 0x53. The revision is masked to 4 bits; reserved bits are sent as zero.
    pub fn encode(&self) -> [u8; Self::LEN] {
        let mut status = (self.revision & 0x0F) << 4;
        if self.motor == MotorKind::Brushless {
            status |= Self::STATUS_BRUSHLESS;
        }
        if !self.current_limited {
            status |= Self::STATUS_NOT_CURRENT_LIMITED;
        }
        let body = [
            Family::SeaBotix.status_type(),
            status,
            self.faults.bits(),
            self.current_deciamps,
            self.speed.to_byte(),
            self.temperature_c,
        ];
        let [b0, b1, b2, b3, b4, b5] = body;
        [b0, b1, b2, b3, b4, b5, checksum(&body)]
    }

    /// Decode. Checks, in this order: length 7, MT 0x53, CSUM; reserved bits are masked. A SPEED byte out of
    /// range gives [`FieldWarning::Speed`] and a zero `speed`; the other fields, faults included, are read.
    pub fn decode(bytes: &[u8]) -> Result<Decoded<Self>, DecodeError> {
        let [mt, status, fault, current, speed, temperature, csum] =
            <[u8; Self::LEN]>::try_from(bytes).map_err(|_| DecodeError::Length {
                expected: Self::LEN as u8,
                actual: bytes.len(),
            })?;
        check_type_and_sum(
            Family::SeaBotix,
            mt,
            &[mt, status, fault, current, speed, temperature],
            csum,
        )?;
        let (speed, warning) = match Speed::from_byte(speed) {
            Ok(speed) => (speed, None),
            Err(_) => (Speed::ZERO, Some(FieldWarning::Speed(speed))),
        };
        Ok(Decoded {
            status: SeaBotixStatus {
                revision: status >> 4,
                motor: if status & Self::STATUS_BRUSHLESS != 0 {
                    MotorKind::Brushless
                } else {
                    MotorKind::Brushed
                },
                current_limited: status & Self::STATUS_NOT_CURRENT_LIMITED == 0,
                faults: Faults::from_bits_truncate(fault),
                current_deciamps: current,
                speed,
                temperature_c: temperature,
            },
            warning,
        })
    }
}

/// Legacy controller software revision, STATUS bits 5-7 read as a 3-bit number (IDS 8.4.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LegacyRevision(u8);

impl LegacyRevision {
    /// 0: original thruster software.
    pub const ORIGINAL: Self = Self(0);
    /// 1: brushless DC software, first revision (Aveox).
    pub const AVEOX_BRUSHLESS: Self = Self(1);
    /// 2: brushed DC software, first revision (SeaBotix Legacy).
    pub const LEGACY_BRUSHED: Self = Self(2);
    /// 4: brushed DC software, revision 4.
    pub const BRUSHED_REV4: Self = Self(4);

    /// Revision of a number; `None` above 7 (3 bits).
    pub const fn new(rev: u8) -> Option<Self> {
        if rev <= 7 { Some(Self(rev)) } else { None }
    }

    /// Revision number, 0..=7.
    pub const fn number(self) -> u8 {
        self.0
    }

    /// Motor kind the revision implies: 1 brushless; 2 and 4 brushed; `None` for 0 (original) and the
    /// undefined 3, 5, 6, 7.
    pub const fn motor_kind(self) -> Option<MotorKind> {
        match self.0 {
            1 => Some(MotorKind::Brushless),
            2 | 4 => Some(MotorKind::Brushed),
            _ => None,
        }
    }
}

/// MAX POWER byte, read according to the revision's motor kind (IDS 8.4.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MaxPower {
    /// Brushless: motor current.
    Current {
        /// Motor current in 0.1 A (12 is 1.2 A).
        deciamps: u8,
    },
    /// Brushed: power set into the motor, in SPEED encoding; equals the ordered speed unless the controller
    /// reduced it.
    Power(Speed),
    /// The byte as received: a revision with no defined motor kind, or a brushed MAX POWER outside the SPEED
    /// range (decoding reports [`FieldWarning::MaxPower`] then).
    Raw(u8),
}

impl MaxPower {
    /// The MAX POWER byte as sent.
    const fn to_byte(self) -> u8 {
        match self {
            MaxPower::Current { deciamps } => deciamps,
            MaxPower::Power(speed) => speed.to_byte(),
            MaxPower::Raw(byte) => byte,
        }
    }
}

/// Legacy (Aveox / Legacy SeaBotix) status, 4 bytes: MT=0x55 STATUS MAX_POWER CSUM (IDS 8.4.1).
///
/// STATUS holds the revision in bits 5-7 and the faults in bits 0-4.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LegacyStatus {
    /// Software revision, STATUS bits 5-7.
    pub revision: LegacyRevision,
    /// Faults, STATUS bits 0-4.
    pub faults: Faults,
    /// MAX POWER.
    pub max_power: MaxPower,
}

impl LegacyStatus {
    /// Message length in bytes.
    pub const LEN: usize = 4;

    /// Encode with MT 0x55.
    ///
    /// MAX POWER is written from whichever variant `max_power` holds (current, speed byte or raw byte), even if it
    /// does not match the revision's motor kind; [`LegacyStatus::decode`] reads it back per the revision.
    pub fn encode(&self) -> [u8; Self::LEN] {
        let mt = Family::Legacy.status_type();
        let status = (self.revision.number() << 5) | self.faults.bits();
        let max_power = self.max_power.to_byte();
        [mt, status, max_power, checksum(&[mt, status, max_power])]
    }

    /// Decode. Checks, in this order: length 4, MT 0x55, CSUM. MAX POWER is read per the revision: a brushed
    /// revision's byte outside the SPEED range is kept raw with [`FieldWarning::MaxPower`]; the faults are read
    /// whatever it holds.
    pub fn decode(bytes: &[u8]) -> Result<Decoded<Self>, DecodeError> {
        let [mt, status, max_power, csum] = <[u8; Self::LEN]>::try_from(bytes).map_err(|_| DecodeError::Length {
            expected: Self::LEN as u8,
            actual: bytes.len(),
        })?;
        check_type_and_sum(Family::Legacy, mt, &[mt, status, max_power], csum)?;
        let revision = LegacyRevision(status >> 5);
        let (max_power, warning) = match revision.motor_kind() {
            Some(MotorKind::Brushless) => (MaxPower::Current { deciamps: max_power }, None),
            Some(MotorKind::Brushed) => match Speed::from_byte(max_power) {
                Ok(speed) => (MaxPower::Power(speed), None),
                Err(_) => (MaxPower::Raw(max_power), Some(FieldWarning::MaxPower(max_power))),
            },
            None => (MaxPower::Raw(max_power), None),
        };
        Ok(Decoded {
            status: LegacyStatus {
                revision,
                faults: Faults::from_bits_truncate(status),
                max_power,
            },
            warning,
        })
    }
}

/// Status of either family, for code that handles both.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Status {
    /// SeaBotix controller status (IDS 8.4.2).
    SeaBotix(SeaBotixStatus),
    /// Aveox / Legacy SeaBotix controller status (IDS 8.4.1).
    Legacy(LegacyStatus),
}

impl Status {
    /// Family whose layout this status uses.
    pub const fn family(&self) -> Family {
        match self {
            Status::SeaBotix(_) => Family::SeaBotix,
            Status::Legacy(_) => Family::Legacy,
        }
    }

    /// Reported faults.
    pub const fn faults(&self) -> Faults {
        match self {
            Status::SeaBotix(status) => status.faults,
            Status::Legacy(status) => status.faults,
        }
    }

    /// Encode in the family's layout.
    pub fn encode(&self) -> StatusFrame {
        match self {
            Status::SeaBotix(status) => StatusFrame {
                bytes: status.encode(),
                len: SeaBotixStatus::LEN as u8,
            },
            Status::Legacy(status) => {
                let [b0, b1, b2, b3] = status.encode();
                StatusFrame {
                    bytes: [b0, b1, b2, b3, 0, 0, 0],
                    len: LegacyStatus::LEN as u8,
                }
            }
        }
    }

    /// Decode a family's status layout (see [`SeaBotixStatus::decode`], [`LegacyStatus::decode`]).
    pub fn decode(family: Family, bytes: &[u8]) -> Result<Decoded<Status>, DecodeError> {
        match family {
            Family::SeaBotix => SeaBotixStatus::decode(bytes).map(|decoded| decoded.map(Status::SeaBotix)),
            Family::Legacy => LegacyStatus::decode(bytes).map(|decoded| decoded.map(Status::Legacy)),
        }
    }

    /// Decode a status read as the family's full length ([`Family::status_len`] bytes) in either of the two
    /// forms the IDS can be read to give ([`StatusForm`]): the full layout when it checks, else the implied-type
    /// form ([`Status::decode_implied`]), else the full layout's error.
    ///
    /// A damaged full frame checks as the implied-type form about once in 256 (a public SeaBotix master's noisy
    /// line gave one in 399): a receiver that knows which form a controller sends should take only that form.
    pub fn decode_either(family: Family, bytes: &[u8]) -> Result<(Decoded<Status>, StatusForm), DecodeError> {
        match Status::decode(family, bytes) {
            Ok(decoded) => Ok((decoded, StatusForm::Full)),
            Err(error) => Status::decode_implied(family, bytes)
                .map(|decoded| (decoded, StatusForm::ImpliedType))
                .map_err(|_| error),
        }
    }

    /// Decode a status read as the family's full length in the implied-type form ([`StatusForm::ImpliedType`]):
    /// the first bytes are the frame from STATUS on, checked with the family's MT implied; the last byte is
    /// whatever the controller sends when it has no more (often 0xFF). A first byte equal to the MT is refused as
    /// [`DecodeError::MessageType`] with `expected` 0 and `actual` the MT: a full frame's first byte stands where
    /// STATUS belongs.
    pub fn decode_implied(family: Family, bytes: &[u8]) -> Result<Decoded<Status>, DecodeError> {
        let len = family.status_len();
        let mt = family.status_type();
        if bytes.len() != len {
            return Err(DecodeError::Length {
                expected: len as u8,
                actual: bytes.len(),
            });
        }
        if bytes.first() == Some(&mt) {
            return Err(DecodeError::MessageType {
                expected: 0,
                actual: mt,
            });
        }
        let mut full = [mt; MAX_STATUS_LEN];
        if let (Some(rest), Some(frame)) = (full.get_mut(1..len), bytes.get(..len - 1)) {
            rest.copy_from_slice(frame);
        }
        Status::decode(family, full.get(..len).unwrap_or_default())
    }
}

/// The two forms a status comes in. IDS 8.4.2 lays the SeaBotix status out as 7 bytes with MT as word 0; IDS
/// 6.6.1 and 8.3 ("this value addresses the thruster") also read as MT being the read address byte itself, with
/// the rest following: a public SeaBotix master reads 6 bytes at 0x53. The same holds for Legacy (4 or 3 bytes).
/// The checksum is the same sum either way (the MT byte counted once).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StatusForm {
    /// MT repeated as the first byte: 7 bytes SeaBotix, 4 Legacy (what this project's thruster sends).
    Full,
    /// MT taken as the address byte: the frame starts at STATUS, 6 bytes SeaBotix, 3 Legacy.
    ImpliedType,
}

impl From<SeaBotixStatus> for Status {
    fn from(status: SeaBotixStatus) -> Status {
        Status::SeaBotix(status)
    }
}

impl From<LegacyStatus> for Status {
    fn from(status: LegacyStatus) -> Status {
        Status::Legacy(status)
    }
}

/// An encoded status of either length, ready to hand to the I2C peripheral.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StatusFrame {
    /// Message bytes; those past `len` are zero.
    bytes: [u8; MAX_STATUS_LEN],
    /// Message length: 4 or 7.
    len: u8,
}

impl StatusFrame {
    /// The frame with `bits` set in its fault field, CSUM recomputed: the SeaBotix FAULT byte takes bits 0-4 and
    /// [`SeaBotixStatus::FAULT_EXTENSIONS`], the Legacy STATUS byte bits 0-4 (its bits 5-7 are the revision);
    /// other bits are dropped. For a thruster that keeps a fault bit set until a read has carried it.
    pub fn with_fault_bits(mut self, bits: u8) -> StatusFrame {
        // The FAULT byte is word 2 of the SeaBotix layout, the STATUS byte word 1 of the Legacy one.
        let (index, mask) = if usize::from(self.len) == SeaBotixStatus::LEN {
            (2, Faults::ALL.bits() | SeaBotixStatus::FAULT_EXTENSIONS)
        } else {
            (1, Faults::ALL.bits())
        };
        let last = usize::from(self.len).saturating_sub(1);
        if let Some(field) = self.bytes.get_mut(index) {
            *field |= bits & mask;
        }
        let sum = checksum(self.bytes.get(..last).unwrap_or(&[]));
        if let Some(csum) = self.bytes.get_mut(last) {
            *csum = sum;
        }
        self
    }

    /// The message bytes, CSUM included.
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&[])
    }
}

impl AsRef<[u8]> for StatusFrame {
    fn as_ref(&self) -> &[u8] {
        self.as_bytes()
    }
}

/// MT and CSUM checks shared by the status decoders.
fn check_type_and_sum(family: Family, mt: u8, body: &[u8], csum: u8) -> Result<(), DecodeError> {
    let expected = family.status_type();
    if mt != expected {
        return Err(DecodeError::MessageType { expected, actual: mt });
    }
    let sum = checksum(body);
    if sum != csum {
        return Err(DecodeError::Checksum {
            expected: sum,
            actual: csum,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fault_bits_added_to_a_frame_keep_it_valid() {
        let seabotix = SeaBotixStatus {
            revision: SeaBotixStatus::REVISION_BRUSHED,
            motor: MotorKind::Brushed,
            current_limited: true,
            faults: Faults::WATER,
            current_deciamps: 12,
            speed: Speed::ZERO,
            temperature_c: 20,
        };
        let frame = Status::from(seabotix).encode();
        assert!(!SeaBotixStatus::link_failsafe_in(frame.as_bytes()));
        assert!(!SeaBotixStatus::overcurrent_in(frame.as_bytes()));
        let flagged = frame.with_fault_bits(Faults::HALL.bits() | SeaBotixStatus::FAULT_LINK_FAILSAFE | 0x80);
        assert_eq!(flagged.as_bytes().get(2), Some(&0x34));
        assert!(SeaBotixStatus::link_failsafe_in(flagged.as_bytes()));
        assert!(!SeaBotixStatus::overcurrent_in(flagged.as_bytes()));
        // Bit 6 alone, then with bit 5: each read on its own; bit 7 is still dropped.
        let overcurrent = frame.with_fault_bits(SeaBotixStatus::FAULT_OVERCURRENT);
        assert_eq!(overcurrent.as_bytes().get(2), Some(&0x50));
        assert!(SeaBotixStatus::overcurrent_in(overcurrent.as_bytes()));
        assert!(!SeaBotixStatus::link_failsafe_in(overcurrent.as_bytes()));
        let both = flagged.with_fault_bits(SeaBotixStatus::FAULT_OVERCURRENT);
        assert_eq!(both.as_bytes().get(2), Some(&0x74));
        assert!(SeaBotixStatus::overcurrent_in(both.as_bytes()) && SeaBotixStatus::link_failsafe_in(both.as_bytes()));
        assert_eq!(
            SeaBotixStatus::decode(both.as_bytes()).unwrap().status.faults,
            Faults::WATER | Faults::HALL,
            "the extensions are masked on decode"
        );
        // A damaged checksum carries nothing.
        let mut broken = overcurrent.as_bytes().to_vec();
        broken[6] ^= 1;
        assert!(!SeaBotixStatus::overcurrent_in(&broken));
        let decoded = SeaBotixStatus::decode(flagged.as_bytes()).unwrap();
        assert_eq!(decoded.status.faults, Faults::WATER | Faults::HALL);
        assert_eq!(decoded.status.revision, 4);
        // Legacy: the revision bits are never touched.
        let legacy = LegacyStatus {
            revision: LegacyRevision::AVEOX_BRUSHLESS,
            faults: Faults::NONE,
            max_power: MaxPower::Current { deciamps: 0 },
        };
        let flagged = Status::from(legacy).encode().with_fault_bits(0xFF);
        let decoded = LegacyStatus::decode(flagged.as_bytes()).unwrap();
        assert_eq!(decoded.status.revision, LegacyRevision::AVEOX_BRUSHLESS);
        assert_eq!(decoded.status.faults, Faults::ALL);
        assert!(!SeaBotixStatus::link_failsafe_in(flagged.as_bytes()));
        assert!(!SeaBotixStatus::overcurrent_in(flagged.as_bytes()));
    }

    #[test]
    fn legacy_revision_range() {
        assert_eq!(LegacyRevision::new(7).map(LegacyRevision::number), Some(7));
        assert_eq!(LegacyRevision::new(8), None);
        assert_eq!(LegacyRevision::new(3).and_then(LegacyRevision::motor_kind), None);
        assert_eq!(LegacyRevision::ORIGINAL.motor_kind(), None);
    }

    #[test]
    fn frame_lengths() {
        let seabotix = SeaBotixStatus {
            revision: 0,
            motor: MotorKind::Brushless,
            current_limited: true,
            faults: Faults::NONE,
            current_deciamps: 0,
            speed: Speed::ZERO,
            temperature_c: 20,
        };
        let frame = Status::from(seabotix).encode();
        assert_eq!(frame.as_bytes().len(), 7);
        assert_eq!(frame.as_bytes(), seabotix.encode());
        let legacy = LegacyStatus {
            revision: LegacyRevision::ORIGINAL,
            faults: Faults::NONE,
            max_power: MaxPower::Raw(0),
        };
        let frame = Status::from(legacy).encode();
        assert_eq!(frame.as_bytes(), [0x55, 0x00, 0x00, 0x55]);
        assert_eq!(frame.as_ref(), legacy.encode());
    }

    #[test]
    fn a_status_in_either_form_decodes_and_says_which() {
        let seabotix = Status::SeaBotix(SeaBotixStatus {
            revision: 0,
            motor: MotorKind::Brushless,
            current_limited: true,
            faults: Faults::WATER | Faults::OVERTEMP,
            current_deciamps: 37,
            speed: Speed::new(-40).unwrap(),
            temperature_c: 61,
        });
        let legacy = Status::Legacy(LegacyStatus {
            revision: LegacyRevision::AVEOX_BRUSHLESS,
            faults: Faults::STALL,
            max_power: MaxPower::Current { deciamps: 12 },
        });
        for status in [seabotix, legacy] {
            let family = status.family();
            let full = status.encode();
            let full = full.as_bytes();
            assert_eq!(
                Status::decode_either(family, full),
                Ok((Decoded { status, warning: None }, StatusForm::Full))
            );
            // The frame from STATUS on, then what a controller with no more to send puts on the line.
            for filler in [0xFF, 0x00, full[full.len() - 1]] {
                let mut implied = full[1..].to_vec();
                implied.push(filler);
                assert_eq!(
                    Status::decode_either(family, &implied),
                    Ok((Decoded { status, warning: None }, StatusForm::ImpliedType)),
                    "{family:?} filler {filler:#x}"
                );
            }
        }
    }

    #[test]
    fn a_damaged_frame_is_not_taken_for_the_other_form() {
        let status = Status::SeaBotix(SeaBotixStatus {
            revision: 0,
            motor: MotorKind::Brushless,
            current_limited: true,
            faults: Faults::NONE,
            current_deciamps: 0,
            speed: Speed::ZERO,
            temperature_c: 20,
        });
        let full = status.encode();
        let full = full.as_bytes();
        // Every single-bit flip of a full frame: refused with the full layout's error, never read as the other form.
        for byte in 0..full.len() {
            for bit in 0..8 {
                let mut damaged = full.to_vec();
                damaged[byte] ^= 1 << bit;
                let plain = Status::decode(Family::SeaBotix, &damaged);
                let either = Status::decode_either(Family::SeaBotix, &damaged);
                match plain {
                    Ok(decoded) => assert_eq!(either, Ok((decoded, StatusForm::Full))),
                    Err(error) => assert!(
                        either == Err(error) || matches!(either, Ok((_, StatusForm::ImpliedType))),
                        "{damaged:02x?}"
                    ),
                }
                if let Ok((_, StatusForm::ImpliedType)) = either {
                    // Only when the damage left the first six bytes a valid implied-type frame.
                    assert_ne!(damaged[0], 0x53);
                }
            }
        }
        // Too short or too long: the length error, whatever the bytes.
        assert!(matches!(
            Status::decode_either(Family::SeaBotix, &full[1..]),
            Err(DecodeError::Length { .. })
        ));
        assert!(matches!(
            Status::decode_either(Family::Legacy, &[0; 5]),
            Err(DecodeError::Length { .. })
        ));
        assert!(Status::decode_either(Family::Legacy, &[]).is_err());
    }
}
