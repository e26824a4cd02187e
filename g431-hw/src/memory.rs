//! The STM32G431RB's memories and how an image lays itself out in them. Each firmware image's linker script
//! `memory.x` is this data printed (a [`Layout`]'s `Display`, written by the firmware crates' build scripts), and
//! [`check`] refuses a layout whose regions leave the chip's memories, overlap, or split a flash page.
//!
//! The thruster boots through an A/B bootloader (embassy-boot): [`THRUSTER_PARTITIONS`] splits the flash into the
//! bootloader, its state, the ACTIVE image and the DFU partition a new image is written to, and
//! [`check_partitions`] refuses a split embassy-boot cannot swap in.

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

/// The flash's write unit, a double word (RM0440 3.3.7: "the Flash memory is programmed 72 bits at a time", 64
/// data bits and 8 ECC bits).
pub const WRITE_UNIT: u32 = 8;

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

    /// Whether `other` lies wholly inside.
    pub const fn contains(self, other: Span) -> bool {
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
    /// Where the image stands to a bootloader.
    pub boot: Boot,
}

/// Where an image stands to a bootloader.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Boot {
    /// The chip starts it from the flash's first word: there is no bootloader.
    None,
    /// It is the bootloader of these partitions: its `memory.x` gives embassy-boot the partitions' offsets.
    Bootloader(&'static Partitions),
    /// It is the application the bootloader starts from the ACTIVE partition: its `memory.x` gives embassy-boot's
    /// updater the offsets of the state and DFU partitions, and places the image's information record
    /// ([`IMAGE_INFO_OFFSET`]).
    Application(&'static Partitions),
}

/// Where an application image keeps its information record (update-image's `ImageInfo`: target, version), from
/// the image's start: just past the vector table (16 + 102 words on the G431, RM0440 Table 97), where the update
/// tools and a thruster receiving an image look for it.
pub const IMAGE_INFO_OFFSET: u32 = 0x200;

/// The information record's size in bytes.
pub const IMAGE_INFO_SIZE: u32 = 32;

/// The flash of an A/B bootloader (embassy-boot): the bootloader, where the chip starts; its state (the swap's
/// progress, page by page); ACTIVE, the image it starts; DFU, where a new image is written and where, after the
/// swap, the previous one waits to be reverted to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Partitions {
    /// The bootloader's image.
    pub bootloader: Span,
    /// embassy-boot's state: a magic word, then the swap's progress.
    pub state: Span,
    /// The image that runs.
    pub active: Span,
    /// The image to swap in, one page larger than ACTIVE: embassy-boot's swap moves every page of ACTIVE one
    /// page up in DFU.
    pub dfu: Span,
}

impl Partitions {
    /// The flash's pages the swap moves.
    pub const fn active_pages(&self) -> u32 {
        self.active.length / PAGE
    }
}

/// Why embassy-boot could not swap with these partitions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PartitionError {
    /// The bootloader is not where the chip starts (RM0440 2.6: boot from main flash maps 0x0800_0000 at 0).
    BootloaderNotFirst,
    /// A partition does not start and end on a page boundary.
    Unaligned,
    /// Two partitions overlap, or one leaves the flash.
    Misplaced,
    /// DFU is not at least a page larger than ACTIVE.
    DfuTooSmall,
}

// embassy-boot's state holds a magic word, a progress-valid word and four words per ACTIVE page
// (`assert_partitions`). One page of state is enough for any ACTIVE this flash can hold beside its DFU: it counts
// 2 + 4 x 31 words at most, of the 256 a page holds, so no partition split here can get that wrong.
const _: () = assert!(2 + 4 * (FLASH.length / PAGE / 2) <= PAGE / WRITE_UNIT);

/// Check partitions as embassy-boot's bootloader does at every start (`assert_partitions`, where a failure is a
/// panic in the bootloader): here at build time instead.
pub const fn check_partitions(partitions: &Partitions) -> Result<(), PartitionError> {
    let Partitions {
        bootloader,
        state,
        active,
        dfu,
    } = *partitions;
    if bootloader.origin != FLASH.origin {
        return Err(PartitionError::BootloaderNotFirst);
    }
    let all = [bootloader, state, active, dfu];
    let mut rest: &[Span] = &all;
    while let [span, tail @ ..] = rest {
        let span = *span;
        if span.origin % PAGE != 0 || span.length % PAGE != 0 || span.length == 0 {
            return Err(PartitionError::Unaligned);
        }
        if !FLASH.contains(span) {
            return Err(PartitionError::Misplaced);
        }
        let mut others = tail;
        while let [other, more @ ..] = others {
            if span.overlaps(*other) {
                return Err(PartitionError::Misplaced);
            }
            others = more;
        }
        rest = tail;
    }
    if dfu.length < active.length + PAGE {
        return Err(PartitionError::DfuTooSmall);
    }
    Ok(())
}

