//! The two chips' memories and how an image lays itself out in them: the thruster's STM32G431RB and the master's
//! STM32G474RE. Each firmware image's linker script `memory.x` is this data printed (a [`Layout`]'s `Display`,
//! written by the firmware crates' build scripts), and [`check`] refuses a layout whose regions leave its chip's
//! memories, overlap, or split a flash page.
//!
//! Both boot through an A/B bootloader (embassy-boot): [`THRUSTER_PARTITIONS`] and [`MASTER_PARTITIONS`] split the
//! flash into the bootloader, its state, the ACTIVE image and the DFU partition a new image is written to, and
//! [`check_partitions`] refuses a split embassy-boot cannot swap in.

use core::fmt;

use crate::pins::same;

/// One KiB.
pub const KIB: u32 = 1024;

/// Where the main flash starts on every STM32G4 (RM0440 2.4, Table 4), and where embassy-stm32's flash driver and
/// embassy-boot count their offsets from.
pub const FLASH_ORIGIN: u32 = 0x0800_0000;

/// A flash page, the unit of erase: 2 KiB in the G431's single bank and in each of the G474's two banks in its
/// dual-bank mode (RM0440 3.3.1, Tables 7 and 8).
pub const PAGE: u32 = 2 * KIB;

/// The flash's write unit, a double word (RM0440 3.3.7: "the Flash memory is programmed 72 bits at a time", 64
/// data bits and 8 ECC bits).
pub const WRITE_UNIT: u32 = 8;

/// A chip's memories, as an image's linker script sees them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Chip {
    /// Its part number, for the generated file's comment and probe-rs.
    pub part: &'static str,
    /// The main flash.
    pub flash: Span,
    /// The RAM the linker sees as one.
    pub ram: Span,
}

/// The thruster's chip (NUCLEO-G431RB): 128 KiB of flash in one bank (RM0440 3.3.1, Table 8: category 2 devices);
/// SRAM1 (16 KiB) + SRAM2 (6 KiB) + CCM SRAM's data-bus alias (10 KiB), back to back from 0x2000_0000 (RM0440 2.4
/// and Table 4, the G431's memory map).
pub const G431RB: Chip = Chip {
    part: "STM32G431RB",
    flash: Span {
        origin: FLASH_ORIGIN,
        length: 128 * KIB,
    },
    ram: Span {
        origin: 0x2000_0000,
        length: 32 * KIB,
    },
};

/// The master's chip (NUCLEO-G474RE): 512 KiB of flash, two banks of 256 KiB with 2 KiB pages in dual-bank mode
/// (DBANK = 1, the factory setting; RM0440 3.3.1, Table 7: category 3 devices), bank 2 from 0x0804_0000; SRAM1
/// (80 KiB) + SRAM2 (16 KiB) + CCM SRAM's data-bus alias (32 KiB), back to back from 0x2000_0000 (RM0440 2.4 and
/// Table 3, the 128 KiB devices' memory map).
pub const G474RE: Chip = Chip {
    part: "STM32G474RE",
    flash: Span {
        origin: FLASH_ORIGIN,
        length: 512 * KIB,
    },
    ram: Span {
        origin: 0x2000_0000,
        length: 128 * KIB,
    },
};

/// Where the G474's second flash bank starts in dual-bank mode (RM0440 3.3.1, Table 7).
pub const G474_BANK2: u32 = FLASH_ORIGIN + 256 * KIB;

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
    /// The image it is for, for the generated file's comment.
    pub image: &'static str,
    /// The chip it is linked for.
    pub chip: &'static Chip,
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

