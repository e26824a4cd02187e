//! The settings kept across power cycles (the parameters and the signing key, [`Settings`]) in flash pages the
//! image does not use, and the task that keeps them there and restarts the master when asked.
//!
//! The store is sequential-storage's map, made for NOR flash: every change appends one small item (a header with
//! its own CRC, the data with another) to the current page; pages are used in turn and erased only when the map
//! moves on (wear levelling). An item cut short by a power loss fails its CRC and is ignored at the next start,
//! so a power cut during a write loses that write and nothing before it.
//!
//! Items, keyed by one byte: each parameter under its index (an `i32` in the parameter's own unit), the signing
//! key (secret and set-up timestamp, 40 bytes; all zero: signing off) and the signing link's timestamp (stored at
//! most once a minute while it advances, so a restart does not reopen the door to old signed frames). A stored
//! value that is not valid for its parameter (a newer or older image) reads as the default.
//!
//! The flash is a port: embedded-storage-async's `NorFlash`, which the STM32 binding implements over
//! embassy-stm32's flash driver and the host tests over sequential-storage's fault-injecting mock flash.

use core::ops::Range;

use embassy_futures::select::{Either3, select3};
use embedded_storage_async::nor_flash::NorFlash;
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::map::{MapConfig, MapStorage};

use crate::params::{Param, Settings};
use crate::shared::{Severity, Shared, text};
use crate::signing::SigningKey;

/// The STM32G431RB's flash kept for the settings, as offsets from the start of flash: its top 16 KiB, eight of
/// the 2 KiB pages of its single bank (RM0440 3.3.1, category 2 devices). `memory.x` keeps the images below.
pub const G431_STORAGE: Range<u32> = 0x1_C000..0x2_0000;

/// Restarts the master: a system reset on the STM32; the bench restarts the core with its flash kept.
pub trait Reboot {
    /// Restart now (on the STM32 this does not return).
    fn reboot(&mut self);
}

/// The signing key's item: the secret, then the set-up timestamp (little-endian).
const SIGNING_KEY: u8 = 0x40;
/// The signing link's timestamp item.
const SIGNING_TIME: u8 = 0x41;
/// The signing key item's size.
const KEY_ITEM: usize = 40;

/// Room for the largest item (its key and the 40-byte signing key, rounded up to 8-byte flash words), aligned as
/// flash drivers like their write buffers.
#[repr(align(8))]
#[derive(Debug)]
struct Buffer([u8; 64]);

/// Why a write did not reach the flash.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum StoreError {
    /// The flash reported an error (or the power was cut, in the tests).
    Flash,
    /// The store is full (it keeps one page free, so this means the items outgrew it).
    Full,
    /// The store found itself corrupt and could not repair it.
    Corrupt,
}

impl<E> From<sequential_storage::Error<E>> for StoreError {
    fn from(error: sequential_storage::Error<E>) -> Self {
        match error {
            sequential_storage::Error::Storage { .. } => Self::Flash,
            sequential_storage::Error::FullStorage => Self::Full,
            _ => Self::Corrupt,
        }
    }
}

type NoCache = Cache<Uncached, Uncached, Uncached, u8>;

/// The settings store on a NOR flash.
pub struct Store<F: NorFlash> {
    map: MapStorage<u8, F, NoCache>,
    buffer: Buffer,
    /// Items that could not be read at start-up (they read as defaults).
    read_errors: u32,
}

impl<F: NorFlash> core::fmt::Debug for Store<F> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Store")
            .field("read_errors", &self.read_errors)
            .finish_non_exhaustive()
    }
}

impl<F: NorFlash> Store<F> {
    /// The store in `range` of `flash`; `None` unless the range is whole erase pages, at least two of them.
    pub fn new(flash: F, range: Range<u32>) -> Option<Self> {
        let config = MapConfig::try_new(range).ok()?;
        Some(Self {
            map: MapStorage::new(flash, config, Cache::new_uncached()),
            buffer: Buffer([0; 64]),
            read_errors: 0,
        })
    }

    /// The flash back (the tests power-cycle it).
    pub fn into_flash(self) -> F {
        self.map.destroy().0
    }

    /// Items that could not be read at start-up.
    pub fn read_errors(&self) -> u32 {
        self.read_errors
    }

