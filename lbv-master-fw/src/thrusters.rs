//! (being written)
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LinkHealth;
