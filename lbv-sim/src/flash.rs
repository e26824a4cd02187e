//! NOR flash, as the STM32G4's: erased a page at a time to 0xFF, programmed a double word (8 bytes) at a time,
//! each double word once between erases but with all zeros, which program over anything. It implements
//! embedded-storage's blocking and async `NorFlash`, so a settings store (sequential-storage) runs on it as on the
//! chip.
//!
//! It is a handle: clones share the memory, so the flash outlives the board that uses it (a master that reboots
//! or loses power finds what it wrote). A handle may see only a partition of the memory ([`Flash::partition`]), as
//! a firmware's updater sees its DFU partition of the chip's one flash. A power cut can be armed to land in the middle of an erase or a program:
//! the operation stops at that byte, leaving the page torn, and the flash answers nothing until power returns.
//!
//! The STM32G4 keeps ECC bits with each double word (RM0440 3.3.2): one it was programming or erasing when the power
//! went is left with data and ECC that disagree. Such a torn double word reads back as its cells hold it, and
//! every read of it is recorded as an ECC double error (on the chip: FLASH_ECCR.ECCD and an NMI), with its
//! offset, until it is erased again (or programmed with zeros).
//!
//! Erases and writes take no time unless the flash is wired to a CPU ([`Flash::stall_cpu`]): then each page erased
//! and each double word programmed stalls that CPU for its [`FlashTiming`], as the G431's single bank stalls the
//! code that runs from it (the work is done at once; the CPU is held for its duration afterwards).

use alloc::collections::BTreeSet;
use alloc::rc::Rc;
use alloc::vec;
use alloc::vec::Vec;
use core::cell::RefCell;

use embassy_time::Duration;
use embedded_storage::nor_flash::{self, NorFlashError, NorFlashErrorKind};

use crate::cpu::Cpu;

/// How long the flash's work takes, and what it stalls.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FlashTiming {
    /// One page erase.
    pub erase_page: Duration,
    /// Programming one write unit (a double word on the STM32G4).
    pub program_unit: Duration,
    /// Where the bank the code runs from ends, in bytes from the flash's start: work below stalls the CPU it is
    /// wired to; work beyond (the other bank of a dual-bank flash, RM0440 3.3.8) runs beside the code, and the
    /// async calls wait it out instead, letting every other task run.
    pub stalls_below: usize,
}

impl FlashTiming {
    /// The STM32G431 as the bench charges it. DS12589's flash table (t_ERASE, t_PROG) could not be read here:
    /// project notes put a page erase at "tens of milliseconds" and the issue that asked for this model at about
    /// 20 ms. The bench takes 25 ms, the thruster bus's timeout: a transfer caught by an erase cannot end in time,
    /// which is the hazard the master must avoid. A double word is taken at 100 us (an assumed figure of the order
    /// of STM32 flash programming times), so a settings record of 12 costs 1.2 ms.
    pub const G431: FlashTiming = FlashTiming {
        erase_page: Duration::from_millis(25),
        program_unit: Duration::from_micros(100),
        stalls_below: usize::MAX,
    };

    /// The STM32G474 in dual-bank mode, with the code in bank 1: the G431's figures (the same flash), and work in
    /// bank 2 (from 256 KiB) beside the code.
    pub const G474_DUAL_BANK: FlashTiming = FlashTiming {
        stalls_below: 256 * 1024,
        ..FlashTiming::G431
    };

    /// How long the work done between two looks at a flash's statistics takes, one operation after another (as a
    /// bootloader does it, waiting for each).
    pub fn work_time(&self, before: FlashStats, after: FlashStats) -> Duration {
        let erases = after.erases.saturating_sub(before.erases);
        let units = after.programmed.saturating_sub(before.programmed) / 8;
        Duration::from_ticks(erases * self.erase_page.as_ticks() + units * self.program_unit.as_ticks())
    }
}

/// Why a flash operation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FlashError {
    /// An offset or length not aligned to the operation's unit.
    NotAligned,
    /// Beyond the end of the flash.
    OutOfBounds,
    /// Programming a double word that is not erased (the STM32's PROGERR).
    NotErased,
    /// The power went (or is off).
    PowerCut,
}

