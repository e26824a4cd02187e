//! Any BAT frame, dispatched on the CAN ID.

use crate::{BMS_ID, BatteryInfo, BmsAlarms, DcdcStatus, DecodeError, FRAME_LEN, INFO_ID, STATUS_ID};

/// One decoded BAT frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Frame {
    /// Battery pack info, ID 0x620.
    Info(BatteryInfo),
    /// BAT DCDC status, ID 0x629.
    Status(DcdcStatus),
    /// BMS alarms, ID 0x628.
    Bms(BmsAlarms),
}

impl Frame {
    /// The standard 11-bit CAN ID of this frame.
    pub const fn id(&self) -> u16 {
        match self {
            Self::Info(_) => INFO_ID,
            Self::Status(_) => STATUS_ID,
            Self::Bms(_) => BMS_ID,
        }
    }

    /// The CAN ID and the 8 data bytes (DLC 8) to send.
    pub fn encode(&self) -> (u16, [u8; FRAME_LEN]) {
        let data = match self {
            Self::Info(info) => info.encode(),
            Self::Status(status) => status.encode(),
            Self::Bms(alarms) => alarms.encode(),
        };
        (self.id(), data)
    }

    /// Decodes a received frame.
    ///
    /// Checks in order: an unknown ID gives [`DecodeError::UnknownId`]; a data length other than 8 gives
    /// [`DecodeError::Length`] (classic CAN: the BAT always sends DLC 8). A field out of range is the frame's to
    /// report ([`BatteryInfo::decode`]).
    pub fn decode(id: u16, data: &[u8]) -> Result<Frame, DecodeError> {
        match id {
            INFO_ID => BatteryInfo::decode(data).map(Self::Info),
            STATUS_ID => DcdcStatus::decode(data).map(Self::Status),
            BMS_ID => BmsAlarms::decode(data).map(Self::Bms),
            _ => Err(DecodeError::UnknownId(id)),
        }
    }
}

impl From<BatteryInfo> for Frame {
    fn from(info: BatteryInfo) -> Self {
        Self::Info(info)
    }
}

impl From<DcdcStatus> for Frame {
    fn from(status: DcdcStatus) -> Self {
        Self::Status(status)
    }
}

impl From<BmsAlarms> for Frame {
    fn from(alarms: BmsAlarms) -> Self {
        Self::Bms(alarms)
    }
}
