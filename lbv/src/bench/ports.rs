//! The firmware cores' ports on lbv-sim's simulated parts: thin newtypes and constructors, here because neither
//! the port traits (the firmware crates') nor the parts (lbv-sim's) are this crate's.
//!
//! Each module names only its own firmware crate and lbv-sim, and the firmware crate's own host tests include the
//! same file by `#[path]`: they cannot take it from this crate, which depends on them (a dev-dependency on it
//! would build a second copy of the firmware crate, whose traits are not the ones under test).

pub mod master;
pub mod thruster;