/// The thruster's flash: an 8 KiB bootloader (embassy's STM32 bootloader builds to about 6.3 KiB), one page of
/// state (118 words of the 256 it holds), and the rest split between ACTIVE (58 KiB, 29 pages, for a
/// 32 KiB image and room to grow) and DFU (60 KiB). The thruster keeps no settings in flash.
pub const THRUSTER_PARTITIONS: Partitions = Partitions {
    bootloader: Span {
        origin: FLASH.origin,
        length: 8 * KIB,
    },
    state: Span {
        origin: FLASH.origin + 8 * KIB,
        length: 2 * KIB,
    },
    active: Span {
        origin: FLASH.origin + 10 * KIB,
        length: 58 * KIB,
    },
    dfu: Span {
        origin: FLASH.origin + 68 * KIB,
        length: 60 * KIB,
    },
};

const _: () = assert!(check_partitions(&THRUSTER_PARTITIONS).is_ok());

/// The thruster's application, linked into ACTIVE.
pub const THRUSTER: Layout = Layout {
    chip: "STM32G431RB (NUCLEO-G431RB), the thruster's application",
    regions: &[
        Region {
            name: "BOOTLOADER",
            span: THRUSTER_PARTITIONS.bootloader,
            holds: "the bootloader (thruster-boot); nothing is linked here",
        },
        Region {
            name: "BOOTLOADER_STATE",
            span: THRUSTER_PARTITIONS.state,
            holds: "the bootloader's state; nothing is linked here",
        },
        Region {
            name: "FLASH",
            span: THRUSTER_PARTITIONS.active,
            holds: "the image (the ACTIVE partition)",
        },
        Region {
            name: "DFU",
            span: THRUSTER_PARTITIONS.dfu,
            holds: "a new image, written by the running one; nothing is linked here",
        },
        Region {
            name: "RAM",
            span: RAM,
            holds: "static data and, below it (flip-link), the stack",
        },
    ],
    boot: Boot::Application(&THRUSTER_PARTITIONS),
};

/// The thruster's bootloader, linked into its partition.
pub const THRUSTER_BOOT: Layout = Layout {
    chip: "STM32G431RB (NUCLEO-G431RB), the thruster's bootloader",
    regions: &[
        Region {
            name: "FLASH",
            span: THRUSTER_PARTITIONS.bootloader,
            holds: "the bootloader",
        },
        Region {
            name: "BOOTLOADER_STATE",
            span: THRUSTER_PARTITIONS.state,
            holds: "its state: the swap's progress",
        },
        Region {
            name: "ACTIVE",
            span: THRUSTER_PARTITIONS.active,
            holds: "the image it starts",
        },
        Region {
            name: "DFU",
            span: THRUSTER_PARTITIONS.dfu,
            holds: "the image it swaps in, and after the swap the one it reverts to",
        },
        Region {
            name: "RAM",
            span: RAM,
            holds: "static data and, below it (flip-link), the stack",
        },
    ],
    boot: Boot::Bootloader(&THRUSTER_PARTITIONS),
};