    /// The stored settings, item by item over `defaults` (what is missing, unreadable or invalid stays default).
    pub async fn load(&mut self, defaults: Settings) -> Settings {
        let mut settings = defaults;
        for param in Param::ALL {
            if let Some(value) = self
                .fetch(param.index() as u8)
                .await
                .and_then(|item| item.first_chunk().copied())
            {
                settings.params.set(param, i32::from_le_bytes(value));
            }
        }
        let key = self.fetch(SIGNING_KEY).await.and_then(|item| key_from_item(&item));
        let time = self
            .fetch(SIGNING_TIME)
            .await
            .and_then(|item| item.first_chunk().copied());
        settings.signing = key.map(|key| SigningKey {
            timestamp: key.timestamp.max(time.map_or(0, u64::from_le_bytes)),
            ..key
        });
        settings
    }

    /// The item stored under `key`, zero-padded to the largest item's size; an unreadable one is counted. (One
    /// fetch of raw bytes for every item type keeps one copy of the store's read code in the image.)
    async fn fetch(&mut self, key: u8) -> Option<[u8; KEY_ITEM]> {
        match self.map.fetch_item::<&[u8]>(&mut self.buffer.0, &key).await {
            Ok(item) => item.map(|bytes| {
                let mut out = [0; KEY_ITEM];
                for (slot, byte) in out.iter_mut().zip(bytes) {
                    *slot = *byte;
                }
                out
            }),
            Err(_) => {
                self.read_errors += 1;
                None
            }
        }
    }

    /// Write what differs between `stored` (what the flash holds) and `settings`, one item per change.
    pub async fn save(&mut self, stored: &Settings, settings: &Settings) -> Result<(), StoreError> {
        for param in Param::ALL {
            let value = settings.params.get(param);
            if value != stored.params.get(param) {
                let index = param.index() as u8;
                self.map.store_item(&mut self.buffer.0, &index, &value).await?;
            }
        }
        if settings.signing != stored.signing {
            let item = key_item(settings.signing);
            self.map.store_item(&mut self.buffer.0, &SIGNING_KEY, &item).await?;
        }
        Ok(())
    }

    /// Store the signing link's timestamp.
    pub async fn save_signing_time(&mut self, timestamp: u64) -> Result<(), StoreError> {
        self.map
            .store_item(&mut self.buffer.0, &SIGNING_TIME, &timestamp)
            .await?;
        Ok(())
    }
}

fn key_item(key: Option<SigningKey>) -> [u8; KEY_ITEM] {
    let mut item = [0; KEY_ITEM];
    if let Some(key) = key {
        let (secret, timestamp) = item.split_at_mut(32);
        secret.copy_from_slice(&key.secret);
        timestamp.copy_from_slice(&key.timestamp.to_le_bytes());
    }
    item
}

fn key_from_item(item: &[u8; KEY_ITEM]) -> Option<SigningKey> {
    let (secret, timestamp) = item.split_first_chunk::<32>()?;
    let timestamp = u64::from_le_bytes(*timestamp.first_chunk::<8>()?);
    (*secret != [0; 32]).then_some(SigningKey {
        secret: *secret,
        timestamp,
    })
}

/// Keep the settings in `store`: write each change the vehicle publishes (`shared.settings`) and the signing
/// link's timestamp (`shared.signing_time`); when the reboot's acknowledgement is out (`shared.reboot`), finish
/// writing and restart through `reboot`. `stored` is what [`Store::load`] returned. A write that fails is
/// reported on the console (Warning) and retried with the next change.
pub async fn settings_task<F: NorFlash, R: Reboot>(
    store: &mut Store<F>,
    mut stored: Settings,
    shared: &Shared,
    reboot: &mut R,
) -> ! {
    let mut settings = shared.settings.receiver();
    let mut signing_time = shared.signing_time.receiver();
    loop {
        let changed = async {
            match settings.as_mut() {
                Some(receiver) => receiver.changed().await,
                None => core::future::pending().await,
            }
        };
        let timestamp = async {
            match signing_time.as_mut() {
                Some(receiver) => receiver.changed().await,
                None => core::future::pending().await,
            }
        };
        match select3(changed, timestamp, shared.reboot.wait()).await {
            Either3::First(new) => {
                if save(store, &stored, &new, shared).await {
                    stored = new;
                }
            }
            Either3::Second(timestamp) => {
                if store.save_signing_time(timestamp).await.is_err() {
                    shared.say(Severity::Warning, text(format_args!("Signing time not saved")));
                }
            }
            Either3::Third(()) => {
                if let Some(new) = settings.as_mut().and_then(|receiver| receiver.try_changed()) {
                    save(store, &stored, &new, shared).await;
                }
                reboot.reboot();
            }
        }
    }
}

