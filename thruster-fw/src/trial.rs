//! A new image on trial. The bootloader (lbv-boot, embassy-boot) swaps a new image in and starts it on trial:
//! until the image confirms itself, any reset (the watchdog's, a brown-out, a power cut) swaps the previous image
//! back. The image confirms only once it has shown that it works here: [`TRIAL_ROUNDS`] watchdog rounds in which
//! every task reported (counted since start; a task that stops for good is a watchdog reset), [`TRIAL_ORDERS`]
//! orders from the master taken and answered, and a reply to the field-update extension read by the master (which
//! asks an image on trial its `Version` every few seconds): the path the next update takes works, so an image that
//! confirms can always be replaced over the bus. It confirms while the master orders zero, since writing the
//! bootloader's state erases a flash page, which stalls the CPU (commutation included) for as long as the erase
//! takes (22 ms typical, DS12589 Table 41, flash memory characteristics).

use embassy_time::{Duration, Ticker, Timer};

use crate::control::LinkUpdate;
use crate::drive::Duty;
use crate::ports::BootState;
use crate::shared::Shared;

/// An image the bootloader did not start on trial (or no bootloader at all): nothing to confirm.
#[derive(Debug, Clone, Copy, Default)]
pub struct Confirmed;

impl BootState for Confirmed {
    type Error = core::convert::Infallible;

    async fn on_trial(&mut self) -> Result<bool, Self::Error> {
        Ok(false)
    }

    async fn confirm(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// Complete watchdog rounds (every task reported, the watchdog fed) the image must run before it confirms: 3 s at
/// the reference's 100 ms feed.
pub const TRIAL_ROUNDS: u32 = 30;

/// Valid orders from the master the image must take before it confirms: half a second of the master's 50 Hz poll.
pub(crate) const TRIAL_ORDERS: u32 = 25;

/// How often the trial looks at its conditions.
pub const TRIAL_CHECK: Duration = Duration::from_millis(100);

/// How long a failed confirmation waits before the next attempt.
pub(crate) const CONFIRM_RETRY: Duration = Duration::from_secs(1);

/// Whether an image on trial has shown enough to confirm: `rounds` complete watchdog rounds, the master's orders,
/// an extension reply `answered`, and the motor at rest by order and by duty.
pub(crate) fn may_confirm(rounds: u32, link: Option<LinkUpdate>, answered: bool, duty: Duty) -> bool {
    let Some(link) = link else {
        return false;
    };
    rounds >= TRIAL_ROUNDS
        && link.orders >= TRIAL_ORDERS
        && answered
        && link.order.speed.is_zero()
        && duty == Duty::ZERO
}

/// The trial: if the image is on trial, confirm it once [`may_confirm`] holds. An image that never gets there
/// (a task that stops, a master it cannot answer) stays on trial, and the next reset reverts it.
pub(crate) async fn trial_task<B: BootState>(boot: &mut B, shared: &Shared) -> ! {
    match boot.on_trial().await {
        Ok(true) => {
            shared.replies.set_on_trial(true);
            info!("image on trial: it confirms itself once it has run and answered the master");
            let mut ticker = Ticker::every(TRIAL_CHECK);
            loop {
                ticker.next().await;
                let (link, duty) = (shared.link.try_get(), shared.duty.try_get().unwrap_or(Duty::ZERO));
                if !may_confirm(shared.health.rounds(), link, shared.replies.answered(), duty) {
                    continue;
                }
                match boot.confirm().await {
                    Ok(()) => {
                        info!("image confirmed: the bootloader keeps it");
                        shared.replies.set_on_trial(false);
                        break;
                    }
                    Err(_) => {
                        warn!("the bootloader's state could not be written: trying again");
                        Timer::after(CONFIRM_RETRY).await;
                    }
                }
            }
        }
        Ok(false) => shared.replies.set_on_trial(false),
        Err(_) => {
            // Fail closed: DFU may hold the image a revert needs, so no update may begin over it.
            shared.replies.set_on_trial(true);
            warn!("the bootloader's state could not be read: the image is not confirmed, and takes no update");
        }
    }
    // Nothing more to do; like the other tasks, it never ends.
    match core::future::pending::<core::convert::Infallible>().await {}
}

#[cfg(test)]
mod tests {
    use embassy_futures::poll_once;

    use super::*;

    /// A state partition that cannot be read.
    struct Unreadable;

    impl BootState for Unreadable {
        type Error = ();

        async fn on_trial(&mut self) -> Result<bool, ()> {
            Err(())
        }

        async fn confirm(&mut self) -> Result<(), ()> {
            Err(())
        }
    }

    #[test]
    fn an_image_whose_state_cannot_be_read_takes_no_update_as_if_on_trial() {
        let shared = Shared::new();
        assert!(shared.replies.on_trial(), "until the state is read");
        let _ = poll_once(trial_task(&mut Unreadable, &shared));
        assert!(shared.replies.on_trial(), "fails closed");
        let shared = Shared::new();
        let _ = poll_once(trial_task(&mut Confirmed, &shared));
        assert!(!shared.replies.on_trial(), "read, and not on trial");
    }
}
