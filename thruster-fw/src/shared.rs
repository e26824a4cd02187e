//! The channels between one controller's tasks ([`Shared`]), and which of them report to the watchdog (`TaskId`).

use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicBool, Ordering};

use crash_record::{Event, Region, What};

use embassy_sync::blocking_mutex::Mutex as BlockingMutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_sync::watch::Watch;
use tmc_proto::StatusFrame;
use tmc_proto::ext::{CommandFrame, CommandKind, FrameBytes, Reply};

use crate::control::{LinkUpdate, Sensed};
use crate::drive::Duty;
use crate::hall::HallTracker;
use crate::health::Health;

/// The tasks that report to the watchdog.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub(crate) enum TaskId {
    /// The I2C slave.
    I2c = 0,
    /// Commutation.
    Commutation = 1,
    /// Fault sampling.
    Faults = 2,
    /// Speed control.
    Control = 3,
}

/// How many tasks report to the watchdog.
pub(crate) const TASKS: u8 = 4;

type Mutex = CriticalSectionRawMutex;

/// The channels between one controller's tasks. Every field holds the latest value: a task reads what it needs
/// when it needs it, and nobody waits on a slower task.
pub struct Shared {
    /// I2C -> control, faults: the master's last order and when it last spoke.
    pub link: Watch<Mutex, LinkUpdate, 1>,
    /// Commutation -> control, faults: the hall tracker after the latest edge.
    pub(crate) hall: Watch<Mutex, HallTracker, 1>,
    /// Faults -> control, commutation: the fault verdict and measurements.
    pub sensed: Watch<Mutex, Sensed, 1>,
    /// Control -> commutation, faults: the duty to apply.
    pub duty: Watch<Mutex, Duty, 1>,
    /// Control -> I2C: the status frame for the next read.
    pub(crate) status: Watch<Mutex, StatusFrame, 1>,
    /// Wakes the commutation task when the duty or the fault verdict changed.
    pub(crate) wake: Signal<Mutex, ()>,
    /// I2C <-> update: the field-update extension's latest command and its reply for the next read; trial ->
    /// update: whether the image is on trial.
    pub replies: Replies,
    /// Fault bits set at any sample since the last status read carried them (see [`Shared::note_unread`]).
    unread: BlockingMutex<Mutex, Cell<u8>>,
    /// Task heartbeats for the watchdog.
    pub health: Health,
    /// The post-mortem region ([`crash_record`]), once the binding has handed it over ([`Shared::keep_crash`]): the
    /// ring of the events noted since the start ([`Shared::note`]), which the record of a stop keeps.
    crash: BlockingMutex<Mutex, RefCell<Option<&'static mut Region>>>,
}

impl Shared {
    /// Empty channels.
    pub const fn new() -> Self {
        Self {
            link: Watch::new(),
            hall: Watch::new(),
            sensed: Watch::new(),
            duty: Watch::new(),
            status: Watch::new(),
            wake: Signal::new(),
            replies: Replies::new(),
            unread: BlockingMutex::new(Cell::new(0)),
            health: Health::new(TASKS),
            crash: BlockingMutex::new(RefCell::new(None)),
        }
    }

    /// Keep the post-mortem region, its start done ([`Region::start`]): from now on events are noted in its ring.
    pub fn keep_crash(&self, region: &'static mut Region) {
        self.crash.lock(|crash| *crash.borrow_mut() = Some(region));
    }

    /// Hand the region back: its events stop here (the bench's power cut, which gives it to the next start).
    pub fn take_crash(&self) -> Option<&'static mut Region> {
        self.crash.lock(|crash| crash.borrow_mut().take())
    }

    /// Note `what` in the ring of the last events, with the time since the start (nothing without the region).
    #[inline(never)]
    pub(crate) fn note(&self, what: What) {
        let at_ms = embassy_time::Instant::now().as_millis() as u32;
        self.crash.lock(|crash| {
            if let Ok(mut crash) = crash.try_borrow_mut()
                && let Some(region) = crash.as_deref_mut()
            {
                region.note(Event { at_ms, what });
            }
        });
    }

    /// Fault bits (the status's fault field) set now. They go into every status read until one read has carried
    /// them, so a fault that sets and clears between two reads is still seen (docs/decisions.md D14).
    pub(crate) fn note_unread(&self, bits: u8) {
        self.unread.lock(|unread| unread.set(unread.get() | bits));
    }

    /// Take the bits noted since the last take, for the read being served.
    pub(crate) fn take_unread(&self) -> u8 {
        self.unread.lock(|unread| unread.replace(0))
    }
}

