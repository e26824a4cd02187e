//! The STM32G431RB's memories and how an image lays itself out in them. Each firmware image's linker script
//! `memory.x` is this data printed (a [`Layout`]'s `Display`, written by the firmware crates' build scripts), and
//! [`check`] refuses a layout whose regions leave the chip's memories, overlap, or split a flash page.

use core::fmt;

use crate::pins::same;

/// One KiB.
pub const KIB: u32 = 1024;

/// The main flash: 128 KiB from 0x0800_0000 in one bank (RM0440 3.3.1, Table 8: category 2 devices).
pub const FLASH: Span = Span {
    origin: 0x0800_0000,
    length: 128 * KIB,
};

/// A flash page, the unit of erase (RM0440 3.3.1: 2 KiB pages in the category 2 devices' single bank).
pub const PAGE: u32 = 2 * KIB;

/// The RAM the linker sees as one: SRAM1 (16 KiB) + SRAM2 (6 KiB) + CCM SRAM's data-bus alias (10 KiB), back to
/// back from 0x2000_0000 (RM0440 2.4 and Table 4, the G431's memory map).
pub const RAM: Span = Span {
    origin: 0x2000_0000,
    length: 32 * KIB,
};

/// An address range.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Span {
    /// The first address.
    pub origin: u32,
    /// In bytes.
    pub length: u32,
}

impl Span {
    /// One past the last address.
    pub const fn end(self) -> u32 {
        self.origin + self.length
    }

    const fn contains(self, other: Span) -> bool {
        self.origin <= other.origin && other.end() <= self.end()
    }

    const fn overlaps(self, other: Span) -> bool {
        self.origin < other.end() && other.origin < self.end()
    }
}

/// A region of a linker script's MEMORY block.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Region {
    /// Its name in `memory.x`: cortex-m-rt links code into `FLASH` and data into `RAM`.
    pub name: &'static str,
    /// Where it is.
    pub span: Span,
    /// What it holds, for the generated file's comment.
    pub holds: &'static str,
}

/// An image's memory layout.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    /// The board it is for, for the generated file's comment.
    pub chip: &'static str,
    /// Every region, flash first.
    pub regions: &'static [Region],
}

/// Both images today: linked into the lower 112 KiB, the top 16 KiB (pages 56-63) kept for the master's settings,
/// so that flashing an image never erases them (the thruster leaves them unused); all of the RAM.
pub const G431RB: Layout = Layout {
    chip: "STM32G431RB (NUCLEO-G431RB)",
    regions: &[
        Region {
            name: "FLASH",
            span: Span {
                origin: FLASH.origin,
                length: 112 * KIB,
            },
            holds: "the image",
        },
        Region {
            name: "STORAGE",
            span: Span {
                origin: FLASH.origin + 112 * KIB,
                length: 16 * KIB,
            },
            holds: "the master's settings (lbv-master-fw/src/settings.rs); nothing is linked here",
        },
        Region {
            name: "RAM",
            span: RAM,
            holds: "static data and, below it (flip-link), the stack",
        },
    ],
};