impl NorFlashError for FlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            FlashError::NotAligned => NorFlashErrorKind::NotAligned,
            FlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            FlashError::NotErased | FlashError::PowerCut => NorFlashErrorKind::Other,
        }
    }
}

impl From<NorFlashErrorKind> for FlashError {
    fn from(kind: NorFlashErrorKind) -> Self {
        match kind {
            NorFlashErrorKind::NotAligned => FlashError::NotAligned,
            _ => FlashError::OutOfBounds,
        }
    }
}

/// What the flash has done.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FlashStats {
    /// Pages erased.
    pub erases: u64,
    /// Bytes programmed.
    pub programmed: u64,
    /// Operations torn by a power cut.
    pub torn: u32,
    /// Reads that touched a torn double word (each an ECC double error on the chip).
    pub ecc_errors: u64,
}

#[derive(Debug)]
struct Memory {
    bytes: Vec<u8>,
    /// Bytes that may still be erased or programmed before the power goes; None: no cut armed.
    until_cut: Option<usize>,
    powered: bool,
    stats: FlashStats,
    /// Offsets of the write units a power cut left half done.
    torn_units: BTreeSet<usize>,
    /// Offsets of the torn units reads have touched.
    ecc_offsets: BTreeSet<usize>,
    /// The CPU its work stalls, and for how long.
    stall: Option<(Cpu, FlashTiming)>,
}

impl Memory {
    /// Spend one byte of the armed power cut's budget before changing the byte at `at` of a unit of `unit` bytes:
    /// false once the power has gone, leaving that unit torn if the cut lands inside it.
    fn spend(&mut self, at: usize, unit: usize) -> bool {
        match self.until_cut {
            Some(0) => {
                self.powered = false;
                self.until_cut = None;
                self.stats.torn += 1;
                let unit = unit.max(1);
                if !at.is_multiple_of(unit) {
                    self.torn_units.insert(at - at % unit);
                }
                false
            }
            Some(left) => {
                self.until_cut = Some(left - 1);
                true
            }
            None => true,
        }
    }
}

/// A NOR flash of pages of `ERASE_SIZE` bytes, programmed `WRITE_SIZE` bytes at a time; clones share it.
#[derive(Debug, Clone)]
pub struct Flash<const WRITE_SIZE: usize, const ERASE_SIZE: usize> {
    memory: Rc<RefCell<Memory>>,
    /// Where this handle's offset 0 is in the memory.
    origin: usize,
    /// How many bytes of the memory, from `origin`, this handle sees.
    length: usize,
}

