//! The thruster buses: their speed and timeout ([`BusConfig`]), and clearing one that is stuck.
//!
//! A slave reset or disturbed in the middle of a byte it was sending can be left holding SDA low, waiting for
//! clocks the master will never send: no START can be made and every transfer fails. UM10204 3.1.16: clock SCL
//! (up to nine times, enough for the rest of a byte and its ACK) until the slave lets SDA go, then send a STOP.
//! [`clear_bus`] does that on two open-drain pins; the binding lends it the bus's pins (and re-initialises its I2C
//! peripheral afterwards), the bench its simulated lines.

use embassy_time::Duration;
use embedded_hal::digital::{InputPin, OutputPin};
use embedded_hal_async::delay::DelayNs;
use embedded_hal_async::i2c::{ErrorType, I2c, Operation};

use crate::ports::BusRecovery;

/// A thruster bus: its clock, and how long a transfer may stall before the master gives up on it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct BusConfig {
    /// SCL frequency, Hz.
    pub frequency_hz: u32,
    /// A transfer stalled this long (SCL held low) is abandoned with a timeout; embassy-stm32's default is 1 s.
    pub timeout: Duration,
}

impl BusConfig {
    /// IDS 6.4.1: the motherboard is a 100 kbit/s I2C master. SMBus's SCL-low timeout, 25 ms, bounds a stalled
    /// transfer.
    pub(crate) const THRUSTERS: BusConfig = BusConfig {
        frequency_hz: 100_000,
        timeout: Duration::from_millis(25),
    };

    /// Half an SCL period, ns: the bus recovery clocks SCL at the bus's own speed.
    pub(crate) const fn half_period_ns(&self) -> u32 {
        let hz = if self.frequency_hz == 0 { 1 } else { self.frequency_hz };
        500_000_000 / hz
    }
}

/// Most SCL clocks a recovery sends: a byte and its ACK.
pub(crate) const MAX_CLOCKS: u8 = 9;

/// UM10204 3.1.16 on two open-drain pins: release both lines; while SDA reads low, clock SCL (low, then high, half
/// a bus period each), at most [`MAX_CLOCKS`] times; then a STOP (SDA low, SCL high, SDA high). Returns whether
/// SDA reads high at the end. A pin that fails to switch or read counts as a bus still stuck.
pub async fn clear_bus<Scl, Sda, D>(scl: &mut Scl, sda: &mut Sda, delay: &mut D, bus: &BusConfig) -> bool
where
    Scl: OutputPin,
    Sda: OutputPin + InputPin,
    D: DelayNs,
{
    let half = bus.half_period_ns();
    if scl.set_high().is_err() || sda.set_high().is_err() {
        return false;
    }
    delay.delay_ns(half).await;
    for _ in 0..MAX_CLOCKS {
        match sda.is_high() {
            Ok(true) => break,
            Ok(false) => {}
            Err(_) => return false,
        }
        if scl.set_low().is_err() {
            return false;
        }
        delay.delay_ns(half).await;
        if scl.set_high().is_err() {
            return false;
        }
        delay.delay_ns(half).await;
    }
    // STOP: SDA rises while SCL is high.
    if scl.set_low().is_err() || sda.set_low().is_err() {
        return false;
    }
    delay.delay_ns(half).await;
    if scl.set_high().is_err() {
        return false;
    }
    delay.delay_ns(half).await;
    if sda.set_high().is_err() {
        return false;
    }
    delay.delay_ns(half).await;
    sda.is_high().unwrap_or(false)
}

/// A bus made of an I2C master and the bus's two lines as GPIOs: transfers go to `i2c`, the recovery is
/// [`clear_bus`] on `scl` and `sda`. For ports whose lines can be driven while the I2C master is idle (the
/// simulated bus); the STM32 binding switches its pins between the peripheral and GPIO itself.
#[derive(Debug)]
pub struct PinRecovery<I, Scl, Sda, D> {
    pub i2c: I,
    /// SCL as an open-drain output.
    pub scl: Scl,
    /// SDA as an open-drain output that reads back the line.
    pub sda: Sda,
    /// Times the half periods.
    pub delay: D,
    /// The bus's speed, at which the recovery clocks SCL.
    pub bus: BusConfig,
}

impl<I: ErrorType, Scl, Sda, D> ErrorType for PinRecovery<I, Scl, Sda, D> {
    type Error = I::Error;
}

impl<I: I2c, Scl, Sda, D> I2c for PinRecovery<I, Scl, Sda, D> {
    async fn transaction(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), Self::Error> {
        self.i2c.transaction(address, operations).await
    }
}

