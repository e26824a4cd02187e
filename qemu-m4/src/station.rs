//! The ground station at the console link's other end: lbv-station's, as the operator (QGroundControl's
//! identity). What is qemu-m4's is the plumbing: the console's in-memory link, and the bench's meter on both tasks.

use embassy_futures::select::select;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_sync::signal::Signal;
use embassy_time::{Instant, Timer};
use lbv_station::{GroundStation, OPERATOR, Seen};

use crate::executors::BENCH_METER;
use crate::master::{DOWNLINK, UPLINK};
use crate::meter::metered;

/// The station. A mutex that holds no critical section while it is held: the reader parses a whole chunk of the
/// downlink under it, and a critical section that long would hold off the hall-edge interrupt.
static STATION: Mutex<CriticalSectionRawMutex, GroundStation> = Mutex::new(GroundStation::with_system(OPERATOR));
/// The station's schedule may have changed: the transmit task looks at it again.
static RESCHEDULE: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// Use the station: build a frame, look at what it has seen. (Nobody holds it across an await.)
pub async fn with<R>(use_it: impl FnOnce(&mut GroundStation) -> R) -> R {
    use_it(&mut *STATION.lock().await)
}

/// What the station has seen.
pub async fn seen<R>(look: impl FnOnce(&Seen) -> R) -> R {
    with(|station| look(&station.seen)).await
}

/// Change what the station sends by itself (its sticks, whether it is connected).
pub async fn change(change: impl FnOnce(&mut GroundStation)) {
    with(change).await;
    RESCHEDULE.signal(());
}

/// Send frames to the master.
pub async fn send(frames: &[u8]) {
    UPLINK.write_all(frames).await;
}

/// Send what the station's schedule says when it says it: heartbeats, and the sticks while they are held.
#[embassy_executor::task]
pub async fn transmit() -> ! {
    metered(&BENCH_METER, None, send_when_due()).await
}

async fn send_when_due() -> ! {
    loop {
        let (frames, next) = with(|station| (station.periodic(Instant::now()), station.next_due())).await;
        send(&frames).await;
        let changed = RESCHEDULE.wait();
        match next {
            Some(at) => {
                select(Timer::at(at), changed).await;
            }
            None => changed.await,
        }
    }
}

/// Read everything the master sends.
#[embassy_executor::task]
pub async fn receive() -> ! {
    metered(&BENCH_METER, None, read_downlink()).await
}

async fn read_downlink() -> ! {
    let mut buffer = [0u8; 128];
    loop {
        let n = DOWNLINK.read(&mut buffer).await;
        let bytes = buffer.get(..n).unwrap_or_default();
        with(|station| station.receive(Instant::now(), bytes)).await;
    }
}