/// The STM32G4's flash: 8-byte double words, 2 KiB pages (RM0440 3.3.7, 3.3.6).
pub type Stm32g4Flash = Flash<8, 2048>;

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> Flash<WRITE_SIZE, ERASE_SIZE> {
    /// `pages` erased pages.
    pub fn new(pages: usize) -> Self {
        let length = pages.saturating_mul(ERASE_SIZE);
        Self {
            memory: Rc::new(RefCell::new(Memory {
                bytes: vec![0xFF; length],
                until_cut: None,
                powered: true,
                stats: FlashStats::default(),
                torn_units: BTreeSet::new(),
                ecc_offsets: BTreeSet::new(),
                stall: None,
            })),
            origin: 0,
            length,
        }
    }

    /// A handle on the `length` bytes of this one from `offset`, as a firmware addresses one partition of its
    /// chip's flash: its offset 0 is `offset` here. It shares the memory, and so the power, any armed cut, the
    /// statistics and the CPU stall, with every other handle. None unless it lies within this handle and starts
    /// and ends on page boundaries.
    pub fn partition(&self, offset: u32, length: u32) -> Option<Self> {
        let (offset, length) = (offset as usize, length as usize);
        let page = ERASE_SIZE.max(1);
        let end = offset.checked_add(length)?;
        if end > self.length || !offset.is_multiple_of(page) || !length.is_multiple_of(page) {
            return None;
        }
        Some(Self {
            memory: Rc::clone(&self.memory),
            origin: self.origin + offset,
            length,
        })
    }

    /// Let every erase and write stall `cpu` for `timing` from now on (every handle on this flash).
    pub fn stall_cpu(&self, cpu: &Cpu, timing: FlashTiming) {
        self.memory.borrow_mut().stall = Some((cpu.clone(), timing));
    }

    /// Erases and writes take no time again.
    pub fn stall_nothing(&self) {
        self.memory.borrow_mut().stall = None;
    }

    /// The offsets of the torn double words in this handle's bytes that reads have touched (each an ECC double
    /// error on the chip).
    pub fn ecc_error_offsets(&self) -> Vec<u32> {
        let memory = self.memory.borrow();
        memory
            .ecc_offsets
            .range(self.origin..self.origin + self.length)
            .filter_map(|offset| u32::try_from(*offset - self.origin).ok())
            .collect()
    }

    /// A copy of everything this handle sees.
    pub fn contents(&self) -> Vec<u8> {
        let memory = self.memory.borrow();
        memory
            .bytes
            .get(self.origin..self.origin + self.length)
            .map(<[u8]>::to_vec)
            .unwrap_or_default()
    }

    /// Cut the power once `bytes` more bytes have been erased or programmed: the operation under way then stops
    /// where it is.
    pub fn cut_power_after(&self, bytes: usize) {
        self.memory.borrow_mut().until_cut = Some(bytes);
    }

    /// Power back on (a cut armed and not yet reached is disarmed).
    pub fn power_on(&self) {
        let mut memory = self.memory.borrow_mut();
        memory.powered = true;
        memory.until_cut = None;
    }

    /// Whether it has power.
    pub fn powered(&self) -> bool {
        self.memory.borrow().powered
    }

    /// What the whole memory has done so far, through any handle.
    pub fn stats(&self) -> FlashStats {
        self.memory.borrow().stats
    }

    fn read_at(&self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        nor_flash::check_read(self, offset, bytes.len())?;
        let mut memory = self.memory.borrow_mut();
        if !memory.powered {
            return Err(FlashError::PowerCut);
        }
        let start = self.origin + offset as usize;
        let stored = memory
            .bytes
            .get(start..start + bytes.len())
            .ok_or(FlashError::OutOfBounds)?;
        bytes.copy_from_slice(stored);
        let unit = WRITE_SIZE.max(1);
        let first = start - start % unit;
        let torn: Vec<usize> = memory.torn_units.range(first..start + bytes.len()).copied().collect();
        if !torn.is_empty() {
            memory.stats.ecc_errors += 1;
            memory.ecc_offsets.extend(torn);
        }
        Ok(())
    }

    /// Erase; the time the work took beside the code (none when it stalled the CPU, or takes no time).
    fn erase_range(&self, from: u32, to: u32) -> Result<Duration, FlashError> {
        nor_flash::check_erase(self, from, to)?;
        let mut memory = self.memory.borrow_mut();
        if !memory.powered {
            return Err(FlashError::PowerCut);
        }
        let unit = WRITE_SIZE.max(1);
        let (from, to) = (self.origin + from as usize, self.origin + to as usize);
        let mut beside = Duration::from_ticks(0);
        for page in (from..to).step_by(ERASE_SIZE.max(1)) {
            for at in page..page + ERASE_SIZE {
                if !memory.spend(at, unit) {
                    return Err(FlashError::PowerCut);
                }
                if let Some(byte) = memory.bytes.get_mut(at) {
                    *byte = 0xFF;
                }
                if at % unit == unit - 1 {
                    memory.torn_units.remove(&(at + 1 - unit));
                }
            }
            memory.stats.erases += 1;
            match &memory.stall {
                Some((cpu, timing)) if page < timing.stalls_below => cpu.stall(timing.erase_page),
                Some((_, timing)) => beside += timing.erase_page,
                None => {}
            }
        }
        Ok(beside)
    }

    /// Program; the time the work took beside the code (none when it stalled the CPU, or takes no time).
    fn program(&self, offset: u32, bytes: &[u8]) -> Result<Duration, FlashError> {
        nor_flash::check_write(self, offset, bytes.len())?;
        let mut memory = self.memory.borrow_mut();
        if !memory.powered {
            return Err(FlashError::PowerCut);
        }
        let start = self.origin + offset as usize;
        let unit = WRITE_SIZE.max(1);
        let stored = memory
            .bytes
            .get(start..start + bytes.len())
            .ok_or(FlashError::OutOfBounds)?;
        // Each double word must be erased, unless it is written all zeros: RM0440 3.3.7 refuses to program a
        // double word twice "except if the data to write is full zero" (FLASH_SR.PROGERR), and zeros with their
        // ECC bits, all zero too, make a whole word of any half-programmed one.
        let programmable = stored
            .chunks(unit)
            .zip(bytes.chunks(unit))
            .all(|(stored, data)| stored.iter().all(|byte| *byte == 0xFF) || data.iter().all(|byte| *byte == 0));
        if !programmable {
            return Err(FlashError::NotErased);
        }
        let mut beside = Duration::from_ticks(0);
        for (at, byte) in (start..).zip(bytes) {
            if !memory.spend(at, WRITE_SIZE) {
                return Err(FlashError::PowerCut);
            }
            if let Some(stored) = memory.bytes.get_mut(at) {
                // NOR: programming only clears bits.
                *stored &= *byte;
            }
            memory.stats.programmed += 1;
            if at % unit == unit - 1 {
                // Programmed to its last byte: its data and ECC agree again.
                memory.torn_units.remove(&(at + 1 - unit));
                match &memory.stall {
                    Some((cpu, timing)) if at < timing.stalls_below => cpu.stall(timing.program_unit),
                    Some((_, timing)) => beside += timing.program_unit,
                    None => {}
                }
            }
        }
        Ok(beside)
    }
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> nor_flash::ErrorType for Flash<WRITE_SIZE, ERASE_SIZE> {
    type Error = FlashError;
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> nor_flash::ReadNorFlash for Flash<WRITE_SIZE, ERASE_SIZE> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        self.read_at(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.length
    }
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> nor_flash::NorFlash for Flash<WRITE_SIZE, ERASE_SIZE> {
    const WRITE_SIZE: usize = WRITE_SIZE;
    const ERASE_SIZE: usize = ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        self.erase_range(from, to).map(drop)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        self.program(offset, bytes).map(drop)
    }
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> embedded_storage_async::nor_flash::ReadNorFlash
    for Flash<WRITE_SIZE, ERASE_SIZE>
{
    const READ_SIZE: usize = 1;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        self.read_at(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.length
    }
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> embedded_storage_async::nor_flash::NorFlash
    for Flash<WRITE_SIZE, ERASE_SIZE>
{
    const WRITE_SIZE: usize = WRITE_SIZE;
    const ERASE_SIZE: usize = ERASE_SIZE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        let beside = self.erase_range(from, to)?;
        wait_out(beside).await;
        Ok(())
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        let beside = self.program(offset, bytes)?;
        wait_out(beside).await;
        Ok(())
    }
}

/// Wait out work the flash did beside the code, as an async driver waits for its end-of-operation interrupt.
async fn wait_out(beside: Duration) {
    if beside.as_ticks() > 0 {
        embassy_time::Timer::after(beside).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};

    type Small = Flash<8, 64>;

    fn read(flash: &mut Small, offset: u32, len: usize) -> Result<Vec<u8>, FlashError> {
        let mut bytes = vec![0; len];
        flash.read(offset, &mut bytes).map(|()| bytes)
    }

    #[test]
    fn erase_sets_0xff_and_program_writes_each_double_word_once() {
        let mut flash = Small::new(2);
        assert_eq!(flash.capacity(), 128);
        assert_eq!(read(&mut flash, 0, 128).unwrap(), vec![0xFF; 128]);
        flash.write(8, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
        assert_eq!(read(&mut flash, 6, 4).unwrap(), [0xFF, 0xFF, 1, 2]);
        assert_eq!(flash.write(8, &[0x0F; 8]), Err(FlashError::NotErased));
        assert_eq!(flash.write(3, &[0; 8]), Err(FlashError::NotAligned));
        assert_eq!(flash.write(128, &[0; 8]), Err(FlashError::OutOfBounds));
        assert_eq!(flash.erase(0, 32), Err(FlashError::NotAligned));
        flash.erase(0, 64).unwrap();
        assert_eq!(read(&mut flash, 8, 8).unwrap(), vec![0xFF; 8]);
        flash.write(8, &[9; 8]).unwrap();
        assert_eq!(flash.stats().erases, 1);
        assert_eq!(flash.stats().programmed, 16);
    }

    #[test]
    fn zeros_program_over_a_programmed_double_word_and_nothing_else_does() {
        let mut flash = Small::new(1);
        flash.write(0, &[0x5A; 16]).unwrap();
        // RM0440 3.3.7: a programmed double word takes all zeros again, and only them.
        flash.write(0, &[0; 8]).unwrap();
        assert_eq!(read(&mut flash, 0, 16).unwrap(), [[0; 8], [0x5A; 8]].concat());
        assert_eq!(flash.write(8, &[0, 0, 0, 0, 0, 0, 0, 1]), Err(FlashError::NotErased));
        assert_eq!(
            flash.write(0, &[[0; 8], [1; 8]].concat()),
            Err(FlashError::NotErased),
            "each double word is judged: the second is neither erased nor written zeros"
        );
        // Zeros make a whole word of a torn one: no ECC error on it after.
        flash.cut_power_after(3);
        assert_eq!(flash.write(16, &[0x33; 8]), Err(FlashError::PowerCut));
        flash.power_on();
        flash.write(16, &[0; 8]).unwrap();
        read(&mut flash, 16, 8).unwrap();
        assert_eq!(flash.ecc_error_offsets(), Vec::<u32>::new());
    }

    #[test]
    fn a_power_cut_tears_the_operation_under_way_and_the_flash_keeps_it() {
        let mut flash = Small::new(1);
        let kept = flash.clone();
        flash.write(0, &[0; 64]).unwrap();
        flash.cut_power_after(20);
        assert_eq!(flash.erase(0, 64), Err(FlashError::PowerCut));
        assert!(!flash.powered());
        assert_eq!(read(&mut flash, 0, 1), Err(FlashError::PowerCut));
        // The board that owned this handle is gone; the memory stays.
        drop(flash);
        kept.power_on();
        let contents = kept.contents();
        assert_eq!(&contents[..20], &[0xFF; 20], "erased up to the cut");
        assert_eq!(&contents[20..], &[0; 44], "the rest as it was");
        assert_eq!(kept.stats().torn, 1);
        let mut flash = kept;
        flash.erase(0, 64).unwrap();
        flash.cut_power_after(3);
        assert_eq!(flash.write(32, &[0x55; 8]), Err(FlashError::PowerCut));
        flash.power_on();
        assert_eq!(
            read(&mut flash, 32, 8).unwrap(),
            [0x55, 0x55, 0x55, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]
        );
    }

    #[test]
    fn erases_and_writes_stall_the_cpu_they_are_wired_to() {
        let _clock = crate::clock::take();
        let cpu = Cpu::new();
        let mut flash = Small::new(2);
        flash.write(0, &[0; 8]).unwrap();
        assert_eq!((cpu.stalls(), cpu.stalled_until()), (0, None), "not wired: no time");
        let timing = FlashTiming {
            erase_page: Duration::from_millis(20),
            program_unit: Duration::from_micros(100),
            stalls_below: usize::MAX,
        };
        flash.clone().stall_cpu(&cpu, timing);
        // Two pages erased and two double words written in one go: the stalls add up.
        flash.erase(0, 128).unwrap();
        flash.write(0, &[1; 16]).unwrap();
        assert_eq!(cpu.stalls(), 4);
        assert_eq!(cpu.stalled_total(), Duration::from_micros(40_200));
        assert_eq!(cpu.stalled_until(), Some(embassy_time::Instant::from_micros(40_200)));
        crate::clock::advance(Duration::from_micros(40_200));
        assert_eq!(cpu.stalled_until(), None, "over");
        flash.stall_nothing();
        flash.erase(0, 64).unwrap();
        assert_eq!(cpu.stalls(), 4);
    }

    #[test]
    fn work_in_the_other_bank_takes_its_time_beside_the_cpu() {
        let _clock = crate::clock::take();
        let cpu = Cpu::new();
        let flash = Small::new(2);
        let timing = FlashTiming {
            erase_page: Duration::from_millis(20),
            program_unit: Duration::from_micros(100),
            stalls_below: 64,
        };
        flash.stall_cpu(&cpu, timing);
        // Page 1 is the other bank: no stall, the time is the caller's to wait out.
        assert_eq!(flash.erase_range(64, 128), Ok(Duration::from_millis(20)));
        assert_eq!(flash.program(64, &[1; 16]), Ok(Duration::from_micros(200)));
        assert_eq!(cpu.stalls(), 0);
        // Page 0 is the code's bank: the CPU stalls, nothing is left to wait.
        assert_eq!(flash.erase_range(0, 64), Ok(Duration::from_ticks(0)));
        assert_eq!(cpu.stalls(), 1);
    }

    #[test]
    fn a_partition_sees_its_pages_of_the_memory_from_its_own_offset_0() {
        let mut whole = Small::new(4);
        let mut second = whole.partition(64, 128).unwrap();
        assert_eq!(second.capacity(), 128);
        assert!(whole.partition(32, 64).is_none(), "not on a page boundary");
        assert!(whole.partition(64, 32).is_none(), "not whole pages");
        assert!(whole.partition(192, 128).is_none(), "past the end");
        let mut third = second.partition(64, 64).unwrap();

        second.write(8, &[7; 8]).unwrap();
        assert_eq!(
            read(&mut whole, 72, 8).unwrap(),
            [7; 8],
            "offset 8 of the partition is 72 of the memory"
        );
        third.write(0, &[9; 8]).unwrap();
        assert_eq!(read(&mut second, 64, 8).unwrap(), [9; 8]);
        assert_eq!(
            third.write(64, &[0; 8]),
            Err(FlashError::OutOfBounds),
            "its end is its own"
        );
        assert_eq!(second.contents().len(), 128);
        assert_eq!(&second.contents()[64..72], &[9; 8]);

        third.erase(0, 64).unwrap();
        assert_eq!(read(&mut whole, 128, 8).unwrap(), [0xFF; 8]);
        assert_eq!(read(&mut whole, 72, 8).unwrap(), [7; 8], "only its page erased");
        assert_eq!(whole.stats().erases, 1, "one memory, one count");

        // A torn double word is reported at its offset in each handle that sees it.
        third.cut_power_after(3);
        assert_eq!(third.write(16, &[1; 8]), Err(FlashError::PowerCut));
        assert!(!whole.powered(), "the power is the chip's");
        whole.power_on();
        read(&mut whole, 0, 256).unwrap();
        assert_eq!(third.ecc_error_offsets(), vec![16]);
        assert_eq!(second.ecc_error_offsets(), vec![80]);
        assert_eq!(whole.ecc_error_offsets(), vec![144]);
        assert_eq!(whole.partition(0, 64).unwrap().ecc_error_offsets(), Vec::<u32>::new());
    }

    #[test]
    fn a_double_word_torn_by_a_power_cut_reads_as_an_ecc_error_until_erased() {
        let mut flash = Small::new(2);
        flash.write(0, &[1; 8]).unwrap();
        // Cut on a double word's boundary: nothing of the next one was programmed, nothing is torn.
        flash.cut_power_after(8);
        assert_eq!(flash.write(8, &[2; 16]), Err(FlashError::PowerCut));
        flash.power_on();
        read(&mut flash, 0, 64).unwrap();
        assert_eq!((flash.stats().ecc_errors, flash.ecc_error_offsets()), (0, vec![]));
        // Cut three bytes into a double word: it is torn, and every read touching it says so.
        flash.cut_power_after(3);
        assert_eq!(flash.write(24, &[3; 8]), Err(FlashError::PowerCut));
        flash.power_on();
        assert_eq!(
            read(&mut flash, 24, 8).unwrap(),
            [3, 3, 3, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]
        );
        read(&mut flash, 30, 1).unwrap();
        read(&mut flash, 16, 8).unwrap();
        assert_eq!((flash.stats().ecc_errors, flash.ecc_error_offsets()), (2, vec![24]));
        // A page erase cut in a double word of the other page tears that one too.
        flash.cut_power_after(64 + 12);
        assert_eq!(flash.erase(0, 128), Err(FlashError::PowerCut));
        flash.power_on();
        read(&mut flash, 0, 128).unwrap();
        assert_eq!(
            flash.ecc_error_offsets(),
            vec![24, 72],
            "every torn double word read so far"
        );
        // Erased, the first page reads cleanly again.
        let before = flash.stats().ecc_errors;
        flash.erase(0, 64).unwrap();
        read(&mut flash, 0, 64).unwrap();
        assert_eq!(flash.stats().ecc_errors, before);
    }
}
