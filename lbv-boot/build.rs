//! Link the bootloader against its board's memory layout (feature `thruster` or `master`), its partitions' offsets
//! for embassy-boot included (`g431_hw::link`). defmt's script is there for a build with embassy-stm32's defmt on (`stm32.rs`, `NoLog`);
//! without, it adds only the logger's two empty functions. Host builds need nothing.
fn main() -> Result<(), Box<dyn std::error::Error>> {
    g431_hw::link::link_image(env!("CARGO_PKG_NAME"))
}