/// Why a layout does not fit the chip.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LayoutError {
    /// The region is neither inside the flash nor inside the RAM.
    Outside(&'static str),
    /// The flash region does not start and end on a page boundary.
    Unaligned(&'static str),
    /// The two regions overlap.
    Overlap(&'static str, &'static str),
    /// No region of this name, which cortex-m-rt needs.
    Missing(&'static str),
}

impl Layout {
    /// The region called `name`.
    pub const fn region(&self, name: &str) -> Option<Region> {
        let mut rest = self.regions;
        while let [region, tail @ ..] = rest {
            if same(region.name, name) {
                return Some(*region);
            }
            rest = tail;
        }
        None
    }
}

/// Check a layout: every region inside the flash (whole pages) or the RAM, no two overlapping, and the `FLASH` and
/// `RAM` regions cortex-m-rt links into present. A `const fn`, so the tables here are checked at build time.
pub const fn check(layout: &Layout) -> Result<(), LayoutError> {
    let mut rest = layout.regions;
    while let [region, tail @ ..] = rest {
        let span = region.span;
        if FLASH.contains(span) {
            if span.origin % PAGE != 0 || span.length % PAGE != 0 {
                return Err(LayoutError::Unaligned(region.name));
            }
        } else if !RAM.contains(span) {
            return Err(LayoutError::Outside(region.name));
        }
        let mut others = tail;
        while let [other, more @ ..] = others {
            if span.overlaps(other.span) {
                return Err(LayoutError::Overlap(region.name, other.name));
            }
            others = more;
        }
        rest = tail;
    }
    if layout.region("FLASH").is_none() {
        return Err(LayoutError::Missing("FLASH"));
    }
    if layout.region("RAM").is_none() {
        return Err(LayoutError::Missing("RAM"));
    }
    Ok(())
}

const _: () = assert!(check(&G431RB).is_ok());

/// The layout as a linker script's MEMORY block: the image's `memory.x`.
impl fmt::Display for Layout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "/* {}: generated from g431_hw::memory; do not edit.", self.chip)?;
        for region in self.regions {
            writeln!(f, "   {}: {}", region.name, region.holds)?;
        }
        writeln!(f, "*/\nMEMORY\n{{")?;
        for region in self.regions {
            let Span { origin, length } = region.span;
            write!(f, "  {:<8}: ORIGIN = 0x{origin:08X}, LENGTH = ", region.name)?;
            if length % KIB == 0 {
                writeln!(f, "{}K", length / KIB)?;
            } else {
                writeln!(f, "{length}")?;
            }
        }
        writeln!(f, "}}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_layout_prints_as_a_linker_script() {
        let text = G431RB.to_string();
        assert!(text.contains("\nMEMORY\n{\n"), "{text}");
        assert!(
            text.contains("  FLASH   : ORIGIN = 0x08000000, LENGTH = 112K\n"),
            "{text}"
        );
        assert!(
            text.contains("  STORAGE : ORIGIN = 0x0801C000, LENGTH = 16K\n"),
            "{text}"
        );
        assert!(
            text.contains("  RAM     : ORIGIN = 0x20000000, LENGTH = 32K\n}\n"),
            "{text}"
        );
    }

    const fn region(name: &'static str, origin: u32, length: u32) -> Region {
        Region {
            name,
            span: Span { origin, length },
            holds: "",
        }
    }

    const fn layout(regions: &'static [Region]) -> Layout {
        Layout { chip: "test", regions }
    }

    const ALL_RAM: Region = region("RAM", RAM.origin, RAM.length);
    const HALF_FLASH: Region = region("FLASH", FLASH.origin, 64 * KIB);

    #[test]
    fn a_bad_layout_is_refused() {
        const OVERLAP: Layout = layout(&[HALF_FLASH, region("DFU", FLASH.origin + 62 * KIB, 4 * KIB), ALL_RAM]);
        assert_eq!(check(&OVERLAP), Err(LayoutError::Overlap("FLASH", "DFU")));
        const UNALIGNED: Layout = layout(&[region("FLASH", FLASH.origin, 63 * KIB), ALL_RAM]);
        assert_eq!(check(&UNALIGNED), Err(LayoutError::Unaligned("FLASH")));
        const OUTSIDE: Layout = layout(&[region("FLASH", FLASH.origin, 130 * KIB), ALL_RAM]);
        assert_eq!(check(&OUTSIDE), Err(LayoutError::Outside("FLASH")));
        const TOO_MUCH_RAM: Layout = layout(&[HALF_FLASH, region("RAM", RAM.origin, 33 * KIB)]);
        assert_eq!(check(&TOO_MUCH_RAM), Err(LayoutError::Outside("RAM")));
        const NO_FLASH: Layout = layout(&[ALL_RAM]);
        assert_eq!(check(&NO_FLASH), Err(LayoutError::Missing("FLASH")));
        const FITS: Layout = layout(&[HALF_FLASH, region("DFU", FLASH.origin + 64 * KIB, 4 * KIB), ALL_RAM]);
        assert_eq!(check(&FITS), Ok(()));
    }
}
