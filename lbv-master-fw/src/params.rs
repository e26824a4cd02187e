//! What the operator sets and the master keeps across power cycles: the MAVLink parameters (names, ranges,
//! defaults and values) and the signing key; together the [`Settings`].
//!
//! The failsafe parameters carry ArduSub's names, so a pilot finds them where ArduSub keeps them, and each value
//! means what it means in ArduSub: QGroundControl labels them from its ArduSub parameter descriptions (those of
//! ArduSub 3.4 for this firmware's 0.x version), and a label must tell the truth. Where ours could not do what
//! ArduSub's number says, the number is refused and the behaviour has an `LBV_` name:
//!
//! | name | meaning | values | default |
//! |---|---|---|---|
//! | `FS_GCS_ENABLE` | the operator's HEARTBEATs stop while armed | 1 warn, 2 disarm | 2 |
//! | `FS_GCS_TIMEOUT` | how long without one, s | 2.0-120.0 | 5.0 |
//! | `LBV_GCS_NEUTRAL` | with `FS_GCS_ENABLE` 1: also hold the sticks neutral until the heartbeats return | 0, 1 | 0 |
//! | `FS_PILOT_INPUT` | the operator's MANUAL_CONTROL stops while armed | 0 off, 1 neutral and warn, 2 disarm | 1 |
//! | `FS_PILOT_TIMEOUT` | how long without one, s | 0.1-3.0 | 3.0 |
//! | `SYSID_MYGCS` | the one ground station obeyed (only while disarmed) | 1-255 | 255 |
//! | `LBV_GAIN` | pilot gain, % of full speed | 1-100 | 50 |
//! | `LBV_POWER_CAP` | power cap sent in each order's INFO byte, % | 1-100 | 100 |
//! | `LBV_FRAME` | thruster layout (only while disarmed) | 4, 6 | the build's |
//! | `LBV_MTEST_MAX` | motor test throttle limit, % | 1-100 | 30 |
//! | `LBV_UPD_UNSIGNED` | field update over a link without signing (only while disarmed) | 0 refused, 1 allowed | 0 |
//! | `BTN0_FUNCTION`..`BTN15_FUNCTION` | what joystick button n does ([`ButtonFunction`]) | 0 none, 3, 4, 42, 43 | see below |
//!
//! The button functions are ArduSub's (its `BTNn_FUNCTION`, numbered as AP_JSButton numbers them), so that
//! QGroundControl's joystick setup offers them for an ArduSub vehicle; the vehicle has four: 3 arm, 4 disarm, 42
//! gain up, 43 gain down. Any other number is refused as out of range. The defaults are ArduSub's for those four on
//! a standard gamepad (button 4 disarm, 6 arm, 11 gain up, 12 gain down); ArduSub's others (modes, camera, lights,
//! shift) have nothing to act on here, and their buttons are 0.
//!
//! - `FS_PILOT_INPUT`: ArduSub's 1, labelled "Warn Only", sends its text *and* centres the sticks (ArduSub's
//!   `failsafe_pilot_input_check` calls `set_neutral_controls` for 1 and 2 alike, then disarms for 2): ours does
//!   the same, under the same numbers.
//! - `FS_PILOT_TIMEOUT`: ArduSub's range, 0.1-3.0 s. Earlier images took up to 10 s; a longer stored timeout reads
//!   as 3 s (the failsafe acts sooner, never later).
//! - `FS_GCS_ENABLE`: ArduSub's 1 (warn only) and 2 (disarm) are ours; its 0 (off), 3 (depth hold) and 4 (surface)
//!   are refused: the vehicle has no depth sensor, and the failsafe stays on. What earlier images called 3 (hold
//!   the sticks neutral, stay armed) is 1 with `LBV_GCS_NEUTRAL` 1; a stored 3 is read that way
//!   ([`crate::settings`]).
//!
//! `LBV_UPD_UNSIGNED` has no ArduPilot counterpart (ArduPilot takes MAVLink FTP from anyone): without signing,
//! anyone on the link can claim `SYSID_MYGCS`, so the update server refuses uploads, removals and the apply
//! command unless the link is signed or this is 1 ([`crate::update::Context::unsigned`]). On a link without
//! signing whoever can send can set it too: it keeps an update from happening by mistake, not from someone who
//! sets out to; signing does that.
//!
//! After these settings a ground station finds read-only stand-ins ([`STAND_INS`]): ArduSub parameters for sensors
//! and functions the vehicle does not have, which QGroundControl's setup pages read from every ArduSub vehicle; each
//! says what the vehicle has ("none", "disabled", MANUAL). [`Listed`] is either kind, in index order.
//!
//! Values are kept as integers in a parameter's own unit (the timeouts in tenths of a second) and go over MAVLink
//! as floats in the displayed unit, with their type ([`Param::param_type`]): the two timeouts REAL32, SYSID_MYGCS
//! INT16, the others INT8, an integer's float holding its value (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST).

use core::fmt;

use embassy_time::Duration;

use crate::console::signing::SigningKey;
use crate::mixer::FrameKind;

/// A parameter's name as MAVLink carries it: up to 16 ASCII bytes, NUL-padded.
pub(crate) type ParamId = [u8; 16];

/// What the ground-station heartbeat failsafe does (`FS_GCS_ENABLE` 1 and 2, as in ArduSub; `LBV_GCS_NEUTRAL`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum GcsFailsafe {
    /// Tell the pilot, keep going.
    Warn,
    /// Disarm: every thruster stops.
    Disarm,
    /// Tell the pilot and hold the sticks at neutral, stay armed; the pilot's input counts again once the
    /// heartbeats return.
    Neutral,
}

/// What the pilot-input failsafe does (`FS_PILOT_INPUT`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum PilotFailsafe {
    /// Nothing.
    Off,
    /// Neutral sticks until the next MANUAL_CONTROL.
    Neutral,
    /// Disarm.
    Disarm,
}

