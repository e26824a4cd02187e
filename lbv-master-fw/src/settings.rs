//! The settings kept across power cycles (the parameters and the signing key, [`Settings`]) in flash pages the
//! image does not use, and the task that keeps them there and restarts the master when asked.
//!
//! The store is sequential-storage's queue, made for NOR flash, used as a log of snapshots: every change appends
//! one record of all the settings (a header with its own CRC, the data with another) to the current page; pages
//! are used in turn and the oldest is erased only when the log comes round to it (wear levelling). At start-up
//! the newest whole record wins. A record cut short by a power loss fails its CRC and is ignored, so a power cut
//! during a write loses that write (all of it) and nothing before it.
//!
//! A record holds a format byte, the parameter count, each parameter (an `i32` in its own unit, by index), the
//! signing key (secret and set-up timestamp; all zero: signing off) and the signing link's reservation (a
//! timestamp ahead of every one used, stored at each start and about once a minute while the link advances, so a
//! restart does not reopen the door to old signed frames: [`crate::console::signing`]). A stored value that is not
//! valid for its parameter reads as the default, except two that images from before `LBV_GCS_NEUTRAL` (records of
//! fewer than 27 parameters) stored with another meaning (`migrate`). One record of everything (rather than one
//! item per setting, as sequential-storage's map keeps them) makes every change all or nothing, and the log's code
//! is no larger.
//!
//! Two ports ([`crate::ports`]): where the settings are kept ([`SettingsStore`]: [`Store`] over any
//! embedded-storage-async `NorFlash` — embassy-stm32's flash driver on the chip, lbv-sim's flash on the bench,
//! sequential-storage's fault-injecting mock in the tests — or, with no flash for them, [`InRam`]), and how the
//! master restarts ([`Reboot`]).

use core::ops::Range;

use embassy_futures::select::{Either, Either3, select, select3};
use embassy_time::{Duration, Timer};
use embedded_storage_async::nor_flash::NorFlash;
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::queue::{QueueConfig, QueueStorage};

use g431_hw::memory::{self, Span};

use crate::console::signing::SigningKey;
use crate::params::{PARAM_COUNT, Param, Params, Settings};
use crate::ports::{Reboot, SettingsStore, StoreError};
use crate::shared::{Severity, Shared, text};

/// The master's flash kept for the settings ([`memory::MASTER_STORAGE`]), as offsets from the start of flash: the
/// top 16 KiB of the STM32G474RE, eight 2 KiB pages of bank 2. `memory.x` keeps the images and DFU below.
pub(crate) const STORAGE: Range<u32> =
    memory::MASTER_STORAGE.origin - memory::FLASH_ORIGIN..memory::MASTER_STORAGE.end() - memory::FLASH_ORIGIN;

/// The pages the master keeps data in, for the binding's NMI handler ([`g431_hw::flash::nmi_action`]): the
/// settings, where a power cut can leave a torn double word that the store skips; the bootloader's state, its
/// record (the update's ticket, the bootloader's verdict and the told word, each read as a checked word that a torn
/// one is not) and DFU, which the field update writes and reads back.
pub const DATA_PAGES: [Span; 4] = [
    memory::MASTER_STORAGE,
    memory::MASTER_PARTITIONS.state,
    memory::MASTER_PARTITIONS.record,
    memory::MASTER_PARTITIONS.dfu,
];

/// Settings kept in RAM only, for a board with no flash set aside for them (the cores on an emulated Cortex-M4):
/// every start is from the defaults, and a save is accepted and forgotten.
#[derive(Debug, Clone, Copy, Default)]
pub struct InRam;

impl SettingsStore for InRam {
    async fn load(&mut self, defaults: Settings) -> Settings {
        defaults
    }

    async fn save(&mut self, _settings: &Settings) -> Result<(), StoreError> {
        Ok(())
    }

    async fn save_signing_time(&mut self, _timestamp: u64) -> Result<(), StoreError> {
        Ok(())
    }
}

/// The record's format; a record of another format is skipped.
const FORMAT: u8 = 1;
/// A record's length: format and parameter count, the parameters, the signing secret and its timestamp, the
/// signing link's timestamp.
const RECORD: usize = 2 + 4 * PARAM_COUNT + 32 + 8 + 8;

/// Room for a record, rounded up to 8-byte flash words, aligned as flash drivers like their write buffers.
#[repr(align(8))]
#[derive(Debug)]
struct Buffer([u8; RECORD.next_multiple_of(8)]);

impl<E> From<sequential_storage::Error<E>> for StoreError {
    fn from(error: sequential_storage::Error<E>) -> Self {
        match error {
            sequential_storage::Error::Storage { .. } => Self::Flash,
            _ => Self::Corrupt,
        }
    }
}

type NoCache = Cache<Uncached, Uncached, Uncached, ()>;