/// The post-mortem record's region (`crash_record::Region`: the record, then the ring of the last events) at the
/// very bottom of RAM, on either chip. That is SRAM1, which has no parity to trip on what a power-on leaves there
/// (RM0440 2.4: SRAM2 and CCM SRAM have parity) and keeps its content over a system reset (RM0440 2.3.1). Nothing
/// is linked there and neither the start-up code nor a bootloader writes there: with flip-link the stack grows down
/// from below the statics at the top of RAM, and reaches it only after using all but its last bytes, which every
/// image's stack budget keeps it far from (`images`). The `RAM` region still begins there, so flip-link's guard, a
/// fault at the bottom of RAM, stays where it was.
pub const CRASH: Span = Span {
    origin: 0x2000_0000,
    length: 192,
};

/// The master's black box (lbv-master-fw's `blackbox`: the vehicle's last minutes, which a warm reset keeps), just
/// above [`CRASH`], on the G474 only: 64 KiB of SRAM1 (80 KiB from the bottom of RAM, RM0440 2.4), linked to nothing
/// and written by nothing else, as [`CRASH`] is. The stack grows down towards it: the master's static RAM and stack
/// budgets leave room below them for both regions (`images`, which checks it).
pub const BLACK_BOX: Span = Span {
    origin: CRASH.origin + CRASH.length,
    length: 64 * KIB,
};

/// Where an application image keeps its information record (update-image's `ImageInfo`: target, version), from
/// the image's start: just past the vector table (16 + 102 words on the G431, RM0440 Table 97), where the update
/// tools and a thruster receiving an image look for it.
pub const IMAGE_INFO_OFFSET: u32 = 0x200;

/// The size of the information record and the update key after it (update-image's `IMAGE_RECORD_LEN`), in bytes.
pub const IMAGE_INFO_SIZE: u32 = 64;

/// The flash of an A/B bootloader (embassy-boot): the bootloader, where the chip starts; its state (the swap's
/// progress, page by page); its record (what lbv-boot keeps beside embassy-boot's state); ACTIVE, the image it
/// starts; DFU, where a new image is written and where, after the swap, the previous one waits to be reverted to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Partitions {
    /// The chip whose flash they split.
    pub chip: &'static Chip,
    /// The bootloader's image.
    pub bootloader: Span,
    /// embassy-boot's state: a magic word, then the swap's progress.
    pub state: Span,
    /// lbv-boot's record, [`RECORD_PAGES`] pages: the ticket page ([`Partitions::ticket`]: the update's length
    /// and signature, written by the application before it marks the update, and the bootloader's verdict on it),
    /// then the security counter's journal ([`Partitions::counter`], two pages written in turn, so that a power cut
    /// in an erase always leaves the other page's entries).
    pub record: Span,
    /// The image that runs.
    pub active: Span,
    /// The image to swap in, one page larger than ACTIVE: embassy-boot's swap moves every page of ACTIVE one
    /// page up in DFU.
    pub dfu: Span,
}

/// The pages of [`Partitions::record`]: the ticket page and the counter journal's two.
pub const RECORD_PAGES: u32 = 3;

impl Partitions {
    /// The flash's pages the swap moves.
    pub const fn active_pages(&self) -> u32 {
        self.active.length / PAGE
    }

    /// The record's first page: the update's ticket and the bootloader's verdict (update-image's `Ticket`,
    /// `Verdict`).
    pub const fn ticket(&self) -> Span {
        Span {
            origin: self.record.origin,
            length: PAGE,
        }
    }