/// A parameter's MAVLink type (MAV_PARAM_TYPE). Integer parameters travel as MAVLink's float holding the
/// integer's value (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST), as ArduPilot and ArduSub send them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum ParamType {
    /// MAV_PARAM_TYPE_INT8 (2).
    Int8,
    /// MAV_PARAM_TYPE_INT16 (4).
    Int16,
    /// MAV_PARAM_TYPE_INT32 (6): only the read-only compass ids ([`STAND_INS`]), AP_Int32 in ArduSub.
    Int32,
    /// MAV_PARAM_TYPE_REAL32 (9).
    Real32,
}

impl ParamType {
    /// The MAV_PARAM_TYPE value.
    pub(crate) const fn mav(self) -> u8 {
        match self {
            Self::Int8 => 2,
            Self::Int16 => 4,
            Self::Int32 => 6,
            Self::Real32 => 9,
        }
    }
}

/// The MAVLink parameters, in index order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Param {
    /// `FS_GCS_ENABLE`: 1 warn (or neutral, with `LBV_GCS_NEUTRAL`), 2 disarm, as ArduSub numbers them.
    GcsFailsafe,
    /// `FS_GCS_TIMEOUT`: ground-station heartbeat timeout, 0.1 s.
    GcsTimeout,
    /// `FS_PILOT_INPUT`: [`PilotFailsafe`] 0 off, 1 neutral (ArduSub's "warn only", which centres the sticks too),
    /// 2 disarm.
    PilotFailsafe,
    /// `FS_PILOT_TIMEOUT`: pilot input timeout, 0.1 s.
    PilotTimeout,
    /// `SYSID_MYGCS`: the operator's ground station, by MAVLink system id.
    OperatorId,
    /// `LBV_GAIN`: pilot gain in % (ArduSub's JS_GAIN_DEFAULT is 50 %).
    Gain,
    /// `LBV_POWER_CAP`: the orders' INFO byte, output power cap in % (100: no cap).
    PowerCap,
    /// `LBV_FRAME`: 4 (LBV200-4) or 6 (LBV300-6).
    Frame,
    /// `LBV_MTEST_MAX`: largest motor test throttle in % (30: thrusters are tested in air).
    MotorTestMax,
    /// `LBV_UPD_UNSIGNED`: 1 lets the field update go over a link without signing (0, the default, refuses it).
    UnsignedUpdates,
    /// `BTN0_FUNCTION`..`BTN15_FUNCTION`: what joystick button n of MANUAL_CONTROL does, ArduSub's number of a
    /// [`ButtonFunction`] (0: nothing).
    Button0,
    Button1,
    Button2,
    Button3,
    Button4,
    Button5,
    Button6,
    Button7,
    Button8,
    Button9,
    Button10,
    Button11,
    Button12,
    Button13,
    Button14,
    Button15,
    /// `LBV_GCS_NEUTRAL`: 1 holds the sticks neutral while the ground station is lost and `FS_GCS_ENABLE` is 1
    /// (warn). Last, as each parameter added since the first image is: stored records keep their indexes.
    GcsNeutral,
}

/// How many parameters there are.
pub const PARAM_COUNT: usize = 27;

/// Joystick buttons with a function parameter: MANUAL_CONTROL's `buttons`, as ArduSub has them.
pub(crate) const BUTTONS: usize = 16;

/// What a joystick button does, by ArduSub's number (AP_JSButton's `button_function_t`), on the press only: a
/// button held acts once.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub(crate) enum ButtonFunction {
    /// 3: arm, as the arm command does (the same checks, the same texts).
    Arm,
    /// 4: disarm, and stop a motor test: every thruster stops. ArduSub has no other motor stop.
    Disarm,
    /// 42: `LBV_GAIN` up by [`GAIN_STEP`], to 100 at most.
    GainUp,
    /// 43: `LBV_GAIN` down by [`GAIN_STEP`], to [`GAIN_STEP`] at least.
    GainDown,
}

impl ButtonFunction {
    /// The function of ArduSub's number, `None` for 0 (nothing) and for one this vehicle has not.
    pub(crate) const fn from_ardusub(number: i32) -> Option<Self> {
        match number {
            3 => Some(Self::Arm),
            4 => Some(Self::Disarm),
            42 => Some(Self::GainUp),
            43 => Some(Self::GainDown),
            _ => None,
        }
    }
}

/// What one gain button press moves `LBV_GAIN` by, in points of %: ArduSub steps its gain between JS_GAIN_MIN and
/// JS_GAIN_MAX (25 % and 100 %, four settings); a vehicle without stabilisation wants finer steps, ten from 10 % to
/// 100 %, the default 50 % among them.
pub(crate) const GAIN_STEP: u8 = 10;

impl Param {
    /// Every parameter, in index order.
    pub const ALL: [Param; PARAM_COUNT] = [
        Self::GcsFailsafe,
        Self::GcsTimeout,
        Self::PilotFailsafe,
        Self::PilotTimeout,
        Self::OperatorId,
        Self::Gain,
        Self::PowerCap,
        Self::Frame,
        Self::MotorTestMax,
        Self::UnsignedUpdates,
        Self::Button0,
        Self::Button1,
        Self::Button2,
        Self::Button3,
        Self::Button4,
        Self::Button5,
        Self::Button6,
        Self::Button7,
        Self::Button8,
        Self::Button9,
        Self::Button10,
        Self::Button11,
        Self::Button12,
        Self::Button13,
        Self::Button14,
        Self::Button15,
        Self::GcsNeutral,
    ];

