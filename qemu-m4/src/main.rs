//! qemu-m4: the firmware cores on an emulated Cortex-M4F (QEMU `mps2-an386`), with the figures a host test cannot
//! give: stack high-water marks, instructions per poll, hall-edge latency.
//!
//! One image, three runs, chosen by the semihosting command line (`run.sh` starts them):
//! - `acceptance seabotix|legacy`: the dev-kit acceptance test looped back inside the chip (`acceptance.rs`);
//! - `vehicle`: the master's whole core with six thruster cores and a scripted pilot (`vehicle.rs`).
//!
//! Everything here is binding and test bench: the firmware is the cores' wiring functions (`thruster_fw::run`,
//! `thruster_fw::run_commutation`, `lbv_master_fw::run`) with their production configurations, linked unchanged.
//! On the host this binary is a stub.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod acceptance;
#[cfg(target_os = "none")]
mod board;
#[cfg(target_os = "none")]
mod executors;
#[cfg(target_os = "none")]
mod halls;
#[cfg(target_os = "none")]
mod heap;
#[cfg(target_os = "none")]
mod i2c;
#[cfg(target_os = "none")]
mod master;
#[cfg(target_os = "none")]
mod meter;
#[cfg(target_os = "none")]
mod report;
#[cfg(target_os = "none")]
mod stacks;
#[cfg(target_os = "none")]
mod station;
#[cfg(target_os = "none")]
mod thruster;
#[cfg(target_os = "none")]
mod time;
#[cfg(target_os = "none")]
mod vehicle;

#[cfg(target_os = "none")]
pub use entry::DEFMT_FRAMES;

#[cfg(target_os = "none")]
mod entry {
    use core::sync::atomic::{AtomicU32, Ordering};

    use cortex_m_rt::{ExceptionFrame, entry, exception};
    use tmc_proto::Family;

    use crate::{acceptance, executors, heap, meter, report, stacks, time, vehicle};

    /// What to run, from the semihosting command line.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    enum Run {
        Acceptance(Family),
        Vehicle,
    }

    /// Read the command line QEMU passes (`-semihosting-config arg=...`): the program name, then the run.
    fn command_line() -> Option<Run> {
        let mut buffer = [0u8; 96];
        let mut block = [buffer.as_mut_ptr() as usize, buffer.len()];
        let block = block.as_mut_ptr();
        // SAFETY: SYS_GET_CMDLINE writes at most `block[1]` bytes to `block[0]` and the length back to `block[1]`;
        // both are read back through the same pointers the host wrote through.
        #[allow(unsafe_code)]
        let (failed, length) = unsafe {
            let failed = cortex_m_semihosting::syscall1(cortex_m_semihosting::nr::GET_CMDLINE, block as usize);
            (failed, block.add(1).read_volatile())
        };
        if failed != 0 {
            return None;
        }
        let line = core::str::from_utf8(buffer.get(..length)?).ok()?;
        let mut words = line.split_whitespace().skip(1);
        match (words.next()?, words.next()) {
            ("acceptance", Some("seabotix")) => Some(Run::Acceptance(Family::SeaBotix)),
            ("acceptance", Some("legacy")) => Some(Run::Acceptance(Family::Legacy)),
            ("vehicle", None) => Some(Run::Vehicle),
            _ => None,
        }
    }

    #[entry]
    fn main() -> ! {
        stacks::enter_thread_mode(thread_main)
    }

    /// Thread mode, on the process stack.
    extern "C" fn thread_main() -> ! {
        heap::init();
        meter::init();
        time::init();
        let Some(run) = command_line() else {
            report::fail("usage: qemu-m4 acceptance seabotix|legacy | qemu-m4 vehicle (semihosting arguments)");
        };
        report::calibration(meter::calibrate());
        executors::run_thread_mode(|spawner| match run {
            Run::Acceptance(family) => acceptance::start(spawner, family),
            Run::Vehicle => vehicle::start(spawner),
        })
    }

    #[panic_handler]
    fn panic(info: &core::panic::PanicInfo<'_>) -> ! {
        crate::say!("{info}");
        report::exit(false)
    }

    #[exception]
    #[allow(unsafe_code)]
    unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
        crate::say!("FAIL hard fault at pc {:#010x}", frame.pc());
        report::exit(false)
    }

    /// The thruster core logs through defmt. Its frames are only counted here: decoding them needs the host's
    /// defmt tools, and the figures and report lines do not depend on them.
    #[defmt::global_logger]
    struct FrameCounter;

    /// defmt frames the cores logged.
    pub static DEFMT_FRAMES: AtomicU32 = AtomicU32::new(0);

    // SAFETY: acquire/release only count; `write` ignores the bytes, so no state is shared between frames.
    #[allow(unsafe_code)]
    unsafe impl defmt::Logger for FrameCounter {
        fn acquire() {
            DEFMT_FRAMES.fetch_add(1, Ordering::Relaxed);
        }
        unsafe fn flush() {}
        unsafe fn release() {}
        unsafe fn write(_bytes: &[u8]) {}
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("qemu-m4 runs on QEMU's mps2-an386: qemu-m4/run.sh builds it and runs it");
    std::process::exit(2);
}