/// A record of `settings` and the signing link's `signing_time`.
fn encode(settings: &Settings, signing_time: u64) -> [u8; RECORD] {
    let mut out = [0; RECORD];
    let mut at = 0;
    let mut put = |bytes: &[u8]| {
        if let Some(slot) = out.get_mut(at..at + bytes.len()) {
            slot.copy_from_slice(bytes);
        }
        at += bytes.len();
    };
    put(&[FORMAT, PARAM_COUNT as u8]);
    for param in Param::ALL {
        put(&settings.params.get(param).to_le_bytes());
    }
    let key = settings.signing;
    put(&key.map_or([0; 32], |key| key.secret));
    put(&key.map_or(0, |key| key.timestamp).to_le_bytes());
    put(&signing_time.to_le_bytes());
    out
}

/// The settings (over `defaults`) and the signing link's timestamp of a record, or `None` when `bytes` is not a
/// whole record of this format. A record of fewer parameters, written by an image from before the last ones were
/// added (they are only ever added at the end), reads with those at their defaults: an update keeps the settings.
fn decode(bytes: &[u8], defaults: Settings) -> Option<(Settings, u64)> {
    let ([format, count], mut rest) = bytes.split_first_chunk::<2>()?;
    let count = usize::from(*count);
    if *format != FORMAT || count > PARAM_COUNT || rest.len() != RECORD - 2 - 4 * (PARAM_COUNT - count) {
        return None;
    }
    let mut take = |n: usize| {
        let (taken, left) = rest.split_at_checked(n)?;
        rest = left;
        Some(taken)
    };
    let mut settings = defaults;
    let before_gcs_neutral = count <= usize::from(Param::GcsNeutral.index());
    for param in Param::ALL.into_iter().take(count) {
        let value = i32::from_le_bytes(take(4)?.first_chunk::<4>().copied()?);
        if !settings.params.set(param, value) && before_gcs_neutral {
            migrate(&mut settings.params, param, value);
        }
    }
    let secret = take(32)?.first_chunk::<32>().copied()?;
    let key_time = u64::from_le_bytes(take(8)?.first_chunk::<8>().copied()?);
    let signing_time = u64::from_le_bytes(take(8)?.first_chunk::<8>().copied()?);
    settings.signing = (secret != [0; 32]).then_some(SigningKey {
        secret,
        timestamp: key_time,
    });
    Some((settings, signing_time))
}

/// A value an image from before `LBV_GCS_NEUTRAL` stored and this one refuses, read so that the vehicle does as it
/// did: `FS_GCS_ENABLE` 3 (neutral, not ArduSub's depth hold) is 1 with `LBV_GCS_NEUTRAL` 1; an `FS_PILOT_TIMEOUT`
/// above ArduSub's 3.0 s (those images took up to 10 s) is 3.0 s, the nearest it can be, the failsafe acting
/// sooner rather than later. Anything else stays default.
fn migrate(params: &mut Params, param: Param, value: i32) {
    match (param, value) {
        (Param::GcsFailsafe, 3) => {
            params.set(Param::GcsFailsafe, 1);
            params.set(Param::GcsNeutral, 1);
        }
        (Param::PilotTimeout, _) => {
            params.set(param, value.min(param.range().1));
        }
        _ => {}
    }
}

/// The settings store on a NOR flash.
pub struct Store<F: NorFlash> {
    queue: QueueStorage<F, NoCache>,
    buffer: Buffer,
    /// The record the flash holds (after [`Store::load`]).
    held: Option<[u8; RECORD]>,
    /// Records that could not be read at start-up.
    read_errors: u32,
    /// The flash is in the layout the pages are placed for ([`Store::set_layout_ok`]).
    layout_ok: bool,
}

impl<F: NorFlash> core::fmt::Debug for Store<F> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Store")
            .field("read_errors", &self.read_errors)
            .finish_non_exhaustive()
    }
}

impl<F: NorFlash> Store<F> {
    /// The store in `range` of `flash`; `None` unless the range is whole erase pages.
    #[cfg(test)]
    pub(crate) fn new(flash: F, range: Range<u32>) -> Option<Self> {
        let config = QueueConfig::try_new(range).ok()?;
        Some(Self {
            queue: QueueStorage::new(flash, config, Cache::new_uncached()),
            buffer: Buffer([0; RECORD.next_multiple_of(8)]),
            held: None,
            read_errors: 0,
            layout_ok: true,
        })
    }

    /// The store in the pages the master's layout leaves for it ([`STORAGE`]) of `flash`, the whole 512 KiB flash
    /// (its 2 KiB pages are checked when the image is built).
    pub const fn master(flash: F) -> Self {
        Self {
            queue: QueueStorage::new(flash, const { QueueConfig::new(STORAGE) }, Cache::new_uncached()),
            buffer: Buffer([0; RECORD.next_multiple_of(8)]),
            held: None,
            read_errors: 0,
            layout_ok: true,
        }
    }

    /// Whether the chip's flash is in the layout [`STORAGE`] is placed in, as the binding reads it at start
    /// (`g431_hw::flash::master_layout_ok`: the G474's dual-bank mode). When it is not, the store reads and
    /// refuses every write ([`StoreError::Layout`]): an erase there would land on other pages.
    pub fn set_layout_ok(&mut self, ok: bool) {
        self.layout_ok = ok;
    }