    /// The MAVLink name (at most 16 characters).
    pub const fn name(self) -> &'static str {
        match self {
            Self::GcsFailsafe => "FS_GCS_ENABLE",
            Self::GcsTimeout => "FS_GCS_TIMEOUT",
            Self::PilotFailsafe => "FS_PILOT_INPUT",
            Self::PilotTimeout => "FS_PILOT_TIMEOUT",
            Self::OperatorId => "SYSID_MYGCS",
            Self::Gain => "LBV_GAIN",
            Self::PowerCap => "LBV_POWER_CAP",
            Self::Frame => "LBV_FRAME",
            Self::MotorTestMax => "LBV_MTEST_MAX",
            Self::UnsignedUpdates => "LBV_UPD_UNSIGNED",
            Self::Button0 => "BTN0_FUNCTION",
            Self::Button1 => "BTN1_FUNCTION",
            Self::Button2 => "BTN2_FUNCTION",
            Self::Button3 => "BTN3_FUNCTION",
            Self::Button4 => "BTN4_FUNCTION",
            Self::Button5 => "BTN5_FUNCTION",
            Self::Button6 => "BTN6_FUNCTION",
            Self::Button7 => "BTN7_FUNCTION",
            Self::Button8 => "BTN8_FUNCTION",
            Self::Button9 => "BTN9_FUNCTION",
            Self::Button10 => "BTN10_FUNCTION",
            Self::Button11 => "BTN11_FUNCTION",
            Self::Button12 => "BTN12_FUNCTION",
            Self::Button13 => "BTN13_FUNCTION",
            Self::Button14 => "BTN14_FUNCTION",
            Self::Button15 => "BTN15_FUNCTION",
            Self::GcsNeutral => "LBV_GCS_NEUTRAL",
        }
    }

    /// The function parameter of joystick button `n` (0..[`BUTTONS`]).
    pub(crate) fn button(n: usize) -> Option<Param> {
        let index = u16::try_from(n).ok().filter(|_| n < BUTTONS)?;
        Self::from_index(Self::Button0.index() + index)
    }

    /// Smallest and largest value, in the parameter's own unit (`LBV_FRAME` takes only the two ends, a button
    /// function only the numbers of [`ButtonFunction`] and 0).
    pub(crate) const fn range(self) -> (i32, i32) {
        match self {
            Self::GcsFailsafe => (1, 2),
            Self::GcsTimeout => (20, 1200),
            Self::PilotFailsafe => (0, 2),
            Self::PilotTimeout => (1, 30),
            Self::OperatorId => (1, 255),
            Self::Gain | Self::PowerCap | Self::MotorTestMax => (1, 100),
            Self::Frame => (4, 6),
            Self::UnsignedUpdates | Self::GcsNeutral => (0, 1),
            // The buttons' functions: 0 to ArduSub's gain down.
            _ => (0, 43),
        }
    }

    /// Own units per displayed unit: the timeouts are kept in tenths of the seconds a ground station shows.
    pub(crate) const fn scale(self) -> i32 {
        match self {
            Self::GcsTimeout | Self::PilotTimeout => 10,
            _ => 1,
        }
    }

    /// The default value (`LBV_FRAME`'s comes from the build, see [`Params::defaults`]).
    ///
    /// The two timeouts are chosen so that a ground station's 1 Hz stream with a frame lost (2 s between two) never
    /// trips either failsafe, with a second to spare for a late frame. The pilot-input failsafe (3 s) acts before
    /// the heartbeat failsafe (5 s, ArduPilot's FS_GCS_TIMEOUT): when the link goes, the thrusters go neutral
    /// first, then the vehicle disarms.
    pub(crate) const fn default_value(self) -> i32 {
        match self {
            Self::GcsFailsafe => 2,
            Self::GcsTimeout => 50,
            Self::PilotFailsafe => 1,
            Self::PilotTimeout => 30,
            Self::OperatorId => 255,
            Self::Gain => 50,
            Self::PowerCap => 100,
            Self::Frame => 6,
            Self::MotorTestMax => 30,
            Self::UnsignedUpdates | Self::GcsNeutral => 0,
            // ArduSub's defaults for the functions the vehicle has: a gamepad's back (4) disarms, its start (6)
            // arms, the d-pad's up and down (11, 12) step the gain.
            Self::Button4 => 4,
            Self::Button6 => 3,
            Self::Button11 => 42,
            Self::Button12 => 43,
            _ => 0,
        }
    }

    /// Its MAVLink type: the timeouts are seconds with a tenth (REAL32); the others are integers, of ArduPilot's
    /// width for the ArduSub names (SYSID_MYGCS is AP_Int16, the failsafe enables and the button functions AP_Int8)
    /// and the smallest that holds the range for ours.
    pub(crate) const fn param_type(self) -> ParamType {
        match self {
            Self::GcsTimeout | Self::PilotTimeout => ParamType::Real32,
            Self::OperatorId => ParamType::Int16,
            _ => ParamType::Int8,
        }
    }

    /// Whether a PARAM_SET of MAV_PARAM_TYPE `param_type` may set it: its own type, or REAL32. With
    /// PARAM_ENCODE_C_CAST the float holds the value whatever the type says, so a REAL32 set of an integer means
    /// the same number; and it is what ArduPilot ground stations send (MAVProxy records a parameter's type only
    /// for PX4 vehicles and otherwise sends REAL32; pymavlink's param_set_send defaults to it; ArduPilot itself
    /// ignores the type). Any other type (an INT32 or UINT8 for an INT8, an integer for a REAL32) is not this
    /// parameter's encoding and is refused.
    pub(crate) const fn takes_type(self, param_type: u8) -> bool {
        param_type == self.param_type().mav() || param_type == ParamType::Real32.mav()
    }

    /// Changing it while armed would hand the vehicle to another station or remix the thrusters mid-dive; who may
    /// update is decided on the surface too.
    pub(crate) const fn only_disarmed(self) -> bool {
        matches!(self, Self::OperatorId | Self::Frame | Self::UnsignedUpdates)
    }

    /// The index in PARAM_VALUE.
    pub const fn index(self) -> u16 {
        self as u16
    }

    /// Whether it is a joystick button's function (`BTNn_FUNCTION`).
    pub(crate) const fn is_button(self) -> bool {
        Self::Button0.index() <= self.index() && self.index() <= Self::Button15.index()
    }

    /// The parameter at an index.
    pub(crate) fn from_index(index: u16) -> Option<Param> {
        Self::ALL.into_iter().find(|param| param.index() == index)
    }

    /// The NUL-padded MAVLink name.
    pub fn id(self) -> ParamId {
        Listed::Setting(self).id()
    }

    /// Whether `value` (own unit) is a valid setting.
    pub const fn accepts(self, value: i32) -> bool {
        let (min, max) = self.range();
        match self {
            Self::Frame => value == min || value == max,
            _ if self.is_button() => value == 0 || ButtonFunction::from_ardusub(value).is_some(),
            _ => min <= value && value <= max,
        }
    }

    /// A MAVLink value in the parameter's own unit: the nearest integer (half away from zero), or `None` if it is
    /// not a number, or if the parameter is an integer and the value is not a whole number (an integer sent as
    /// raw bits, MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE, reads as a tiny denormal: 2 would become 0 and
    /// turn a failsafe off). Values too large for an `i32` saturate and so stay out of range.
    pub fn from_float(self, value: f32) -> Option<i32> {
        let scaled = value * self.scale() as f32;
        if !scaled.is_finite() {
            return None;
        }
        // A float this large is a whole number; below it the cast to i32 is exact.
        let whole = scaled.abs() >= 8_388_608.0 || scaled as i32 as f32 == scaled;
        if self.param_type() != ParamType::Real32 && !whole {
            return None;
        }
        let rounded = if scaled >= 0.0 { scaled + 0.5 } else { scaled - 0.5 };
        Some(rounded as i32)
    }

    /// A value in the parameter's own unit as MAVLink carries it.
    pub fn to_float(self, value: i32) -> f32 {
        value as f32 / self.scale() as f32
    }

    /// A value in the parameter's own unit, written in the displayed unit ("120", "0.5") with integer arithmetic:
    /// formatting an `f32` would add some 10 KiB to the image.
    pub(crate) fn shown(self, value: i32) -> impl fmt::Display {
        Shown(self.scale(), value)
    }
}

