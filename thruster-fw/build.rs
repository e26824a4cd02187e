//! Link the firmware image against its memory layout (`g431_hw::link`); host builds need nothing.
fn main() -> Result<(), Box<dyn std::error::Error>> {
    g431_hw::link::link_image(env!("CARGO_PKG_NAME"))
}