    /// The flash back (the tests power-cycle it).
    #[cfg(test)]
    pub(crate) fn into_flash(self) -> F {
        self.queue.destroy().0
    }

    /// Put a record in the aligned buffer, which flash drivers like to write from.
    fn stage(&mut self, record: [u8; RECORD]) {
        if let Some(staged) = self.buffer.0.first_chunk_mut::<RECORD>() {
            *staged = record;
        }
    }

    /// Append the staged record unless the flash holds it already. The oldest records go when the log comes
    /// round: only the newest counts.
    async fn write_staged(&mut self) -> Result<(), StoreError> {
        let Some(staged) = self.buffer.0.first_chunk::<RECORD>() else {
            return Ok(());
        };
        if self.held.as_ref() == Some(staged) {
            return Ok(());
        }
        if !self.layout_ok {
            return Err(StoreError::Layout);
        }
        self.queue.push(staged, true).await?;
        self.held = Some(*staged);
        Ok(())
    }
}

impl<F: NorFlash> SettingsStore for Store<F> {
    /// The signing key's timestamp is the later of the one it was set up with and the link's stored reservation:
    /// the floor of this start.
    async fn load(&mut self, defaults: Settings) -> Settings {
        let mut newest = None;
        match self.queue.iter().await {
            Ok(mut records) => loop {
                match records.next(&mut self.buffer.0).await {
                    Ok(Some(record)) => newest = decode(&record, defaults).or(newest),
                    Ok(None) => break,
                    Err(_) => {
                        self.read_errors += 1;
                        break;
                    }
                }
            },
            Err(_) => self.read_errors += 1,
        }
        let (mut settings, signing_time) = newest.unwrap_or((defaults, 0));
        if let Some(key) = settings.signing.as_mut() {
            key.timestamp = key.timestamp.max(signing_time);
        }
        // As the vehicle will publish them: nothing to write until they change.
        self.held = Some(encode(&settings, signing_time));
        settings
    }

    /// Nothing is written when the flash holds them already.
    async fn save(&mut self, settings: &Settings) -> Result<(), StoreError> {
        let signing_time = self.held.as_ref().map_or(0, signing_time_of);
        self.stage(encode(settings, signing_time));
        self.write_staged().await
    }

    /// Nothing is written before [`SettingsStore::load`].
    async fn save_signing_time(&mut self, timestamp: u64) -> Result<(), StoreError> {
        let Some(held) = self.held else {
            return Ok(());
        };
        self.stage(held);
        if let Some(slot) = self.buffer.0.get_mut(RECORD - 8..RECORD) {
            slot.copy_from_slice(&timestamp.to_le_bytes());
        }
        self.write_staged().await
    }

    fn read_errors(&self) -> u32 {
        self.read_errors
    }

    fn writes_refused(&self) -> bool {
        !self.layout_ok
    }
}

/// The signing link's timestamp in a record (its last 8 bytes).
fn signing_time_of(record: &[u8; RECORD]) -> u64 {
    record.last_chunk::<8>().copied().map_or(0, u64::from_le_bytes)
}

/// How long after a failed write of the signing reservation it is tried again.
pub(crate) const SIGNING_RETRY: Duration = Duration::from_secs(5);