/// A read-only parameter: one of ArduSub's that QGroundControl's setup pages read from every ArduSub vehicle, for a
/// sensor or a function this vehicle does not have. It holds the value by which ArduSub says "none", "disabled" or
/// what this vehicle does instead; it is not kept in flash, and a PARAM_SET of it is refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct StandIn {
    /// ArduSub's name.
    pub name: &'static str,
    /// ArduSub's type for it.
    pub param_type: ParamType,
    /// Its value (every one is a whole number, the floats' too).
    pub value: i8,
}

const fn stand_in(name: &'static str, param_type: ParamType, value: i8) -> StandIn {
    StandIn {
        name,
        param_type,
        value,
    }
}

/// The stand-ins, after the settings in index order. Why each holds its value (QGroundControl's reading of it in
/// brackets):
/// - `INS_ACCOFFS_*` 0.0: no accelerometer, so no calibration (its Sensors page says "Setup required": there is
///   nothing to calibrate, but a nonzero offset would claim a calibration);
/// - `COMPASS_DEV_ID*` 0: no compass ("Not installed"); its offsets and declination 0.0, unused;
/// - `FLTMODE1`-`6` 19: every mode slot is ArduSub's MANUAL, the one mode there is;
/// - `FS_EKF_ACTION`, `FS_TEMP_ENABLE`, `FS_PRESS_ENABLE` 0: no estimator, no internal temperature or pressure
///   sensor, so no such failsafe ("Disabled");
/// - `FS_LEAK_ENABLE` 1: a thruster that senses water stops itself (its interface's fault reaction) and the master
///   warns the pilot, no more ("Warn only");
/// - `SERVO5`-`14_FUNCTION` 0: no servo outputs ("Disabled"), so no lights or camera mount on them;
/// - `BATT_MONITOR` -1: ArduPilot has no number for the BAT board on CAN, and -1 is none of its numbers (a blank
///   label, not a wrong one); the battery itself is in BATTERY_STATUS.
pub const STAND_INS: [StandIn; 37] = {
    use ParamType::{Int8, Int16, Int32, Real32};
    [
        stand_in("INS_ACCOFFS_X", Real32, 0),
        stand_in("INS_ACCOFFS_Y", Real32, 0),
        stand_in("INS_ACCOFFS_Z", Real32, 0),
        stand_in("COMPASS_DEV_ID", Int32, 0),
        stand_in("COMPASS_DEV_ID2", Int32, 0),
        stand_in("COMPASS_DEV_ID3", Int32, 0),
        stand_in("COMPASS_OFS_X", Real32, 0),
        stand_in("COMPASS_OFS_Y", Real32, 0),
        stand_in("COMPASS_OFS_Z", Real32, 0),
        stand_in("COMPASS_OFS2_X", Real32, 0),
        stand_in("COMPASS_OFS2_Y", Real32, 0),
        stand_in("COMPASS_OFS2_Z", Real32, 0),
        stand_in("COMPASS_OFS3_X", Real32, 0),
        stand_in("COMPASS_OFS3_Y", Real32, 0),
        stand_in("COMPASS_OFS3_Z", Real32, 0),
        stand_in("COMPASS_DEC", Real32, 0),
        stand_in("FLTMODE1", Int8, 19),
        stand_in("FLTMODE2", Int8, 19),
        stand_in("FLTMODE3", Int8, 19),
        stand_in("FLTMODE4", Int8, 19),
        stand_in("FLTMODE5", Int8, 19),
        stand_in("FLTMODE6", Int8, 19),
        stand_in("FS_EKF_ACTION", Int8, 0),
        stand_in("FS_LEAK_ENABLE", Int8, 1),
        stand_in("FS_TEMP_ENABLE", Int8, 0),
        stand_in("FS_PRESS_ENABLE", Int8, 0),
        stand_in("SERVO5_FUNCTION", Int16, 0),
        stand_in("SERVO6_FUNCTION", Int16, 0),
        stand_in("SERVO7_FUNCTION", Int16, 0),
        stand_in("SERVO8_FUNCTION", Int16, 0),
        stand_in("SERVO9_FUNCTION", Int16, 0),
        stand_in("SERVO10_FUNCTION", Int16, 0),
        stand_in("SERVO11_FUNCTION", Int16, 0),
        stand_in("SERVO12_FUNCTION", Int16, 0),
        stand_in("SERVO13_FUNCTION", Int16, 0),
        stand_in("SERVO14_FUNCTION", Int16, 0),
        stand_in("BATT_MONITOR", Int8, -1),
    ]
};