/// The master: linked into the lower 112 KiB, the top 16 KiB (pages 56-63) kept for its settings, so that flashing
/// an image never erases them; all of the RAM.
pub const MASTER: Layout = Layout {
    chip: "STM32G431RB (NUCLEO-G431RB), the master",
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
    boot: Boot::None,
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

const _: () = {
    assert!(check(&MASTER).is_ok());
    assert!(check(&THRUSTER).is_ok());
    assert!(check(&THRUSTER_BOOT).is_ok());
};

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
            // The space before the colon matters: lld reads `NAME:` as one word.
            write!(f, "  {:<16} : ORIGIN = 0x{origin:08X}, LENGTH = ", region.name)?;
            if length % KIB == 0 {
                writeln!(f, "{}K", length / KIB)?;
            } else {
                writeln!(f, "{length}")?;
            }
        }
        writeln!(f, "}}")?;
        let partitions = match self.boot {
            Boot::None => return Ok(()),
            Boot::Bootloader(partitions) | Boot::Application(partitions) => partitions,
        };
        // embassy-boot finds the partitions by these symbols, as offsets from the flash's start (embassy-stm32's
        // flash driver addresses the flash by offset).
        writeln!(
            f,
            "\n/* The partitions, for embassy-boot: offsets from the start of flash. */"
        )?;
        for (name, span) in [
            ("state", partitions.state),
            ("active", partitions.active),
            ("dfu", partitions.dfu),
        ] {
            let start = span.origin - FLASH.origin;
            writeln!(f, "__bootloader_{name}_start = 0x{start:08X};")?;
            writeln!(f, "__bootloader_{name}_end = 0x{:08X};", start + span.length)?;
        }
        if let Boot::Application(_) = self.boot {
            // Placed by address and followed by .text: cortex-m-rt starts .text at `_stext` when it is given.
            writeln!(
                f,
                "\n/* The image's information record (update-image), at a fixed offset past the vector table. */\n\
                 SECTIONS\n{{\n  .image_info ORIGIN(FLASH) + 0x{IMAGE_INFO_OFFSET:X} :\n  {{\n    \
                 KEEP(*(.image_info));\n  }} > FLASH\n}} INSERT AFTER .vector_table;\n\
                 _stext = ADDR(.image_info) + SIZEOF(.image_info);\n\
                 ASSERT(SIZEOF(.image_info) == {IMAGE_INFO_SIZE}, \"the image has no information record: \
                 declare one in a .image_info static\");"
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_layout_prints_as_a_linker_script() {
        let text = MASTER.to_string();
        assert!(text.contains("\nMEMORY\n{\n"), "{text}");
        assert!(
            text.contains("  FLASH            : ORIGIN = 0x08000000, LENGTH = 112K\n"),
            "{text}"
        );
        assert!(
            text.contains("  STORAGE          : ORIGIN = 0x0801C000, LENGTH = 16K\n"),
            "{text}"
        );
        assert!(
            text.contains("  RAM              : ORIGIN = 0x20000000, LENGTH = 32K\n}\n"),
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
        Layout {
            chip: "test",
            regions,
            boot: Boot::None,
        }
    }

    const ALL_RAM: Region = region("RAM", RAM.origin, RAM.length);
    const HALF_FLASH: Region = region("FLASH", FLASH.origin, 64 * KIB);

    #[test]
    fn the_thruster_layouts_print_the_partitions_for_embassy_boot() {
        for layout in [THRUSTER, THRUSTER_BOOT] {
            let text = layout.to_string();
            for symbol in [
                "__bootloader_state_start = 0x00002000;\n",
                "__bootloader_state_end = 0x00002800;\n",
                "__bootloader_active_start = 0x00002800;\n",
                "__bootloader_active_end = 0x00011000;\n",
                "__bootloader_dfu_start = 0x00011000;\n",
                "__bootloader_dfu_end = 0x00020000;\n",
            ] {
                assert!(text.contains(symbol), "{symbol} in\n{text}");
            }
        }
        let application = THRUSTER.to_string();
        assert!(application.contains("  FLASH            : ORIGIN = 0x08002800, LENGTH = 58K\n"));
        assert!(application.contains(".image_info ORIGIN(FLASH) + 0x200 :"));
        let bootloader = THRUSTER_BOOT.to_string();
        assert!(bootloader.contains("  FLASH            : ORIGIN = 0x08000000, LENGTH = 8K\n"));
        assert!(!bootloader.contains(".image_info"));
        assert!(!MASTER.to_string().contains("__bootloader"));
    }

    const fn span(origin_kib: u32, length_kib: u32) -> Span {
        Span {
            origin: FLASH.origin + origin_kib * KIB,
            length: length_kib * KIB,
        }
    }

    #[test]
    fn partitions_embassy_boot_cannot_swap_in_are_refused() {
        let good = THRUSTER_PARTITIONS;
        assert_eq!(check_partitions(&good), Ok(()));
        let cases = [
            (
                Partitions {
                    bootloader: span(2, 6),
                    ..good
                },
                PartitionError::BootloaderNotFirst,
            ),
            (
                Partitions {
                    state: Span {
                        origin: good.state.origin,
                        length: 1024,
                    },
                    ..good
                },
                PartitionError::Unaligned,
            ),
            (
                Partitions {
                    dfu: span(66, 60),
                    ..good
                },
                PartitionError::Misplaced,
            ),
            (
                Partitions {
                    dfu: span(70, 60),
                    ..good
                },
                PartitionError::Misplaced,
            ),
            (
                Partitions {
                    dfu: span(68, 58),
                    ..good
                },
                PartitionError::DfuTooSmall,
            ),
        ];
        for (partitions, refusal) in cases {
            assert_eq!(check_partitions(&partitions), Err(refusal), "{partitions:?}");
        }
    }

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