/// Keep the settings in `store` (which has [`SettingsStore::load`]ed them): write each change the vehicle publishes
/// (`shared.settings`) and each signing reservation the console asks for (`shared.signing_time`), telling the
/// console once a reservation is in flash (`shared.signing_stored`); when the reboot's acknowledgement is out
/// (`shared.reboot`), finish writing and restart through `reboot`. A write that fails is reported on the console
/// (Warning); a settings change is retried with the next change, a reservation every [`SIGNING_RETRY`] until it
/// is stored (until then the console signs and accepts nothing beyond the last one), unless the flash's layout
/// refused it ([`StoreError::Layout`], which stands until a restart).
///
/// The settings' pages are in the G474's bank 2 and the code in bank 1, so a write or an erase runs beside the code
/// (RM0440 3.3.8): the thruster buses go on meanwhile.
pub async fn settings_task<S: SettingsStore, R: Reboot>(store: &mut S, shared: &Shared, reboot: &mut R) -> ! {
    let mut settings = shared.settings.receiver();
    let mut signing_time = shared.signing_time.receiver();
    let stored = shared.signing_stored.sender();
    let mut unsaved: Option<u64> = None;
    loop {
        let changed = async {
            match settings.as_mut() {
                Some(receiver) => {
                    receiver.changed().await;
                }
                None => core::future::pending().await,
            }
        };
        let asked = async {
            match signing_time.as_mut() {
                Some(receiver) => receiver.changed().await,
                None => core::future::pending().await,
            }
        };
        let retry = async {
            match unsaved {
                Some(reservation) => {
                    Timer::after(SIGNING_RETRY).await;
                    reservation
                }
                None => core::future::pending().await,
            }
        };
        let reservation = async {
            match select(asked, retry).await {
                Either::First(reservation) | Either::Second(reservation) => reservation,
            }
        };
        let result = match select3(changed, reservation, shared.reboot.wait()).await {
            Either3::First(()) => match shared.settings.try_get() {
                Some(new) => store.save(&new).await,
                None => Ok(()),
            },
            Either3::Second(reservation) => {
                let result = store.save_signing_time(reservation).await;
                // A refusal of the flash's layout stands until a restart: told once, not tried again.
                unsaved = (result.is_err() && result != Err(StoreError::Layout)).then_some(reservation);
                if result.is_ok() {
                    stored.send(reservation);
                }
                result
            }
            Either3::Third(()) => {
                if let Some(new) = settings.as_mut().and_then(|receiver| receiver.try_changed()) {
                    let _ = store.save(&new).await;
                }
                // A reservation asked for is stored before the restart: the next start's floor lies past it.
                let asked = signing_time.as_mut().and_then(|receiver| receiver.try_changed());
                if let Some(reservation) = asked.or(unsaved) {
                    let _ = store.save_signing_time(reservation).await;
                }
                reboot.reboot().await
            }
        };
        if let Err(error) = result {
            let why = match error {
                StoreError::Flash => "flash error",
                StoreError::Corrupt => "store corrupt",
                StoreError::Layout => crate::NOT_DUAL_BANK,
            };
            shared.say(Severity::Warning, text(format_args!("Settings not saved: {why}")));
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

    /// Power up: load what the flash holds.
    fn load(flash: &mut Flash) -> (Settings, u32) {
        let mut store = Store::new(flash, RANGE).unwrap();
        let settings = block_on(store.load(defaults()));
        (settings, store.read_errors())
    }

    /// Power up, then store `new`.
    fn save(flash: &mut Flash, new: &Settings) -> Result<(), StoreError> {
        let mut store = Store::new(flash, RANGE).unwrap();
        block_on(store.load(defaults()));
        block_on(store.save(new))
    }

    fn with(change: impl FnOnce(&mut Settings)) -> Settings {
        let mut settings = defaults();
        change(&mut settings);
        settings
    }

    #[test]
    fn the_storage_pages_are_the_layout_s() {
        // The image's memory layout (its memory.x) keeps the images out of the top 16 KiB; the store uses exactly
        // that.
        let layout = g431_hw::images::layout_of("lbv-master-fw", |_| true).unwrap();
        let storage = layout.region("STORAGE").expect("a STORAGE region").span;
        let origin = g431_hw::memory::FLASH_ORIGIN;
        assert_eq!(STORAGE, storage.origin - origin..storage.end() - origin);
        assert_eq!(STORAGE, 0x7_C000..0x7_C000 + 16 * 1024);
        assert_eq!((STORAGE.end - STORAGE.start) % 2048, 0, "whole 2 KiB pages");
        assert_eq!(STORAGE.end, 512 * 1024, "the top of the 512 KiB flash");
    }

    #[test]
    fn an_ecc_error_in_a_page_the_master_writes_is_let_pass_and_one_in_its_code_is_not() {
        use g431_hw::flash::{NmiAction, eccr, nmi_action};
        use g431_hw::memory::{G474_BANK2, MASTER_PARTITIONS};
        // A double error at `address`, as FLASH_ECCR reports it: bank 2 and the offset in it, or bank 1's offset.
        let ecc = |address: u32| match address.checked_sub(G474_BANK2) {
            Some(offset) => eccr::ECCD | eccr::BK_ECC | offset,
            None => eccr::ECCD | (address - g431_hw::memory::FLASH_ORIGIN),
        };
        let p = MASTER_PARTITIONS;
        // The record: the ticket and the verdict the bootloader wrote, torn by a power cut, are read at start.
        for span in [
            memory::MASTER_STORAGE,
            p.state,
            p.record,
            p.ticket(),
            p.counter(),
            p.dfu,
        ] {
            for address in [span.origin, span.end() - 8] {
                let action = nmi_action(ecc(address), &DATA_PAGES);
                assert!(matches!(action, NmiAction::PassDataRead { .. }), "{address:#x}");
            }
        }
        for address in [p.bootloader.origin, p.active.origin, p.active.end() - 8] {
            assert_eq!(nmi_action(ecc(address), &DATA_PAGES), NmiAction::Stop, "{address:#x}");
        }
    }

    #[test]
    fn a_bad_range_is_refused() {
        let mut flash = flash();
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
        save(&mut flash, &new).unwrap();
        assert_eq!(load(&mut flash), (new, 0));
        // What the flash holds already is not written again.
        let before = flash.stats_snapshot();
        save(&mut flash, &new).unwrap();
        assert_eq!(before.compare_to(flash.stats_snapshot()).writes, 0);
        // The link's signing time is kept with the key; the later of the two is the link's start.
        let mut store = Store::new(&mut flash, RANGE).unwrap();
        block_on(store.load(defaults()));
        block_on(store.save_signing_time(999_999)).unwrap();
        assert_eq!(load(&mut flash).0.signing.map(|k| k.timestamp), Some(999_999));
        // At power-up the vehicle publishes what was loaded: nothing to write.
        let mut store = Store::new(&mut flash, RANGE).unwrap();
        let loaded = block_on(store.load(defaults()));
        store.into_flash();
        let before = flash.stats_snapshot();
        let mut store = Store::new(&mut flash, RANGE).unwrap();
        block_on(store.load(defaults()));
        block_on(store.save(&loaded)).unwrap();
        store.into_flash();
        assert_eq!(before.compare_to(flash.stats_snapshot()).writes, 0);
        // Signing off: an all-zero key.
        let off = Settings { signing: None, ..new };
        save(&mut flash, &off).unwrap();
        assert_eq!(load(&mut flash).0, off);
    }

    /// Push raw bytes as a record, from an aligned buffer.
    fn push(store: &mut Store<&mut Flash>, bytes: &[u8]) {
        let mut aligned = Buffer([0; RECORD.next_multiple_of(8)]);
        aligned.0[..bytes.len()].copy_from_slice(bytes);
        block_on(store.queue.push(&aligned.0[..bytes.len()], true)).unwrap();
    }

    #[test]
    fn invalid_values_and_other_formats_read_as_defaults() {
        let mut flash = flash();
        let good = with(|s| {
            s.params.set(Param::PowerCap, 70);
        });
        save(&mut flash, &good).unwrap();
        {
            let mut store = Store::new(&mut flash, RANGE).unwrap();
            // A record with LBV_GAIN 1000: the gain reads as its default, the rest as stored.
            let mut record = encode(&good, 0);
            let gain = 2 + 4 * usize::from(Param::Gain.index());
            record[gain..gain + 4].copy_from_slice(&1000i32.to_le_bytes());
            push(&mut store, &record);
        }
        let (settings, errors) = load(&mut flash);
        assert_eq!(
            (settings.params.gain_percent(), settings.params.power_cap_percent()),
            (50, 70)
        );
        assert_eq!(errors, 0);
        {
            // Newer records of another format, or cut short, are passed over: the last good one stands.
            let mut store = Store::new(&mut flash, RANGE).unwrap();
            let mut other = encode(&defaults(), 0);
            other[0] = FORMAT + 1;
            push(&mut store, &other);
            push(&mut store, &encode(&defaults(), 0)[..40]);
        }
        assert_eq!(load(&mut flash).0.params.power_cap_percent(), 70);
    }

    /// A record as an older image wrote it, with its first `count` parameters (SYSID_MYGCS 200, the rest at their
    /// defaults), then the signing key and the link's time.
    fn old_record(count: usize) -> Vec<u8> {
        let mut old = vec![FORMAT, count as u8];
        for param in Param::ALL.into_iter().take(count) {
            let value = if param == Param::OperatorId {
                200
            } else {
                param.default_value()
            };
            old.extend(value.to_le_bytes());
        }
        old.extend([7; 32]);
        old.extend(5u64.to_le_bytes());
        old.extend(6_000_000u64.to_le_bytes());
        old
    }

    #[test]
    fn a_record_of_an_image_with_fewer_parameters_keeps_its_settings() {
        // What the image before LBV_GCS_NEUTRAL wrote (26 parameters), the one before the buttons (ten), and the one
        // before LBV_UPD_UNSIGNED (nine).
        for count in [26, 10, 9] {
            let old = old_record(count);
            assert_eq!(old.len(), RECORD - 4 * (PARAM_COUNT - count));
            let mut flash = flash();
            {
                let mut store = Store::new(&mut flash, RANGE).unwrap();
                push(&mut store, &old);
            }
            let (settings, errors) = load(&mut flash);
            assert_eq!(errors, 0);
            assert_eq!(settings.params.operator(), 200);
            assert!(!settings.params.unsigned_updates(), "the new ones at their defaults");
            for param in Param::ALL.into_iter().skip(count) {
                assert_eq!(settings.params.get(param), defaults().params.get(param), "{param:?}");
            }
            assert_eq!(settings.params.button(6), Some(crate::params::ButtonFunction::Arm));
            assert_eq!(
                settings.signing,
                Some(SigningKey {
                    secret: [7; 32],
                    timestamp: 6_000_000
                }),
                "the key kept, from the link's reservation on"
            );
            // Once changed, it is stored whole in this image's layout.
            let mut changed = settings;
            changed.params.set(Param::Button0, 42);
            save(&mut flash, &changed).unwrap();
            assert_eq!(load(&mut flash).0, changed);
        }
        // A count that does not fit the length, or more parameters than this image has, is no record of it.
        let mut short = old_record(10);
        short[1] = 9;
        let mut more = encode(&defaults(), 0).to_vec();
        more[1] = PARAM_COUNT as u8 + 1;
        for bad in [short, more] {
            assert_eq!(decode(&bad, defaults()), None);
        }
    }

    /// `old_record` with parameter `param` at `value`.
    fn old_record_with(count: usize, changes: &[(Param, i32)]) -> Vec<u8> {
        let mut old = old_record(count);
        for (param, value) in changes {
            let at = 2 + 4 * usize::from(param.index());
            old[at..at + 4].copy_from_slice(&value.to_le_bytes());
        }
        old
    }

    #[test]
    fn an_earlier_images_neutral_and_long_pilot_timeout_are_read_as_this_one_says_them() {
        use crate::params::GcsFailsafe;
        let read = |record: Vec<u8>| {
            let mut flash = flash();
            {
                let mut store = Store::new(&mut flash, RANGE).unwrap();
                push(&mut store, &record);
            }
            let (settings, errors) = load(&mut flash);
            assert_eq!(errors, 0);
            settings.params
        };
        // FS_GCS_ENABLE 3 was "hold the sticks neutral": now 1 with LBV_GCS_NEUTRAL 1, which does the same.
        let params = read(old_record_with(
            26,
            &[(Param::GcsFailsafe, 3), (Param::PilotTimeout, 100)],
        ));
        assert_eq!((params.get(Param::GcsFailsafe), params.get(Param::GcsNeutral)), (1, 1));
        assert_eq!(params.gcs_failsafe(), GcsFailsafe::Neutral);
        // 10 s, above ArduSub's 3 s: the nearest it can be.
        assert_eq!(params.pilot_timeout(), Duration::from_secs(3));
        assert_eq!(params.operator(), 200, "the rest kept");
        // What ArduSub means too is kept as it was.
        for (gcs, action) in [(1, GcsFailsafe::Warn), (2, GcsFailsafe::Disarm)] {
            let params = read(old_record_with(
                26,
                &[(Param::GcsFailsafe, gcs), (Param::PilotTimeout, 5)],
            ));
            assert_eq!(params.gcs_failsafe(), action);
            assert_eq!(params.get(Param::GcsNeutral), 0);
            assert_eq!(params.pilot_timeout(), Duration::from_millis(500));
        }
        // From the image of the ten parameters too.
        let params = read(old_record_with(10, &[(Param::GcsFailsafe, 3)]));
        assert_eq!(params.gcs_failsafe(), GcsFailsafe::Neutral);
        // A record of this image cannot hold a 3; one that did would be no record of it: the default.
        let params = read(old_record_with(
            PARAM_COUNT,
            &[(Param::GcsFailsafe, 3), (Param::PilotTimeout, 100)],
        ));
        assert_eq!(params.gcs_failsafe(), GcsFailsafe::Disarm);
        assert_eq!(params.pilot_timeout(), Duration::from_secs(3));
        // Once changed, stored whole in this image's terms.
        let mut flash = flash();
        {
            let mut store = Store::new(&mut flash, RANGE).unwrap();
            push(&mut store, &old_record_with(26, &[(Param::GcsFailsafe, 3)]));
        }
        let (mut settings, _) = load(&mut flash);
        settings.params.set(Param::Gain, 60);
        save(&mut flash, &settings).unwrap();
        let (after, _) = load(&mut flash);
        assert_eq!(after, settings);
        assert_eq!(after.params.gcs_failsafe(), GcsFailsafe::Neutral);
    }

    #[test]
    fn many_changes_wear_every_page_and_the_last_one_wins() {
        let mut flash = flash();
        let start = flash.stats_snapshot();
        let mut store = Store::new(&mut flash, RANGE).unwrap();
        block_on(store.load(defaults()));
        let mut last = defaults();
        // Enough writes to go round the eight pages several times (12 records to a page).
        for n in 0..1000 {
            last = with(|s| {
                s.params.set(Param::Gain, 1 + n % 100);
                s.params.set(Param::PowerCap, 100 - n % 100);
            });
            block_on(store.save(&last)).unwrap();
        }
        store.into_flash();
        assert_eq!(load(&mut flash), (last, 0));
        let erases = start.compare_to(flash.stats_snapshot()).erases;
        assert!(erases >= 40, "pages were reused ({erases} erases)");
    }

    /// Cut the power during one write, in a store `fill` writes full, and check that the next start finds the
    /// settings before the write or after it, nothing else, and that the store goes on working. The power is cut
    /// after every byte of the writes, and after every 16th byte of a page erase. Returns the bytes the write
    /// takes (erased and written).
    fn power_cut_during_a_write(fill: u32) -> u32 {
        let mut flash = flash();
        let mut store = Store::new(&mut flash, RANGE).unwrap();
        block_on(store.load(defaults()));
        for n in 0..fill {
            block_on(store.save(&with(|s| {
                s.params.set(Param::Gain, 1 + (n % 100) as i32);
            })))
            .unwrap();
        }
        let earlier = with(|s| {
            s.params.set(Param::Gain, 42);
            s.signing = Some(SigningKey {
                secret: [1; 32],
                timestamp: 42,
            });
        });
        block_on(store.save(&earlier)).unwrap();
        store.into_flash();
        let target = with(|s| {
            *s = earlier;
            s.params.set(Param::GcsTimeout, 77);
        });
        let total = {
            let mut uncut = flash.clone();
            uncut.bytes_until_shutoff = Some(u32::MAX);
            save(&mut uncut, &target).unwrap();
            u32::MAX - uncut.bytes_until_shutoff.unwrap()
        };
        let erase = if total > 2048 { 0..2048 } else { 0..0 };
        for cut_at in (0..=total).filter(|n| !erase.contains(n) || n % 16 == 0) {
            let mut cut = flash.clone();
            cut.bytes_until_shutoff = Some(cut_at);
            let result = save(&mut cut, &target);
            let completed = cut.bytes_until_shutoff.is_some();
            // Power back: the cut-off flag is gone, the flash holds what was written.
            cut.bytes_until_shutoff = None;
            let (after, _) = load(&mut cut);
            if completed {
                assert_eq!((cut_at, result, after), (total, Ok(()), target));
                continue;
            }
            assert_eq!(result, Err(StoreError::Flash));
            // Cut in the last word's padding, the record is whole already.
            assert!(
                after == earlier || after == target,
                "fill {fill}, cut after {cut_at} bytes: only the interrupted write may be lost: {after:?}"
            );
            // And the store goes on working.
            let next = with(|s| {
                *s = after;
                s.params.set(Param::PowerCap, 55);
            });
            save(&mut cut, &next).unwrap();
            assert_eq!(load(&mut cut).0, next, "fill {fill}, cut after {cut_at} bytes");
        }
        total
    }

    #[test]
    fn a_power_cut_during_a_write_loses_at_most_that_write() {
        // One record: an 8-byte header and 154 bytes of data in 21 double words.
        assert_eq!(power_cut_during_a_write(0), 168);
    }

    #[test]
    fn a_power_cut_while_the_store_moves_to_a_new_page_loses_at_most_that_write() {
        // 12 records to a page: after 11 (and one more), the interrupted write closes its page and opens the
        // next (two page markers more); after 95, the log has gone round the eight pages and must erase the
        // oldest first.
        assert_eq!(
            power_cut_during_a_write(11),
            168 + 16,
            "the write that moves to a new page"
        );
        assert_eq!(
            power_cut_during_a_write(95),
            2048 + 168 + 16,
            "the write that erases a page first"
        );
    }

    struct Restart(std::rc::Rc<core::cell::Cell<u32>>);

    impl Reboot for Restart {
        async fn reboot(&mut self) -> ! {
            self.0.set(self.0.get() + 1);
            core::future::pending().await
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
            s.signing = Some(SigningKey {
                secret: [9; 32],
                timestamp: 10,
            });
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
                for _ in 0..4 {
                    yield_now().await;
                }
                shared.signing_time.sender().send(7_000_000);
                for _ in 0..4 {
                    yield_now().await;
                }
                assert_eq!(shared.signing_stored.try_get(), Some(7_000_000), "the console is told");
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
            match block_on(select(settings_task(&mut store, &shared, &mut reboot), script)) {
                Either::First(never) => match never {},
                Either::Second(()) => {}
            }
        }
        let (after, _) = load(&mut flash);
        assert_eq!(after.params.operator(), 200);
        assert_eq!(after.params.gain_percent(), 99);
        assert_eq!(after.signing.map(|key| key.timestamp), Some(7_000_000));
        assert!(shared.outbox.try_receive().is_err(), "no warning");
    }

    #[test]
    fn a_failed_write_is_reported_on_the_console() {
        let shared = Shared::new();
        let mut flash = flash();
        let mut reboot = Restart(Default::default());
        let mut store = Store::new(&mut flash, RANGE).unwrap();
        block_on(store.load(defaults()));
        store.into_flash();
        flash.bytes_until_shutoff = Some(3);
        let mut store = Store::new(&mut flash, RANGE).unwrap();
        block_on(store.load(defaults()));
        let script = async {
            shared.settings.sender().send(with(|s| {
                s.params.set(Param::Gain, 10);
            }));
            for _ in 0..4 {
                yield_now().await;
            }
        };
        match block_on(select(settings_task(&mut store, &shared, &mut reboot), script)) {
            Either::First(never) => match never {},
            Either::Second(()) => {}
        }
        assert!(matches!(
            shared.outbox.try_receive(),
            Ok(crate::shared::Outgoing::Text(Severity::Warning, text)) if text.starts_with("Settings not saved")
        ));
    }

    #[test]
    fn on_a_flash_not_in_its_layout_the_store_reads_and_writes_nothing() {
        let mut flash = flash();
        let stored = with(|s| {
            s.params.set(Param::Gain, 80);
        });
        save(&mut flash, &stored).unwrap();
        let before = flash.stats_snapshot();
        let mut store = Store::new(&mut flash, RANGE).unwrap();
        assert!(!store.writes_refused());
        store.set_layout_ok(false);
        assert!(store.writes_refused());
        assert_eq!(block_on(store.load(defaults())), stored, "what the flash holds is read");
        // What it holds already is no write; a change and a reservation are refused.
        assert_eq!(block_on(store.save(&stored)), Ok(()));
        let changed = with(|s| {
            s.params.set(Param::Gain, 20);
        });
        assert_eq!(block_on(store.save(&changed)), Err(StoreError::Layout));
        assert_eq!(block_on(store.save_signing_time(5_000_000)), Err(StoreError::Layout));
        store.into_flash();
        let after = before.compare_to(flash.stats_snapshot());
        assert_eq!((after.writes, after.erases), (0, 0), "nothing written");
        assert_eq!(load(&mut flash), (stored, 0));
    }

    #[test]
    fn the_task_tells_each_change_the_layout_refuses_and_does_not_try_a_reservation_again() {
        let _clock = lbv_sim::clock::take();
        let shared = Shared::new();
        let mut flash = flash();
        let mut reboot = Restart(Default::default());
        let before = flash.stats_snapshot();
        let mut store = Store::new(&mut flash, RANGE).unwrap();
        store.set_layout_ok(false);
        let loaded = block_on(store.load(defaults()));
        let texts = |shared: &Shared| {
            core::iter::from_fn(|| shared.outbox.try_receive().ok())
                .map(|out| match out {
                    crate::shared::Outgoing::Text(Severity::Warning, text) => text.to_string(),
                    other => panic!("{other:?}"),
                })
                .collect::<Vec<_>>()
        };
        let script = async {
            // The start's publication of what was loaded writes nothing, and says nothing.
            shared.settings.sender().send(loaded);
            crate::battery::tests::elapse(Duration::from_millis(10)).await;
            assert_eq!(texts(&shared), [] as [&str; 0]);
            shared.settings.sender().send(with(|s| {
                s.params.set(Param::Gain, 10);
            }));
            shared.signing_time.sender().send(9_000_000);
            crate::battery::tests::elapse(Duration::from_millis(10)).await;
            assert_eq!(texts(&shared), ["Settings not saved: flash not dual-bank"; 2]);
            crate::battery::tests::elapse(SIGNING_RETRY * 3).await;
            assert_eq!(texts(&shared), [] as [&str; 0], "not tried again");
            assert_eq!(shared.signing_stored.try_get(), None, "not stored, not confirmed");
        };
        match block_on(select(settings_task(&mut store, &shared, &mut reboot), script)) {
            Either::First(never) => match never {},
            Either::Second(()) => {}
        }
        store.into_flash();
        let after = before.compare_to(flash.stats_snapshot());
        assert_eq!((after.writes, after.erases), (0, 0), "nothing written");
    }

    #[test]
    fn a_reservation_asked_for_with_the_reboot_is_stored_before_the_restart() {
        let shared = Shared::new();
        let mut flash = flash();
        let restarts = std::rc::Rc::new(core::cell::Cell::new(0));
        let mut reboot = Restart(restarts.clone());
        let keyed = with(|s| {
            s.signing = Some(SigningKey {
                secret: [9; 32],
                timestamp: 10,
            })
        });
        save(&mut flash, &keyed).unwrap();
        {
            let mut store = Store::new(&mut flash, RANGE).unwrap();
            block_on(store.load(defaults()));
            let script = async {
                shared.signing_time.sender().send(8_000_000);
                shared.reboot.signal(());
                for _ in 0..4 {
                    yield_now().await;
                }
                assert_eq!(restarts.get(), 1);
            };
            match block_on(select(settings_task(&mut store, &shared, &mut reboot), script)) {
                Either::First(never) => match never {},
                Either::Second(()) => {}
            }
        }
        assert_eq!(load(&mut flash).0.signing.map(|key| key.timestamp), Some(8_000_000));
    }

    #[test]
    fn a_failed_reservation_is_written_again_until_it_is_stored() {
        let _clock = lbv_sim::clock::take();
        let shared = Shared::new();
        let mut flash = flash();
        let mut reboot = Restart(Default::default());
        save(
            &mut flash,
            &with(|s| {
                s.params.set(Param::Gain, 10);
            }),
        )
        .unwrap();
        // The next write fails part way.
        flash.bytes_until_shutoff = Some(3);
        {
            let mut store = Store::new(&mut flash, RANGE).unwrap();
            block_on(store.load(defaults()));
            let script = async {
                shared.signing_time.sender().send(9_000_000);
                crate::battery::tests::elapse(Duration::from_millis(10)).await;
                assert_eq!(shared.signing_stored.try_get(), None, "not stored, not confirmed");
                assert!(matches!(
                    shared.outbox.try_receive(),
                    Ok(crate::shared::Outgoing::Text(Severity::Warning, _))
                ));
                crate::battery::tests::elapse(SIGNING_RETRY).await;
                assert_eq!(shared.signing_stored.try_get(), Some(9_000_000), "stored on the retry");
            };
            match block_on(select(settings_task(&mut store, &shared, &mut reboot), script)) {
                Either::First(never) => match never {},
                Either::Second(()) => {}
            }
        }
        let mut store = Store::new(&mut flash, RANGE).unwrap();
        block_on(store.load(defaults()));
        assert_eq!(signing_time_of(&store.held.unwrap()), 9_000_000);
    }
}