/// Write `new` over `stored`; whether it all reached the flash.
async fn save<F: NorFlash>(store: &mut Store<F>, stored: &Settings, new: &Settings, shared: &Shared) -> bool {
    match store.save(stored, new).await {
        Ok(()) => true,
        Err(error) => {
            let why = match error {
                StoreError::Flash => "flash error",
                StoreError::Full => "store full",
                StoreError::Corrupt => "store corrupt",
            };
            shared.say(Severity::Warning, text(format_args!("Settings not saved: {why}")));
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mixer::FrameKind;
    use embassy_futures::block_on;
    use embassy_futures::select::{Either, select};
    use embassy_futures::yield_now;
    use sequential_storage::mock_flash::{MockFlashBase, WriteCountCheck};

    /// The G431's storage pages: eight of 2 KiB, written in 8-byte double words, each word once between erases
    /// (its flash has ECC).
    type Flash = MockFlashBase<8, 8, 256>;
    const RANGE: Range<u32> = 0..(8 * 2048);

    fn flash() -> Flash {
        Flash::new(WriteCountCheck::OnceOnly, None, true)
    }

    fn defaults() -> Settings {
        Settings::defaults(FrameKind::Lbv300_6)
    }

    fn load(flash: &mut Flash) -> (Settings, u32) {
        let mut store = Store::new(flash, RANGE).unwrap();
        let settings = block_on(store.load(defaults()));
        (settings, store.read_errors())
    }

    fn save(flash: &mut Flash, stored: &Settings, new: &Settings) -> Result<(), StoreError> {
        let mut store = Store::new(flash, RANGE).unwrap();
        block_on(store.save(stored, new))
    }

    fn with(change: impl FnOnce(&mut Settings)) -> Settings {
        let mut settings = defaults();
        change(&mut settings);
        settings
    }

    #[test]
    fn the_storage_pages_are_memory_x_s() {
        // memory.x keeps the images out of the top 16 KiB; the store uses exactly that.
        let memory_x = include_str!("../../memory.x");
        let line = |name: &str| {
            memory_x
                .lines()
                .find(|line| line.trim_start().starts_with(name))
                .unwrap_or_else(|| panic!("memory.x has no {name} region"))
                .to_owned()
        };
        assert!(
            line("FLASH").contains("ORIGIN = 0x08000000, LENGTH = 112K"),
            "{}",
            line("FLASH")
        );
        assert!(
            line("STORAGE").contains("ORIGIN = 0x0801C000, LENGTH = 16K"),
            "{}",
            line("STORAGE")
        );
        assert_eq!(G431_STORAGE, 0x1_C000..0x1_C000 + 16 * 1024);
        assert_eq!((G431_STORAGE.end - G431_STORAGE.start) % 2048, 0, "whole 2 KiB pages");
        assert_eq!(G431_STORAGE.end, 128 * 1024, "the top of the 128 KiB flash");
    }

    #[test]
    fn a_bad_range_is_refused() {
        let mut flash = flash();
        assert!(Store::new(&mut flash, 0..2048).is_none(), "one page");
        assert!(Store::new(&mut flash, 100..4196).is_none(), "not page aligned");
        assert!(Store::new(&mut flash, 0..4096).is_some());
    }

    #[test]
    fn blank_flash_reads_as_the_defaults() {
        let mut blank = flash();
        assert_eq!(load(&mut blank), (defaults(), 0));
        let mut flash = flash();
        let mut store = Store::new(&mut flash, RANGE).unwrap();
        let other = Settings::defaults(FrameKind::Lbv200_4);
        assert_eq!(block_on(store.load(other)), other);
    }

    #[test]
    fn what_is_saved_survives_a_power_cycle() {
        let mut flash = flash();
        let new = with(|s| {
            s.params.set(Param::Gain, 80);
            s.params.set(Param::GcsTimeout, 33);
            s.params.set(Param::Frame, 4);
            s.signing = Some(SigningKey {
                secret: [0x5A; 32],
                timestamp: 123_456,
            });
        });
        save(&mut flash, &defaults(), &new).unwrap();
        assert_eq!(load(&mut flash), (new, 0));
        // Only the changes are written: saving the same again writes nothing.
        let before = flash.stats_snapshot();
        save(&mut flash, &new, &new).unwrap();
        assert_eq!(before.compare_to(flash.stats_snapshot()).writes, 0);
        // The signing time is kept with the key; the later of the two is the link's start.
        block_on(Store::new(&mut flash, RANGE).unwrap().save_signing_time(999_999)).unwrap();
        assert_eq!(load(&mut flash).0.signing.map(|k| k.timestamp), Some(999_999));
        // Signing off: an all-zero key.
        let off = Settings { signing: None, ..new };
        save(&mut flash, &new, &off).unwrap();
        assert_eq!(load(&mut flash).0, off);
    }

    #[test]
    fn a_stored_value_out_of_range_reads_as_the_default() {
        let mut flash = flash();
        {
            let mut store = Store::new(&mut flash, RANGE).unwrap();
            let mut plant = |param: Param, value: i32| {
                block_on(
                    store
                        .map
                        .store_item(&mut store.buffer.0, &(param.index() as u8), &value),
                )
                .unwrap();
            };
            plant(Param::Gain, 1000);
            plant(Param::PowerCap, 70);
        }
        let (settings, errors) = load(&mut flash);
        assert_eq!(settings.params.gain_percent(), 50);
        assert_eq!(settings.params.power_cap_percent(), 70);
        assert_eq!(errors, 0);
    }

    #[test]
    fn many_changes_wear_every_page_and_the_last_value_wins() {
        let mut flash = flash();
        let start = flash.stats_snapshot();
        let mut stored = defaults();
        // Enough writes to go round the eight pages several times.
        for n in 0..3000 {
            let new = with(|s| {
                s.params.set(Param::Gain, 1 + n % 100);
                s.params.set(Param::PowerCap, 100 - n % 100);
            });
            save(&mut flash, &stored, &new).unwrap();
            stored = new;
        }
        assert_eq!(load(&mut flash), (stored, 0));
        let erases = start.compare_to(flash.stats_snapshot()).erases;
        assert!(erases >= 16, "pages were reused ({erases} erases)");
    }

    /// Cut the power during one write, in a store `fill` writes full, and check that the next start finds every
    /// earlier value and the interrupted one either old or new, and that the store still works. The power is cut
    /// after every byte of the writes, and after every 16th byte of a page erase. Returns the bytes the write
    /// takes (erased and written).
    fn power_cut_during_a_write(fill: u32) -> u32 {
        let mut flash = flash();
        let mut stored = defaults();
        for n in 0..fill {
            let new = with(|s| {
                s.params.set(Param::Gain, 1 + (n % 100) as i32);
            });
            save(&mut flash, &stored, &new).unwrap();
            stored = new;
        }
        let earlier = with(|s| {
            *s = stored;
            s.signing = Some(SigningKey {
                secret: [1; 32],
                timestamp: 42,
            });
        });
        save(&mut flash, &stored, &earlier).unwrap();
        let target = with(|s| {
            *s = earlier;
            s.params.set(Param::GcsTimeout, 77);
        });
        let total = {
            let mut uncut = flash.clone();
            uncut.bytes_until_shutoff = Some(u32::MAX);
            save(&mut uncut, &earlier, &target).unwrap();
            u32::MAX - uncut.bytes_until_shutoff.unwrap()
        };
        let erase = if total > 2048 { 0..2048 } else { 0..0 };
        for cut_at in (0..=total).filter(|n| !erase.contains(n) || n % 16 == 0) {
            let mut cut = flash.clone();
            cut.bytes_until_shutoff = Some(cut_at);
            let result = save(&mut cut, &earlier, &target);
            let completed = cut.bytes_until_shutoff.is_some();
            // Power back: the cut-off flag is gone, the flash holds what was written.
            cut.bytes_until_shutoff = None;
            let (after, _) = load(&mut cut);
            let timeout = after.params.get(Param::GcsTimeout);
            assert!(
                timeout == 50 || timeout == 77,
                "fill {fill}, cut after {cut_at} bytes: {timeout}"
            );
            let mut expected = earlier;
            expected.params.set(Param::GcsTimeout, timeout);
            assert_eq!(
                after, expected,
                "fill {fill}, cut after {cut_at} bytes: only the interrupted write may be lost"
            );
            if completed {
                assert_eq!(cut_at, total);
                assert_eq!(result, Ok(()));
                assert_eq!(after, target);
                continue;
            }
            assert_eq!(result, Err(StoreError::Flash));
            // And the store goes on working.
            let next = with(|s| {
                *s = after;
                s.params.set(Param::PowerCap, 55);
            });
            save(&mut cut, &after, &next).unwrap();
            assert_eq!(load(&mut cut).0, next, "fill {fill}, cut after {cut_at} bytes");
        }
        total
    }

    #[test]
    fn a_power_cut_during_a_write_loses_at_most_that_write() {
        // One item: an 8-byte header and the key and value in one 8-byte word.
        assert_eq!(power_cut_during_a_write(0), 16);
    }

    #[test]
    fn a_power_cut_while_the_store_moves_to_a_new_page_loses_at_most_that_write() {
        // After 123 one-item writes (and the key's), the interrupted write closes its page and opens the next:
        // two page markers more. After 885, the store has gone round and must erase a page first (2048 bytes).
        assert_eq!(power_cut_during_a_write(123), 32, "the write that moves to a new page");
        assert_eq!(
            power_cut_during_a_write(885),
            2048 + 32,
            "the write that erases a page first"
        );
    }

    struct Restart(std::rc::Rc<core::cell::Cell<u32>>);

    impl Reboot for Restart {
        fn reboot(&mut self) {
            self.0.set(self.0.get() + 1);
        }
    }

    #[test]
    fn the_task_writes_changes_and_restarts_after_the_last_write() {
        let shared = Shared::new();
        let mut flash = flash();
        let restarts = std::rc::Rc::new(core::cell::Cell::new(0));
        let mut reboot = Restart(restarts.clone());
        let changed = with(|s| {
            s.params.set(Param::OperatorId, 200);
        });
        {
            let mut store = Store::new(&mut flash, RANGE).unwrap();
            let stored = block_on(store.load(defaults()));
            let script = async {
                let settings = shared.settings.sender();
                settings.send(stored);
                for _ in 0..4 {
                    yield_now().await;
                }
                settings.send(changed);
                shared.signing_time.sender().send(7_000_000);
                for _ in 0..4 {
                    yield_now().await;
                }
                // A last change and the reboot at once: the change is written first.
                settings.send(with(|s| {
                    *s = changed;
                    s.params.set(Param::Gain, 99);
                }));
                shared.reboot.signal(());
                for _ in 0..4 {
                    yield_now().await;
                }
                assert_eq!(restarts.get(), 1);
            };
            match block_on(select(settings_task(&mut store, stored, &shared, &mut reboot), script)) {
                Either::First(never) => match never {},
                Either::Second(()) => {}
            }
        }
        let (after, _) = load(&mut flash);
        assert_eq!(after.params.operator(), 200);
        assert_eq!(after.params.gain_percent(), 99);
        assert!(shared.outbox.try_receive().is_err(), "no warning");
    }

    #[test]
    fn a_failed_write_is_reported_on_the_console() {
        let shared = Shared::new();
        let mut flash = flash();
        flash.bytes_until_shutoff = Some(3);
        let mut reboot = Restart(Default::default());
        let mut store = Store::new(&mut flash, RANGE).unwrap();
        let script = async {
            shared.settings.sender().send(with(|s| {
                s.params.set(Param::Gain, 10);
            }));
            for _ in 0..4 {
                yield_now().await;
            }
        };
        match block_on(select(
            settings_task(&mut store, defaults(), &shared, &mut reboot),
            script,
        )) {
            Either::First(never) => match never {},
            Either::Second(()) => {}
        }
        assert!(matches!(
            shared.outbox.try_receive(),
            Ok(crate::shared::Outgoing::Text(Severity::Warning, text)) if text.starts_with("Settings not saved")
        ));
    }
}