    /// The record's other two pages: the security counter's journal.
    pub const fn counter(&self) -> Span {
        Span {
            origin: self.record.origin + PAGE,
            length: self.record.length - PAGE,
        }
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
    /// The state partition cannot hold the swap's progress: a magic word, a progress-valid word and four words per
    /// ACTIVE page (embassy-boot's `assert_partitions`).
    StateTooSmall,
    /// The record is not [`RECORD_PAGES`] pages.
    RecordSize,
}

/// Check partitions as embassy-boot's bootloader does at every start (`assert_partitions`, where a failure is a
/// panic in the bootloader): here at build time instead.
pub const fn check_partitions(partitions: &Partitions) -> Result<(), PartitionError> {
    let Partitions {
        chip,
        bootloader,
        state,
        record,
        active,
        dfu,
    } = *partitions;
    if bootloader.origin != chip.flash.origin {
        return Err(PartitionError::BootloaderNotFirst);
    }
    let all = [bootloader, state, record, active, dfu];
    let mut rest: &[Span] = &all;
    while let [span, tail @ ..] = rest {
        let span = *span;
        if span.origin % PAGE != 0 || span.length % PAGE != 0 || span.length == 0 {
            return Err(PartitionError::Unaligned);
        }
        if !chip.flash.contains(span) {
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
    if state.length < (2 + 4 * partitions.active_pages()) * WRITE_UNIT {
        return Err(PartitionError::StateTooSmall);
    }
    if record.length != RECORD_PAGES * PAGE {
        return Err(PartitionError::RecordSize);
    }
    Ok(())
}

/// A span of the flash, in KiB from its start.
const fn kib(origin: u32, length: u32) -> Span {
    Span {
        origin: FLASH_ORIGIN + origin * KIB,
        length: length * KIB,
    }
}

/// The thruster's flash: a 16 KiB bootloader (lbv-boot: embassy-boot's swap and the signature check before it, 15 KiB),
/// one page of state (102 words of the 256 it holds), the record's three pages, and the rest split between ACTIVE
/// (50 KiB, 25 pages) and DFU (52 KiB); the last page is left unused, since ACTIVE and DFU grow by whole pages
/// together. The thruster keeps no settings in flash.
pub const THRUSTER_PARTITIONS: Partitions = Partitions {
    chip: &G431RB,
    bootloader: kib(0, 16),
    state: kib(16, 2),
    record: kib(18, 6),
    active: kib(24, 50),
    dfu: kib(74, 52),
};

/// The master's flash, one bank for the image that runs and one for everything written: bank 1 holds the
/// bootloader (16 KiB, the thruster's bootloader built for this chip) and ACTIVE (228 KiB, 114 pages); bank 2 holds
/// the bootloader's state (two pages: 458 words of the 512 they hold), its record (three pages), DFU (230 KiB,
/// ACTIVE and a page) and the settings' 16 KiB ([`MASTER_STORAGE`]), which end the flash as on the master's first
/// board, where flashing an image never reaches them. ACTIVE can grow no further than DFU allows, so bank 1's top
/// 12 KiB stay unused. The running image writes the state, the record, DFU and its settings in the bank it does not
/// run from, which RM0440 3.3.8 allows without stalling it (a page erase in the bank code runs from stalls every
/// fetch for tens of milliseconds).
pub const MASTER_PARTITIONS: Partitions = Partitions {
    chip: &G474RE,
    bootloader: kib(0, 16),
    state: kib(256, 4),
    record: kib(260, 6),
    active: kib(16, 228),
    dfu: kib(266, 230),
};

/// Where the master keeps its settings: the top 16 KiB of the G474RE's flash, eight pages of bank 2.
pub const MASTER_STORAGE: Span = kib(496, 16);

const _: () = {
    assert!(check_partitions(&THRUSTER_PARTITIONS).is_ok());
    assert!(check_partitions(&MASTER_PARTITIONS).is_ok());
    // Bank 1 holds what runs, bank 2 everything the running master writes.
    assert!(MASTER_PARTITIONS.active.end() <= G474_BANK2 && MASTER_PARTITIONS.state.origin == G474_BANK2);
    assert!(MASTER_PARTITIONS.record.origin >= G474_BANK2 && MASTER_PARTITIONS.dfu.origin >= G474_BANK2);
    assert!(MASTER_PARTITIONS.dfu.end() == MASTER_STORAGE.origin && MASTER_STORAGE.end() == G474RE.flash.end());
};

const fn region(name: &'static str, span: Span, holds: &'static str) -> Region {
    Region { name, span, holds }
}

const STACK_AND_STATICS: &str = "static data and, below it (flip-link), the stack";

/// The thruster's application, linked into ACTIVE.
pub const THRUSTER: Layout = Layout {
    image: "the thruster's application (NUCLEO-G431RB)",
    chip: &G431RB,
    regions: &[
        region(
            "BOOTLOADER",
            THRUSTER_PARTITIONS.bootloader,
            "the bootloader (lbv-boot); nothing is linked here",
        ),
        region(
            "BOOTLOADER_STATE",
            THRUSTER_PARTITIONS.state,
            "the bootloader's state; nothing is linked here",
        ),
        region(
            "BOOT_RECORD",
            THRUSTER_PARTITIONS.record,
            "the bootloader's record: an update's ticket and verdict, the security counter; nothing is linked here",
        ),
        region("FLASH", THRUSTER_PARTITIONS.active, "the image (the ACTIVE partition)"),
        region(
            "DFU",
            THRUSTER_PARTITIONS.dfu,
            "a new image, written by the running one; nothing is linked here",
        ),
        region("RAM", G431RB.ram, STACK_AND_STATICS),
    ],
    boot: Boot::Application(&THRUSTER_PARTITIONS),
};

/// The thruster's bootloader, linked into its partition.
pub const THRUSTER_BOOT: Layout = Layout {
    image: "the thruster's bootloader (NUCLEO-G431RB)",
    chip: &G431RB,
    regions: &[
        region("FLASH", THRUSTER_PARTITIONS.bootloader, "the bootloader"),
        region(
            "BOOTLOADER_STATE",
            THRUSTER_PARTITIONS.state,
            "its state: the swap's progress",
        ),
        region(
            "BOOT_RECORD",
            THRUSTER_PARTITIONS.record,
            "its record: an update's ticket and its verdict, the security counter",
        ),
        region("ACTIVE", THRUSTER_PARTITIONS.active, "the image it starts"),
        region(
            "DFU",
            THRUSTER_PARTITIONS.dfu,
            "the image it checks and swaps in, and after the swap the one it reverts to",
        ),
        region("RAM", G431RB.ram, STACK_AND_STATICS),
    ],
    boot: Boot::Bootloader(&THRUSTER_PARTITIONS),
};

/// The master's application, linked into ACTIVE.
pub const MASTER: Layout = Layout {
    image: "the master's application (NUCLEO-G474RE)",
    chip: &G474RE,
    regions: &[
        region(
            "BOOTLOADER",
            MASTER_PARTITIONS.bootloader,
            "the bootloader (lbv-boot); nothing is linked here",
        ),
        region(
            "FLASH",
            MASTER_PARTITIONS.active,
            "the image (the ACTIVE partition, bank 1)",
        ),
        region(
            "BOOTLOADER_STATE",
            MASTER_PARTITIONS.state,
            "the bootloader's state (bank 2); nothing is linked here",
        ),
        region(
            "BOOT_RECORD",
            MASTER_PARTITIONS.record,
            "the bootloader's record (bank 2): an update's ticket and verdict, the security counter; nothing is \
             linked here",
        ),
        region(
            "DFU",
            MASTER_PARTITIONS.dfu,
            "a new image, written by the running one (bank 2); nothing is linked here",
        ),
        region(
            "STORAGE",
            MASTER_STORAGE,
            "the master's settings (lbv-master-fw/src/settings.rs); nothing is linked here",
        ),
        region("RAM", G474RE.ram, STACK_AND_STATICS),
    ],
    boot: Boot::Application(&MASTER_PARTITIONS),
};

/// The master's bootloader, linked into its partition.
pub const MASTER_BOOT: Layout = Layout {
    image: "the master's bootloader (NUCLEO-G474RE)",
    chip: &G474RE,
    regions: &[
        region("FLASH", MASTER_PARTITIONS.bootloader, "the bootloader"),
        region("ACTIVE", MASTER_PARTITIONS.active, "the image it starts (bank 1)"),
        region(
            "BOOTLOADER_STATE",
            MASTER_PARTITIONS.state,
            "its state: the swap's progress (bank 2)",
        ),
        region(
            "BOOT_RECORD",
            MASTER_PARTITIONS.record,
            "its record: an update's ticket and its verdict, the security counter (bank 2)",
        ),
        region(
            "DFU",
            MASTER_PARTITIONS.dfu,
            "the image it checks and swaps in, and after the swap the one it reverts to (bank 2)",
        ),
        region(
            "STORAGE",
            MASTER_STORAGE,
            "the master's settings, which it never touches",
        ),
        region("RAM", G474RE.ram, STACK_AND_STATICS),
    ],
    boot: Boot::Bootloader(&MASTER_PARTITIONS),
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
    let chip = layout.chip;
    let mut rest = layout.regions;
    while let [region, tail @ ..] = rest {
        let span = region.span;
        if chip.flash.contains(span) {
            if span.origin % PAGE != 0 || span.length % PAGE != 0 {
                return Err(LayoutError::Unaligned(region.name));
            }
        } else if !chip.ram.contains(span) {
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
    assert!(check(&MASTER_BOOT).is_ok());
};

/// The layout as a linker script's MEMORY block: the image's `memory.x`.
impl fmt::Display for Layout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "/* {}, {}: generated from g431_hw::memory; do not edit.",
            self.image, self.chip.part
        )?;
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
            let start = span.origin - FLASH_ORIGIN;
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
        assert!(
            text.starts_with("/* the master's application (NUCLEO-G474RE), STM32G474RE:"),
            "{text}"
        );
        assert!(text.contains("\nMEMORY\n{\n"), "{text}");
        for line in [
            "  FLASH            : ORIGIN = 0x08004000, LENGTH = 228K\n",
            "  BOOTLOADER_STATE : ORIGIN = 0x08040000, LENGTH = 4K\n",
            "  BOOT_RECORD      : ORIGIN = 0x08041000, LENGTH = 6K\n",
            "  DFU              : ORIGIN = 0x08042800, LENGTH = 230K\n",
            "  STORAGE          : ORIGIN = 0x0807C000, LENGTH = 16K\n",
            "  RAM              : ORIGIN = 0x20000000, LENGTH = 128K\n}\n",
        ] {
            assert!(text.contains(line), "{line} in\n{text}");
        }
        let thruster = THRUSTER.to_string();
        assert!(
            thruster.contains("  RAM              : ORIGIN = 0x20000000, LENGTH = 32K\n}\n"),
            "{thruster}"
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
            image: "test",
            chip: &G431RB,
            regions,
            boot: Boot::None,
        }
    }

    const ALL_RAM: Region = region("RAM", G431RB.ram.origin, G431RB.ram.length);
    const HALF_FLASH: Region = region("FLASH", FLASH_ORIGIN, 64 * KIB);

    #[test]
    fn the_thruster_layouts_print_the_partitions_for_embassy_boot() {
        for layout in [THRUSTER, THRUSTER_BOOT] {
            let text = layout.to_string();
            for symbol in [
                "__bootloader_state_start = 0x00004000;\n",
                "__bootloader_state_end = 0x00004800;\n",
                "__bootloader_active_start = 0x00006000;\n",
                "__bootloader_active_end = 0x00012800;\n",
                "__bootloader_dfu_start = 0x00012800;\n",
                "__bootloader_dfu_end = 0x0001F800;\n",
            ] {
                assert!(text.contains(symbol), "{symbol} in\n{text}");
            }
        }
        let application = THRUSTER.to_string();
        assert!(application.contains("  FLASH            : ORIGIN = 0x08006000, LENGTH = 50K\n"));
        assert!(application.contains("  BOOT_RECORD      : ORIGIN = 0x08004800, LENGTH = 6K\n"));
        assert!(application.contains(".image_info ORIGIN(FLASH) + 0x200 :"));
        let bootloader = THRUSTER_BOOT.to_string();
        assert!(bootloader.contains("  FLASH            : ORIGIN = 0x08000000, LENGTH = 16K\n"));
        assert!(!bootloader.contains(".image_info"));
    }

    #[test]
    fn the_master_layouts_print_their_partitions_for_embassy_boot() {
        for layout in [MASTER, MASTER_BOOT] {
            let text = layout.to_string();
            for symbol in [
                "__bootloader_state_start = 0x00040000;\n",
                "__bootloader_state_end = 0x00041000;\n",
                "__bootloader_active_start = 0x00004000;\n",
                "__bootloader_active_end = 0x0003D000;\n",
                "__bootloader_dfu_start = 0x00042800;\n",
                "__bootloader_dfu_end = 0x0007C000;\n",
            ] {
                assert!(text.contains(symbol), "{symbol} in\n{text}");
            }
        }
        assert!(MASTER.to_string().contains(".image_info ORIGIN(FLASH) + 0x200 :"));
        assert!(!MASTER_BOOT.to_string().contains(".image_info"));
    }

    const fn span(origin_kib: u32, length_kib: u32) -> Span {
        kib(origin_kib, length_kib)
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
                    dfu: span(72, 52),
                    ..good
                },
                PartitionError::Misplaced,
            ),
            (
                Partitions {
                    dfu: span(78, 52),
                    ..good
                },
                PartitionError::Misplaced,
            ),
            (
                Partitions {
                    record: span(16, 6),
                    ..good
                },
                PartitionError::Misplaced,
            ),
            (
                Partitions {
                    dfu: span(74, 50),
                    ..good
                },
                PartitionError::DfuTooSmall,
            ),
            (
                Partitions {
                    record: span(18, 4),
                    ..good
                },
                PartitionError::RecordSize,
            ),
        ];
        let master = MASTER_PARTITIONS;
        let cases = cases.into_iter().chain([
            (
                Partitions {
                    state: span(256, 2),
                    ..master
                },
                PartitionError::StateTooSmall,
            ),
            (
                // The G474's flash under the G431's partitions' chip: DFU leaves the flash.
                Partitions {
                    chip: &G431RB,
                    ..master
                },
                PartitionError::Misplaced,
            ),
        ]);
        for (partitions, refusal) in cases {
            assert_eq!(check_partitions(&partitions), Err(refusal), "{partitions:?}");
        }
    }

    #[test]
    fn a_bad_layout_is_refused() {
        const OVERLAP: Layout = layout(&[HALF_FLASH, region("DFU", FLASH_ORIGIN + 62 * KIB, 4 * KIB), ALL_RAM]);
        assert_eq!(check(&OVERLAP), Err(LayoutError::Overlap("FLASH", "DFU")));
        const UNALIGNED: Layout = layout(&[region("FLASH", FLASH_ORIGIN, 63 * KIB), ALL_RAM]);
        assert_eq!(check(&UNALIGNED), Err(LayoutError::Unaligned("FLASH")));
        const OUTSIDE: Layout = layout(&[region("FLASH", FLASH_ORIGIN, 130 * KIB), ALL_RAM]);
        assert_eq!(check(&OUTSIDE), Err(LayoutError::Outside("FLASH")));
        const TOO_MUCH_RAM: Layout = layout(&[HALF_FLASH, region("RAM", G431RB.ram.origin, 33 * KIB)]);
        assert_eq!(check(&TOO_MUCH_RAM), Err(LayoutError::Outside("RAM")));
        const NO_FLASH: Layout = layout(&[ALL_RAM]);
        assert_eq!(check(&NO_FLASH), Err(LayoutError::Missing("FLASH")));
        const FITS: Layout = layout(&[HALF_FLASH, region("DFU", FLASH_ORIGIN + 64 * KIB, 4 * KIB), ALL_RAM]);
        assert_eq!(check(&FITS), Ok(()));
    }
}