/// How many parameters a ground station sees: the settings, then the stand-ins.
pub const LISTED_COUNT: usize = PARAM_COUNT + STAND_INS.len();

/// A parameter as a ground station sees it: a setting (index 0..[`PARAM_COUNT`]) or a stand-in after them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Listed {
    Setting(Param),
    StandIn { index: u16, stand_in: StandIn },
}

impl Listed {
    /// Every one, in index order.
    pub fn all() -> impl Iterator<Item = Listed> {
        let stand_ins = (PARAM_COUNT as u16..).zip(STAND_INS);
        Param::ALL
            .into_iter()
            .map(Self::Setting)
            .chain(stand_ins.map(|(index, stand_in)| Self::StandIn { index, stand_in }))
    }

    /// The one at an index.
    pub fn from_index(index: u16) -> Option<Listed> {
        let Some(n) = usize::from(index).checked_sub(PARAM_COUNT) else {
            return Param::from_index(index).map(Self::Setting);
        };
        let stand_in = *STAND_INS.get(n)?;
        Some(Self::StandIn { index, stand_in })
    }

    /// The one of a NUL-padded MAVLink name (exact, case-sensitive, as ArduPilot matches).
    pub(crate) fn from_id(id: &ParamId) -> Option<Listed> {
        let len = id.iter().position(|byte| *byte == 0).unwrap_or(id.len());
        let name = id.get(..len)?;
        Self::all().find(|listed| listed.name().as_bytes() == name)
    }

    /// The MAVLink name (at most 16 characters).
    pub fn name(self) -> &'static str {
        match self {
            Self::Setting(param) => param.name(),
            Self::StandIn { stand_in, .. } => stand_in.name,
        }
    }

    /// The NUL-padded MAVLink name.
    pub fn id(self) -> ParamId {
        let mut id = [0; 16];
        for (slot, byte) in id.iter_mut().zip(self.name().bytes()) {
            *slot = byte;
        }
        id
    }

    /// The index in PARAM_VALUE.
    pub fn index(self) -> u16 {
        match self {
            Self::Setting(param) => param.index(),
            Self::StandIn { index, .. } => index,
        }
    }

    /// Its MAVLink type.
    pub fn param_type(self) -> ParamType {
        match self {
            Self::Setting(param) => param.param_type(),
            Self::StandIn { stand_in, .. } => stand_in.param_type,
        }
    }

    /// Its value in its own unit, with `params` in force.
    pub fn value(self, params: &Params) -> i32 {
        match self {
            Self::Setting(param) => params.get(param),
            Self::StandIn { stand_in, .. } => i32::from(stand_in.value),
        }
    }

    /// A value in its own unit as MAVLink carries it.
    pub fn to_float(self, value: i32) -> f32 {
        match self {
            Self::Setting(param) => param.to_float(value),
            Self::StandIn { .. } => value as f32,
        }
    }
}

struct Shown(i32, i32);

impl fmt::Display for Shown {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let Shown(scale, value) = *self;
        let sign = if value < 0 { "-" } else { "" };
        let magnitude = value.unsigned_abs();
        let scale = scale.unsigned_abs().max(1);
        match magnitude % scale {
            0 => write!(f, "{sign}{}", magnitude / scale),
            tenths => write!(f, "{sign}{}.{tenths}", magnitude / scale),
        }
    }
}

/// Every parameter's value, each always in its range.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Params([i32; PARAM_COUNT]);

impl Params {
    /// The defaults, with the build's frame.
    pub(crate) fn defaults(frame: FrameKind) -> Self {
        let mut values = Param::ALL.map(Param::default_value);
        if let Some(slot) = values.get_mut(usize::from(Param::Frame.index())) {
            *slot = frame.thrusters() as i32;
        }
        Self(values)
    }

    /// A parameter's value, in its own unit.
    pub fn get(&self, param: Param) -> i32 {
        self.0
            .get(usize::from(param.index()))
            .copied()
            .unwrap_or(param.default_value())
    }

    /// Set a parameter; `false` (and nothing changed) if the value is not valid for it.
    pub fn set(&mut self, param: Param, value: i32) -> bool {
        match self.0.get_mut(usize::from(param.index())) {
            Some(slot) if param.accepts(value) => {
                *slot = value;
                true
            }
            _ => false,
        }
    }

    /// `FS_GCS_ENABLE` and `LBV_GCS_NEUTRAL`.
    pub(crate) fn gcs_failsafe(&self) -> GcsFailsafe {
        match (self.get(Param::GcsFailsafe), self.get(Param::GcsNeutral)) {
            (1, 1) => GcsFailsafe::Neutral,
            (1, _) => GcsFailsafe::Warn,
            _ => GcsFailsafe::Disarm,
        }
    }

    /// `FS_GCS_TIMEOUT`.
    pub fn gcs_timeout(&self) -> Duration {
        deciseconds(self.get(Param::GcsTimeout))
    }

