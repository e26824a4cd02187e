//! What an image's stop handlers take the record with on a Cortex-M: the region at its address in RAM, the
//! registers an exception stacked, the fault status registers and the active exception.

use crate::{FaultStatus, Frame, Kind, PanicAt, Region, Stop};

// Any bytes are a region, with nothing to align.
const _: () = assert!(core::mem::align_of::<Region>() == 1);

/// The region at `origin`.
///
/// # Safety
///
/// `origin` is the start of [`crate::REGION_LEN`] bytes of RAM that nothing else is linked into and no stack
/// reaches (`g431_hw::memory::CRASH`), and the caller holds the only reference: the start takes it once and hands it
/// on; a stop handler takes it again only once every other context has stopped for good.
#[allow(unsafe_code)]
pub unsafe fn region(origin: u32) -> &'static mut Region {
    // SAFETY: as the caller promises; any bytes are a `Region`.
    unsafe { &mut *(origin as *mut Region) }
}

/// The registers an exception stacked, and the stack pointer before it (the basic frame is eight words; an FPU
/// frame's 18 more words and an alignment word are not counted: the SP is where the frame begins plus 32).
pub fn stacked(frame: &cortex_m_rt::ExceptionFrame) -> Frame {
    Frame {
        pc: frame.pc(),
        lr: frame.lr(),
        xpsr: frame.xpsr(),
        sp: (frame as *const cortex_m_rt::ExceptionFrame as u32).wrapping_add(32),
    }
}

/// A stop of `kind` now: the fault status registers (ARMv7-M B3.2.15-B3.2.18) and the active exception
/// (ICSR.VECTACTIVE, B3.2.4) read, with `frame`, `panic` and the uptime.
pub fn stop(kind: Kind, frame: Frame, panic: Option<PanicAt>, uptime_ms: u32) -> Stop {
    // SAFETY: SCB's registers, only read.
    #[allow(unsafe_code)]
    let scb = unsafe { &*cortex_m::peripheral::SCB::PTR };
    Stop {
        kind,
        frame,
        faults: FaultStatus {
            cfsr: scb.cfsr.read(),
            hfsr: scb.hfsr.read(),
            mmfar: scb.mmfar.read(),
            bfar: scb.bfar.read(),
        },
        exception: (scb.icsr.read() & 0x1FF) as u16,
        panic,
        uptime_ms,
    }
}

/// The stack pointer in use (a panic's, which has no stacked frame).
pub fn stack_pointer() -> Frame {
    Frame {
        sp: cortex_m::register::msp::read(),
        ..Frame::default()
    }
}
