//! The master's ports on lbv-sim's simulated parts, for the bench (`lbv`, with Cargo feature `sim`) and this crate's
//! host tests, host only: a thruster bus recovered by the core's own `clear_bus` on the simulated lines, the battery
//! CAN receiver on a simulated CAN node, the settings store on a simulated G474 flash, a reboot that whoever runs the
//! board carries out, and an update sink that records every image it is given.

extern crate std;

use std::vec::Vec;

use std::cell::{Cell, RefCell};
use std::convert::Infallible;
use std::rc::Rc;

use crate::ports::{Applied, CanFrame, CanReceiver, Reboot, Refused, UpdateSink, UpdateTarget};
use crate::recovery::BusConfig;
use crate::recovery::PinRecovery;
use crate::settings::Store;
use crate::shared::{Sender, UpdateHolds};
use crate::update::ImageHeader;
use crate::update::ftp::Nak;
use crate::update::sys::Versions;
use embassy_time::Delay;
use g431_hw::memory;
use lbv_sim::Queue;
use lbv_sim::flash::Stm32g4Flash;
use lbv_sim::i2c::{Bus, Master, Scl, Sda};

/// A simulated thruster bus as the master sees it: transfers on lbv-sim's master port, the recovery on its lines.
pub type ThrusterBus = PinRecovery<Master, Scl, Sda, Delay>;

/// The master's port on `bus`, whose speed is `config`'s.
pub fn thruster_bus(bus: &Bus, config: &BusConfig) -> ThrusterBus {
    PinRecovery {
        i2c: bus.master(),
        scl: bus.scl(),
        sda: bus.sda(),
        delay: Delay,
        bus: *config,
    }
}

/// The master's receive queue on a simulated CAN bus.
#[derive(Debug, Clone, Default)]
pub struct CanNode(pub Queue<CanFrame>);

impl CanReceiver for CanNode {
    type Error = Infallible;

    async fn receive(&mut self) -> Result<CanFrame, Infallible> {
        Ok(self.0.receive().await)
    }
}

/// The master's flash, erased: the G474RE's 512 KiB, 256 pages of 2 KiB in its two banks (RM0440 3.3.1).
pub fn master_flash() -> Stm32g4Flash {
    Stm32g4Flash::new((memory::G474RE.flash.length / memory::PAGE) as usize)
}

/// The settings store on a simulated master's `flash`, in the pages the binding gives it (a handle: the memory
/// stays with whoever holds another).
pub fn flash_store(flash: &Stm32g4Flash) -> Store<Stm32g4Flash> {
    Store::master(flash.clone())
}

/// A simulated master's reboot: it counts the request and waits; whoever runs the board sees
/// [`RebootRequest::requested`], drops the master's tasks and boots it again.
#[derive(Debug, Clone, Default)]
pub struct RebootRequest(Rc<Cell<u32>>);

impl RebootRequest {
    /// Reboots asked for so far.
    pub fn requested(&self) -> u32 {
        self.0.get()
    }
}

impl Reboot for RebootRequest {
    async fn reboot(&mut self) -> ! {
        self.0.set(self.0.get().saturating_add(1));
        core::future::pending().await
    }
}

/// One image the update sink was given.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReceivedImage {
    /// What it was for.
    pub target: UpdateTarget,
    /// The file as it came: its header, then the payload.
    pub bytes: Vec<u8>,
    /// `None` while it comes; then whether it came whole (`false`: stopped).
    pub complete: Option<bool>,
    /// Times it was applied.
    pub(crate) applied: u32,
}

/// An update sink that records every image it is given, in order, and applies nothing ([`Applied::NotWired`]): the
/// bench's copy of what its master's sink got ([`Recorded`]), and the update server's tests' sink. A handle: the
/// records outlive a reboot of the master.
#[derive(Debug, Clone, Default)]
pub struct UpdateRecorder(Rc<RefCell<Vec<ReceivedImage>>>);

impl UpdateRecorder {
    /// Every image so far, oldest first.
    pub fn images(&self) -> Vec<ReceivedImage> {
        self.0.borrow().clone()
    }
}

impl UpdateSink for UpdateRecorder {
    fn begin(&mut self, target: UpdateTarget, header: &ImageHeader) -> Result<(), Refused> {
        self.0.borrow_mut().push(ReceivedImage {
            target,
            bytes: header.bytes.to_vec(),
            complete: None,
            applied: 0,
        });
        Ok(())
    }

    fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), Refused> {
        let mut images = self.0.borrow_mut();
        match images.last_mut() {
            // The server hands on the bytes in order: anything else is its bug, refused here for a test to see.
            Some(image) if image.complete.is_none() && image.bytes.len() as u64 == u64::from(offset) => {
                image.bytes.extend_from_slice(data);
                Ok(())
            }
            _ => Err(Refused::Because("out of order")),
        }
    }

    fn finish(&mut self, complete: bool) -> Result<(), Refused> {
        match self.0.borrow_mut().last_mut() {
            Some(image) if image.complete.is_none() => {
                image.complete = Some(complete);
                Ok(())
            }
            _ => Err(Refused::Because("finished twice")),
        }
    }

    fn apply(&mut self, target: UpdateTarget, _: Sender) -> Result<Applied, Nak> {
        let mut images = self.0.borrow_mut();
        match images
            .iter_mut()
            .rev()
            .find(|image| image.target == target && image.complete == Some(true))
        {
            Some(image) => {
                image.applied += 1;
                Ok(Applied::NotWired)
            }
            None => Err(Nak::Fail),
        }
    }
}

/// A sink whose images are also recorded: `sink` answers, `recorder` keeps a copy of everything it is given.
#[derive(Debug, Clone)]
pub struct Recorded<S> {
    /// Keeps the copy.
    pub recorder: UpdateRecorder,
    /// Takes the images.
    pub sink: S,
}

impl<S: UpdateSink> UpdateSink for Recorded<S> {
    async fn ready(&mut self) {
        self.sink.ready().await;
    }

    fn begin(&mut self, target: UpdateTarget, header: &ImageHeader) -> Result<(), Refused> {
        let _ = self.recorder.begin(target, header);
        self.sink.begin(target, header)
    }

    fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), Refused> {
        let _ = self.recorder.write(offset, data);
        self.sink.write(offset, data)
    }

    fn finish(&mut self, complete: bool) -> Result<(), Refused> {
        let _ = self.recorder.finish(complete);
        self.sink.finish(complete)
    }

    fn apply(&mut self, target: UpdateTarget, from: Sender) -> Result<Applied, Nak> {
        let _ = self.recorder.apply(target, from);
        self.sink.apply(target, from)
    }

    fn query_version(&mut self, slot: u8, from: Sender) -> Result<(), Refused> {
        self.sink.query_version(slot, from)
    }

    fn publish(&self, holds: &UpdateHolds) {
        self.sink.publish(holds);
    }

    fn boards(&self, versions: &mut Versions) {
        self.sink.boards(versions);
    }
}