    /// `FS_PILOT_INPUT`.
    pub(crate) fn pilot_failsafe(&self) -> PilotFailsafe {
        match self.get(Param::PilotFailsafe) {
            0 => PilotFailsafe::Off,
            2 => PilotFailsafe::Disarm,
            _ => PilotFailsafe::Neutral,
        }
    }

    /// `FS_PILOT_TIMEOUT`.
    pub(crate) fn pilot_timeout(&self) -> Duration {
        deciseconds(self.get(Param::PilotTimeout))
    }

    /// `SYSID_MYGCS`.
    pub fn operator(&self) -> u8 {
        u8::try_from(self.get(Param::OperatorId)).unwrap_or(u8::MAX)
    }

    /// `LBV_GAIN`, %.
    pub fn gain_percent(&self) -> u8 {
        self.percent(Param::Gain)
    }

    /// `LBV_POWER_CAP`, %.
    pub(crate) fn power_cap_percent(&self) -> u8 {
        self.percent(Param::PowerCap)
    }

    /// `LBV_MTEST_MAX`, %.
    pub(crate) fn motor_test_max_percent(&self) -> u8 {
        self.percent(Param::MotorTestMax)
    }

    /// `LBV_UPD_UNSIGNED`: the field update may go over a link without signing.
    pub fn unsigned_updates(&self) -> bool {
        self.get(Param::UnsignedUpdates) == 1
    }

    /// What joystick button `n` does (`BTNn_FUNCTION`); `None`: nothing, or no such button.
    pub(crate) fn button(&self, n: usize) -> Option<ButtonFunction> {
        ButtonFunction::from_ardusub(self.get(Param::button(n)?))
    }

    /// `LBV_FRAME`.
    pub(crate) fn frame(&self) -> FrameKind {
        u8::try_from(self.get(Param::Frame))
            .ok()
            .and_then(FrameKind::from_thrusters)
            .unwrap_or(FrameKind::Lbv300_6)
    }

    fn percent(&self, param: Param) -> u8 {
        u8::try_from(self.get(param)).unwrap_or(100)
    }
}

fn deciseconds(value: i32) -> Duration {
    Duration::from_millis(100 * u64::try_from(value).unwrap_or(0))
}

/// Everything the master keeps across power cycles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Settings {
    pub params: Params,
    /// The MAVLink 2 signing key; `None`: signing is off.
    pub signing: Option<SigningKey>,
}