impl<I, Scl: OutputPin, Sda: OutputPin + InputPin, D: DelayNs> BusRecovery for PinRecovery<I, Scl, Sda, D> {
    async fn recover(&mut self) -> bool {
        clear_bus(&mut self.scl, &mut self.sda, &mut self.delay, &self.bus).await
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::cell::{Cell, RefCell};
    use core::convert::Infallible;
    use embassy_time::{Delay, Instant};
    use lbv_sim::i2c::{Bus, Timing};
    use lbv_sim::{Executor, clock};

    const BUS: BusConfig = BusConfig::THRUSTERS;

    #[test]
    fn the_bus_runs_at_100_kbit_s_with_a_25_ms_timeout() {
        assert_eq!(BusConfig::THRUSTERS.frequency_hz, 100_000);
        assert_eq!(BusConfig::THRUSTERS.timeout, Duration::from_millis(25));
        assert_eq!(BusConfig::THRUSTERS.half_period_ns(), 5_000);
    }

    fn lines() -> Bus {
        Bus::new(Timing::new(BUS.frequency_hz, BUS.timeout))
    }

    /// Run the recovery on `bus` on virtual time; whether SDA came free and how long it took.
    fn recover(bus: &Bus) -> (bool, Duration) {
        let clock = clock::take();
        let freed = Cell::new(None);
        let (mut scl, mut sda) = (bus.scl(), bus.sda());
        let mut executor = Executor::new();
        executor.spawn(async {
            freed.set(Some(clear_bus(&mut scl, &mut sda, &mut Delay, &BUS).await));
        });
        let took = executor.run_until(&clock, Duration::from_millis(1), Duration::from_micros(1), || {
            freed.get().is_some()
        });
        (freed.get().unwrap_or(false), took.unwrap_or(Duration::MAX))
    }

    #[test]
    fn a_slave_holding_sda_for_up_to_nine_clocks_is_clocked_free_then_stopped() {
        for clocks in 1..=9 {
            let bus = lines();
            bus.hold_sda(clocks);
            let (freed, took) = recover(&bus);
            assert!(freed, "{clocks} clocks");
            let stats = bus.stats();
            assert_eq!(
                stats.pin_clocks,
                u64::from(clocks) + 1,
                "{clocks} to free it, and the STOP's"
            );
            assert_eq!(stats.pin_stops, 1);
            // Half periods of 5 us: the first, two per clock, three for the STOP.
            assert_eq!(took, Duration::from_micros(5 * (1 + 2 * u64::from(clocks) + 3)));
        }
    }

    #[test]
    fn a_free_bus_gets_only_the_stop_and_a_slave_needing_more_clocks_is_reported() {
        let bus = lines();
        let (freed, _) = recover(&bus);
        assert!(freed);
        assert_eq!((bus.stats().pin_clocks, bus.stats().pin_stops), (1, 1));

        // The STOP's own SCL pulse is a tenth clock: a slave needing ten lets go in time for the STOP.
        for clocks in [11, u32::MAX] {
            let bus = lines();
            bus.hold_sda(clocks);
            let (freed, _) = recover(&bus);
            assert!(!freed, "{clocks}");
            assert_eq!(bus.stats().pin_clocks, 10, "nine, then the STOP's");
            assert_eq!(bus.stats().pin_stops, 0, "no STOP with SDA held low");
        }
    }

    /// A pin that fails to read.
    struct Broken;

    impl embedded_hal::digital::ErrorType for Broken {
        type Error = embedded_hal::digital::ErrorKind;
    }

    impl OutputPin for Broken {
        fn set_low(&mut self) -> Result<(), Self::Error> {
            Ok(())
        }
        fn set_high(&mut self) -> Result<(), Self::Error> {
            Ok(())
        }
    }

    impl InputPin for Broken {
        fn is_high(&mut self) -> Result<bool, Self::Error> {
            Err(embedded_hal::digital::ErrorKind::Other)
        }
        fn is_low(&mut self) -> Result<bool, Self::Error> {
            Err(embedded_hal::digital::ErrorKind::Other)
        }
    }

    /// Every pin change, in order.
    struct Recorder<'a>(&'a RefCell<Vec<(&'static str, bool)>>, &'static str);

    impl embedded_hal::digital::ErrorType for Recorder<'_> {
        type Error = Infallible;
    }

    impl OutputPin for Recorder<'_> {
        fn set_low(&mut self) -> Result<(), Infallible> {
            self.0.borrow_mut().push((self.1, false));
            Ok(())
        }
        fn set_high(&mut self) -> Result<(), Infallible> {
            self.0.borrow_mut().push((self.1, true));
            Ok(())
        }
    }

    #[test]
    fn a_pin_that_cannot_be_read_is_a_bus_still_stuck() {
        let clock = clock::take();
        let changes = RefCell::new(Vec::new());
        let results = RefCell::new(Vec::new());
        let mut executor = Executor::new();
        executor.spawn(async {
            let mut scl = Recorder(&changes, "scl");
            let freed = clear_bus(&mut scl, &mut Broken, &mut Delay, &BUS).await;
            results.borrow_mut().push(freed);
        });
        executor.run_for(&clock, Duration::from_millis(1), Duration::from_micros(1));
        assert_eq!(*results.borrow(), [false]);
        assert_eq!(*changes.borrow(), [("scl", true)], "gave up at the first read");
        assert!(clock.now() > Instant::from_ticks(0));
    }
}