impl core::fmt::Debug for Shared {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Shared").finish_non_exhaustive()
    }
}

impl Default for Shared {
    fn default() -> Self {
        Self::new()
    }
}

/// The reply a read gets instead of the status: the one to the latest extension command, "busy" until the update
/// task has carried it out, gone once read done.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Pending {
    command: CommandKind,
    seq: u8,
    done: bool,
    frame: FrameBytes,
}

impl Pending {
    /// The reply's bytes.
    pub(crate) fn frame(&self) -> &FrameBytes {
        &self.frame
    }
}

/// The I2C task's and the update task's channels: the latest command, the reply to it, and whether it was read.
pub struct Replies {
    /// I2C -> update: the latest command (a newer one replaces one not taken yet).
    pub(crate) commands: Signal<Mutex, CommandFrame>,
    pending: BlockingMutex<Mutex, Cell<Option<Pending>>>,
    /// A done reply was read.
    pub(crate) read: Signal<Mutex, ()>,
    /// Trial -> update: the running image is on trial, or (until the trial task has read the bootloader's state,
    /// and when it cannot) it may be: no update begins over the image a revert may need.
    on_trial: AtomicBool,
    /// The master has read a done reply since the start: the extension, the path of the next update, works.
    answered: AtomicBool,
}

// The methods the tasks call are kept out of line (`inline(never)`): inlined into the tasks' poll functions they
// cost more flash, as built.
impl Replies {
    /// Nothing pending.
    pub(crate) const fn new() -> Self {
        Self {
            commands: Signal::new(),
            pending: BlockingMutex::new(Cell::new(None)),
            read: Signal::new(),
            on_trial: AtomicBool::new(true),
            answered: AtomicBool::new(false),
        }
    }

    /// A command arrived: the next read gets "busy" for it until it is done, and the update task gets it.
    #[inline(never)]
    pub(crate) fn command(&self, frame: CommandFrame) {
        let command = frame.command.kind();
        let busy = Reply::Busy {
            seq: frame.seq,
            command,
        };
        self.pending.lock(|pending| {
            pending.set(Some(Pending {
                command,
                seq: frame.seq,
                done: false,
                frame: busy.encode(),
            }))
        });
        self.commands.signal(frame);
    }

    /// The reply a read now gets, if any.
    #[inline(never)]
    pub(crate) fn for_read(&self) -> Option<Pending> {
        self.pending.lock(Cell::get)
    }

    /// `sent` was read: a done reply is gone (the next read gets the status); a busy one stays.
    #[inline(never)]
    pub(crate) fn sent(&self, sent: &Pending) {
        if !sent.done {
            return;
        }
        self.pending.lock(|pending| {
            if pending
                .get()
                .is_some_and(|now| now.done && now.command == sent.command && now.seq == sent.seq)
            {
                pending.set(None);
            }
        });
        self.answered.store(true, Ordering::Relaxed);
        self.read.signal(());
    }

    /// Whether the master has read a reply to an extension command since the start.
    pub(crate) fn answered(&self) -> bool {
        self.answered.load(Ordering::Relaxed)
    }

    /// The update task's reply; dropped if a newer command has replaced the one it answers.
    #[inline(never)]
    pub(crate) fn complete(&self, reply: Reply) {
        self.pending.lock(|pending| {
            if let Some(now) = pending.get()
                && !now.done
                && now.command == reply.command()
                && now.seq == reply.seq()
            {
                pending.set(Some(Pending {
                    done: true,
                    frame: reply.encode(),
                    ..now
                }));
            }
        });
    }

    /// Whether the running image is on trial (the trial task says so once it has read the bootloader's state).
    pub fn on_trial(&self) -> bool {
        self.on_trial.load(Ordering::Relaxed)
    }

    pub(crate) fn set_on_trial(&self, on_trial: bool) {
        self.on_trial.store(on_trial, Ordering::Relaxed);
    }
}

impl Default for Replies {
    fn default() -> Self {
        Self::new()
    }
}

impl core::fmt::Debug for Replies {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Replies").finish_non_exhaustive()
    }
}