impl Settings {
    /// Default parameters for the build's frame, signing off.
    pub fn defaults(frame: FrameKind) -> Self {
        Self {
            params: Params::defaults(frame),
            signing: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn setting(id: &ParamId) -> Option<Param> {
        match Listed::from_id(id)? {
            Listed::Setting(param) => Some(param),
            Listed::StandIn { .. } => None,
        }
    }

    fn id(name: &str) -> ParamId {
        let mut id = [0; 16];
        id[..name.len()].copy_from_slice(name.as_bytes());
        id
    }

    #[test]
    fn names_indexes_and_defaults() {
        for (n, param) in Param::ALL.into_iter().enumerate() {
            assert_eq!(usize::from(param.index()), n);
            assert_eq!(Param::from_index(param.index()), Some(param));
            assert!(param.name().len() <= 16);
            assert_eq!(setting(&param.id()), Some(param));
            assert!(param.accepts(param.default_value()), "{param:?}");
        }
        assert_eq!(Param::from_index(PARAM_COUNT as u16), None);
        assert_eq!(setting(&id("fs_gcs_enable")), None, "case-sensitive");
        assert_eq!(setting(&id("FS_GCS_ENABLEX")), None);
        assert_eq!(
            setting(b"FS_PILOT_TIMEOUT"),
            Some(Param::PilotTimeout),
            "16 bytes, no NUL"
        );
        let defaults = Params::defaults(FrameKind::Lbv200_4);
        assert_eq!(defaults.frame(), FrameKind::Lbv200_4);
        assert_eq!(defaults.gcs_failsafe(), GcsFailsafe::Disarm);
        assert_eq!(defaults.gcs_timeout(), Duration::from_secs(5));
        assert_eq!(defaults.pilot_failsafe(), PilotFailsafe::Neutral);
        assert_eq!(defaults.pilot_timeout(), Duration::from_secs(3));
        assert_eq!(defaults.operator(), 255);
        assert_eq!(
            (
                defaults.gain_percent(),
                defaults.power_cap_percent(),
                defaults.motor_test_max_percent()
            ),
            (50, 100, 30)
        );
    }

    #[test]
    fn updates_over_a_link_without_signing_are_refused_unless_allowed_while_disarmed() {
        let mut params = Params::defaults(FrameKind::Lbv300_6);
        assert_eq!(setting(&id("LBV_UPD_UNSIGNED")), Some(Param::UnsignedUpdates));
        assert!(!params.unsigned_updates(), "refused by default");
        assert!(params.set(Param::UnsignedUpdates, 1));
        assert!(params.unsigned_updates());
        assert!(!params.set(Param::UnsignedUpdates, 2));
        assert!(params.set(Param::UnsignedUpdates, 0));
        assert!(!params.unsigned_updates());
        assert!(Param::UnsignedUpdates.only_disarmed());
        assert_eq!(Param::UnsignedUpdates.param_type(), ParamType::Int8);
    }

    #[test]
    fn button_functions_are_ardusubs_numbers_of_the_four_the_vehicle_has() {
        let mut params = Params::defaults(FrameKind::Lbv300_6);
        for n in 0..BUTTONS {
            let param = Param::button(n).unwrap();
            assert_eq!(param.name(), format!("BTN{n}_FUNCTION"));
            assert!(param.is_button() && !param.only_disarmed());
        }
        assert_eq!(Param::button(BUTTONS), None);
        assert!(!Param::UnsignedUpdates.is_button());
        // ArduSub's gamepad layout, with only what the vehicle has.
        let defaults: Vec<_> = (0..BUTTONS).map(|n| params.button(n)).collect();
        let mut expected = vec![None; BUTTONS];
        expected[4] = Some(ButtonFunction::Disarm);
        expected[6] = Some(ButtonFunction::Arm);
        expected[11] = Some(ButtonFunction::GainUp);
        expected[12] = Some(ButtonFunction::GainDown);
        assert_eq!(defaults, expected);
        assert_eq!(params.button(BUTTONS), None);
        // ArduSub's other functions (1 shift, 2 arm toggle, 5 manual mode, 21 mount centre, ...) are refused.
        let taken: Vec<i32> = (-1..=120).filter(|v| Param::Button0.accepts(*v)).collect();
        assert_eq!(taken, [0, 3, 4, 42, 43]);
        assert!(params.set(Param::Button0, 42));
        assert_eq!(params.button(0), Some(ButtonFunction::GainUp));
        assert!(!params.set(Param::Button0, 2));
        assert!(params.set(Param::Button4, 0));
        assert_eq!(params.button(4), None);
    }

    #[test]
    fn the_failsafe_parameters_take_only_what_ardusub_means_by_them() {
        let mut params = Params::defaults(FrameKind::Lbv300_6);
        // FS_GCS_ENABLE: ArduSub's 1 warn only and 2 disarm; not its 0 off, 3 depth hold or 4 surface.
        let taken: Vec<i32> = (-1..=5).filter(|v| Param::GcsFailsafe.accepts(*v)).collect();
        assert_eq!(taken, [1, 2]);
        assert_eq!(params.gcs_failsafe(), GcsFailsafe::Disarm, "ArduSub's default");
        assert!(params.set(Param::GcsFailsafe, 1));
        assert_eq!(params.gcs_failsafe(), GcsFailsafe::Warn);
        // Earlier images' 3 (neutral) is 1 with LBV_GCS_NEUTRAL.
        assert_eq!(setting(&id("LBV_GCS_NEUTRAL")), Some(Param::GcsNeutral));
        assert_eq!(Param::GcsNeutral.default_value(), 0);
        assert!(!Param::GcsNeutral.is_button() && !Param::GcsNeutral.only_disarmed());
        assert!(params.set(Param::GcsNeutral, 1));
        assert!(!params.set(Param::GcsNeutral, 2));
        assert_eq!(params.gcs_failsafe(), GcsFailsafe::Neutral);
        assert!(params.set(Param::GcsFailsafe, 2));
        assert_eq!(params.gcs_failsafe(), GcsFailsafe::Disarm, "disarm wins");
        // FS_PILOT_INPUT: ArduSub's numbers, 1 ("Warn Only") centring the sticks as ArduSub's does.
        let taken: Vec<i32> = (-1..=3).filter(|v| Param::PilotFailsafe.accepts(*v)).collect();
        assert_eq!(taken, [0, 1, 2]);
        for (value, action) in [
            (0, PilotFailsafe::Off),
            (1, PilotFailsafe::Neutral),
            (2, PilotFailsafe::Disarm),
        ] {
            assert!(params.set(Param::PilotFailsafe, value));
            assert_eq!(params.pilot_failsafe(), action);
        }
        // FS_PILOT_TIMEOUT: ArduSub's 0.1-3.0 s, default 3.0 s.
        assert_eq!(Param::PilotTimeout.range(), (1, 30));
        assert_eq!(Param::PilotTimeout.from_float(0.1), Some(1));
        assert!(params.set(Param::PilotTimeout, 1));
        assert_eq!(params.pilot_timeout(), Duration::from_millis(100));
        assert!(!params.set(Param::PilotTimeout, 31));
        assert_eq!(Param::PilotTimeout.default_value(), 30);
    }

    #[test]
    fn one_lost_frame_of_a_1_hz_stream_trips_neither_failsafe_by_default() {
        let defaults = Params::defaults(FrameKind::Lbv300_6);
        // Two seconds between frames, and late by up to half a second.
        let worst_gap = Duration::from_millis(2500);
        assert!(defaults.gcs_timeout() > worst_gap);
        assert!(defaults.pilot_timeout() > worst_gap);
        assert!(
            defaults.pilot_timeout() < defaults.gcs_timeout(),
            "neutral before disarm"
        );
    }

    #[test]
    fn values_are_kept_in_range() {
        let mut params = Params::defaults(FrameKind::Lbv300_6);
        for param in Param::ALL {
            let (min, max) = param.range();
            for value in [i32::MIN, min - 1, max + 1, i32::MAX] {
                assert!(!params.set(param, value), "{param:?} {value}");
            }
            assert_eq!(params.get(param), Params::defaults(FrameKind::Lbv300_6).get(param));
            assert!(params.set(param, max));
            assert_eq!(params.get(param), max);
        }
        assert!(!params.set(Param::Frame, 5));
        assert_eq!(params.frame(), FrameKind::Lbv300_6);
        assert!(params.set(Param::Frame, 4));
        assert_eq!(params.frame(), FrameKind::Lbv200_4);
    }

    #[test]
    fn integer_parameters_take_only_whole_numbers() {
        // FS_PILOT_INPUT = 2 sent as raw bits (PX4's bytewise encoding) is a denormal, not 0.
        let bytewise = f32::from_bits(2);
        assert_eq!(Param::PilotFailsafe.from_float(bytewise), None);
        assert_eq!(Param::PilotFailsafe.from_float(2.0), Some(2));
        assert_eq!(Param::Gain.from_float(79.5), None);
        assert_eq!(Param::OperatorId.from_float(-0.0), Some(0));
        assert_eq!(Param::OperatorId.from_float(3e9), Some(i32::MAX), "still saturates");
        assert!(Param::PilotFailsafe.takes_type(2) && Param::PilotFailsafe.takes_type(9));
        for other in [0, 1, 3, 4, 6, 10, 255] {
            assert!(!Param::PilotFailsafe.takes_type(other), "{other}");
        }
        assert!(Param::OperatorId.takes_type(4) && !Param::OperatorId.takes_type(2));
        assert!(Param::GcsTimeout.takes_type(9) && !Param::GcsTimeout.takes_type(2));
        // Seconds with a tenth still round.
        assert_eq!(Param::GcsTimeout.from_float(f32::from_bits(2)), Some(0));
        let types = Param::ALL.map(Param::param_type);
        assert_eq!(
            types[..10],
            [
                ParamType::Int8,
                ParamType::Real32,
                ParamType::Int8,
                ParamType::Real32,
                ParamType::Int16,
                ParamType::Int8,
                ParamType::Int8,
                ParamType::Int8,
                ParamType::Int8,
                ParamType::Int8
            ]
        );
        assert_eq!(
            types[10..10 + BUTTONS],
            [ParamType::Int8; BUTTONS],
            "the buttons, AP_Int8 as in ArduSub"
        );
        assert_eq!(types[10 + BUTTONS..], [ParamType::Int8], "LBV_GCS_NEUTRAL");
        for param in Param::ALL {
            let (min, max) = param.range();
            let fits = match param.param_type() {
                ParamType::Int8 => i32::from(i8::MIN) <= min && max <= i32::from(i8::MAX),
                ParamType::Int16 => i32::from(i16::MIN) <= min && max <= i32::from(i16::MAX),
                ParamType::Int32 | ParamType::Real32 => true,
            };
            assert!(fits, "{param:?}");
        }
    }

    #[test]
    fn the_stand_ins_follow_the_settings_and_say_absent_disabled_or_manual() {
        let params = Params::defaults(FrameKind::Lbv300_6);
        let all: Vec<Listed> = Listed::all().collect();
        assert_eq!(all.len(), LISTED_COUNT);
        for (n, listed) in all.iter().enumerate() {
            assert_eq!(usize::from(listed.index()), n);
            assert_eq!(Listed::from_index(n as u16), Some(*listed));
            assert_eq!(Listed::from_id(&listed.id()), Some(*listed), "names are unique");
            assert!(listed.name().len() <= 16);
            assert_eq!(matches!(listed, Listed::Setting(_)), n < PARAM_COUNT);
        }
        assert_eq!(Listed::from_index(LISTED_COUNT as u16), None);
        let value = |name: &str| {
            let listed = Listed::from_id(&id(name)).unwrap();
            assert!(matches!(listed, Listed::StandIn { .. }), "{name}");
            (listed.to_float(listed.value(&params)), listed.param_type())
        };
        // What QGroundControl's sensors check reads: no accelerometer calibration is claimed, no compass is there.
        for axis in ["X", "Y", "Z"] {
            assert_eq!(value(&format!("INS_ACCOFFS_{axis}")), (0.0, ParamType::Real32));
            for compass in ["", "2", "3"] {
                assert_eq!(value(&format!("COMPASS_OFS{compass}_{axis}")), (0.0, ParamType::Real32));
            }
        }
        for id in ["COMPASS_DEV_ID", "COMPASS_DEV_ID2", "COMPASS_DEV_ID3"] {
            assert_eq!(value(id), (0.0, ParamType::Int32), "AP_Int32, 0: no compass");
        }
        assert_eq!(value("COMPASS_DEC"), (0.0, ParamType::Real32));
        // Every mode slot is MANUAL (ArduSub's 19), the one mode there is.
        for n in 1..=6 {
            assert_eq!(value(&format!("FLTMODE{n}")), (19.0, ParamType::Int8));
        }
        // No estimator, no internal temperature or pressure sensor; a thruster's water is warned of.
        assert_eq!(value("FS_EKF_ACTION"), (0.0, ParamType::Int8));
        assert_eq!(value("FS_TEMP_ENABLE"), (0.0, ParamType::Int8));
        assert_eq!(value("FS_PRESS_ENABLE"), (0.0, ParamType::Int8));
        assert_eq!(value("FS_LEAK_ENABLE"), (1.0, ParamType::Int8), "warn only");
        for n in 5..=14 {
            assert_eq!(value(&format!("SERVO{n}_FUNCTION")), (0.0, ParamType::Int16));
        }
        assert_eq!(
            value("BATT_MONITOR"),
            (-1.0, ParamType::Int8),
            "none of ArduPilot's numbers"
        );
        assert_eq!(setting(&id("INS_ACCOFFS_X")), None, "not a setting");
    }

    #[test]
    fn floats_in_the_displayed_unit() {
        let t = Param::GcsTimeout;
        assert_eq!(t.from_float(3.3), Some(33));
        assert_eq!(t.from_float(2.96), Some(30));
        assert_eq!(t.to_float(33), 3.3);
        assert_eq!(Param::Gain.from_float(79.0), Some(79));
        assert_eq!(Param::Gain.from_float(-80.0), Some(-80));
        assert_eq!(Param::Gain.from_float(f32::NAN), None);
        assert_eq!(Param::Gain.from_float(f32::INFINITY), None);
        assert_eq!(t.from_float(1e30), Some(i32::MAX), "saturates, so stays out of range");
        assert_eq!(format!("{}", t.shown(5)), "0.5");
        assert_eq!(format!("{}", t.shown(1200)), "120");
        assert_eq!(format!("{}", t.shown(-33)), "-3.3");
        assert_eq!(format!("{}", Param::Gain.shown(100)), "100");
        for param in Param::ALL {
            let (min, max) = param.range();
            for value in [min, max, param.default_value()] {
                assert_eq!(param.from_float(param.to_float(value)), Some(value), "{param:?}");
            }
        }
    }
}
