//! A serial line at its baud rate, one way, between two UARTs with buffers of fixed size: what the sending side
//! writes waits for room in its transmit buffer, leaves it at 10 bit times a byte (8N1), and arrives in the
//! receiving side's buffer, where it stays until it is read; a byte that finds that buffer full is lost (an
//! overrun). This is the console link of the master as its binding has it (LPUART1 at 115200 baud, embassy-stm32's
//! `BufferedUart` with a 512-byte transmit and a 256-byte receive ring buffer), for a bench run that must see what
//! the line's rate and those buffers do: a receiving task that stops reading loses bytes, a transmitting task that
//! has more to say than the line carries waits.
//!
//! The bytes' arrival is computed when they are sent, and the receive buffer is filled as a read finds them
//! arrived: nothing takes them out between two reads, so a byte that arrived when the buffer was full at that time
//! is the one lost, as on the chip. A read that finds nothing waits for the next byte's arrival.

use alloc::collections::VecDeque;
use alloc::rc::Rc;
use alloc::vec::Vec;
use core::cell::RefCell;
use core::convert::Infallible;
use core::future::poll_fn;
use core::task::{Poll, Waker};

use embassy_time::{Duration, Instant, Timer};

/// Bits a byte takes on the line: a start bit, eight data bits and a stop bit.
const BITS_PER_BYTE: u64 = 10;

#[derive(Debug)]
struct State {
    /// The time one byte takes on the line.
    byte_time: Duration,
    /// The sending side's buffer: bytes written and not yet out on the line.
    tx_capacity: usize,
    /// The receiving side's buffer.
    rx_capacity: usize,
    /// Bytes written, each with the time it has arrived whole at the other end, in order.
    flight: VecDeque<(Instant, u8)>,
    /// Bytes arrived and not yet read.
    buffer: VecDeque<u8>,
    /// Bytes lost to a full receive buffer.
    lost: u64,
    /// A reader waiting for bytes with nothing on the line.
    reader: Option<Waker>,
}

impl State {
    /// When the last byte written has arrived (now, when the line is idle).
    fn free_at(&self, now: Instant) -> Instant {
        self.flight.back().map_or(now, |(at, _)| (*at).max(now))
    }

    /// Put on the line whatever of `bytes` is written at `now`.
    fn send(&mut self, now: Instant, bytes: impl IntoIterator<Item = u8>) {
        let mut at = self.free_at(now);
        for byte in bytes {
            at += self.byte_time;
            self.flight.push_back((at, byte));
        }
    }

    /// Move what has arrived by `now` into the receive buffer; what finds it full is lost.
    fn arrive(&mut self, now: Instant) {
        while let Some(&(at, byte)) = self.flight.front() {
            if at > now {
                break;
            }
            self.flight.pop_front();
            if self.buffer.len() < self.rx_capacity {
                self.buffer.push_back(byte);
            } else {
                self.lost += 1;
            }
        }
    }

    /// Bytes written and not yet out on the line at `now`: the transmit buffer's fill. A byte is out once its last
    /// bit has left, one byte time before it has arrived.
    fn unsent(&self, now: Instant) -> usize {
        let out_by = now + self.byte_time;
        self.flight.iter().rev().take_while(|(at, _)| *at > out_by).count()
    }
}

/// A serial line, one way; clones are handles on the same line. The sending side is [`SerialLine::send`] (a
/// scripted peer, which writes at once whatever it has) or a [`LineTx`]; the receiving side a [`LineRx`] or
/// [`SerialLine::take_arrived`].
#[derive(Debug, Clone)]
pub struct SerialLine(Rc<RefCell<State>>);

impl SerialLine {
    /// A line at `baud`, from a transmit buffer of `tx_capacity` bytes to a receive buffer of `rx_capacity`.
    pub fn new(baud: u32, tx_capacity: usize, rx_capacity: usize) -> Self {
        let byte_time = Duration::from_micros((BITS_PER_BYTE * 1_000_000).div_ceil(u64::from(baud.max(1))));
        Self(Rc::new(RefCell::new(State {
            byte_time,
            tx_capacity: tx_capacity.max(1),
            rx_capacity,
            flight: VecDeque::new(),
            buffer: VecDeque::new(),
            lost: 0,
            reader: None,
        })))
    }

    /// The time a byte takes on the line.
    pub fn byte_time(&self) -> Duration {
        self.0.borrow().byte_time
    }

    /// Write `bytes` now, whatever the transmit buffer holds (a peer that has room): they go out after those
    /// written before.
    pub fn send(&self, bytes: impl IntoIterator<Item = u8>) {
        let waker = {
            let mut state = self.0.borrow_mut();
            state.send(Instant::now(), bytes);
            state.reader.take()
        };
        if let Some(waker) = waker {
            waker.wake();
        }
    }

    /// Everything arrived by now and not read yet, oldest first, however much (a peer that reads at once).
    pub fn take_arrived(&self) -> Vec<u8> {
        let mut state = self.0.borrow_mut();
        let now = Instant::now();
        let mut out: Vec<u8> = state.buffer.drain(..).collect();
        while let Some(&(at, byte)) = state.flight.front() {
            if at > now {
                break;
            }
            state.flight.pop_front();
            out.push(byte);
        }
        out
    }

    /// When the next byte on its way arrives; `None` when nothing is on the line.
    pub fn next_arrival(&self) -> Option<Instant> {
        self.0.borrow().flight.front().map(|(at, _)| *at)
    }

    /// Bytes written and not yet out on the line now: the transmit buffer's fill.
    pub fn unsent(&self) -> usize {
        self.0.borrow().unsent(Instant::now())
    }

    /// Bytes lost so far because the receive buffer was full.
    pub fn lost(&self) -> u64 {
        self.0.borrow().lost
    }

    /// The receiving UART restarts: its buffer is emptied (what is on the line still comes).
    pub fn reset_receiver(&self) {
        self.0.borrow_mut().buffer.clear();
    }

    /// The receiving side as a UART's receive port.
    pub fn rx(&self) -> LineRx {
        LineRx(self.clone())
    }

    /// The sending side as a UART's transmit port.
    pub fn tx(&self) -> LineTx {
        LineTx(self.clone())
    }
}

/// The receiving side of a [`SerialLine`] (`embedded_io_async::Read`): a read takes what has arrived, up to the
/// buffer given, and waits for a byte when none has.
#[derive(Debug, Clone)]
pub struct LineRx(SerialLine);

impl embedded_io_async::ErrorType for LineRx {
    type Error = Infallible;
}

impl embedded_io_async::Read for LineRx {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        if buf.is_empty() {
            return Ok(0);
        }
        loop {
            let next = {
                let mut state = self.0.0.borrow_mut();
                state.arrive(Instant::now());
                if !state.buffer.is_empty() {
                    let mut n = 0;
                    for slot in buf.iter_mut() {
                        let Some(byte) = state.buffer.pop_front() else { break };
                        *slot = byte;
                        n += 1;
                    }
                    return Ok(n);
                }
                state.flight.front().map(|(at, _)| *at)
            };
            match next {
                Some(at) => Timer::at(at).await,
                // Nothing on the line: wait for a send.
                None => {
                    poll_fn(|cx| {
                        let mut state = self.0.0.borrow_mut();
                        if state.flight.is_empty() {
                            state.reader = Some(cx.waker().clone());
                            Poll::Pending
                        } else {
                            Poll::Ready(())
                        }
                    })
                    .await
                }
            }
        }
    }
}

/// The sending side of a [`SerialLine`] (`embedded_io_async::Write`): a write waits for room in the transmit
/// buffer and takes what fits; a flush waits until everything written is out.
#[derive(Debug, Clone)]
pub struct LineTx(SerialLine);

impl embedded_io_async::ErrorType for LineTx {
    type Error = Infallible;
}

impl embedded_io_async::Write for LineTx {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        if buf.is_empty() {
            return Ok(0);
        }
        loop {
            let now = Instant::now();
            let (room, wait) = {
                let state = self.0.0.borrow();
                let unsent = state.unsent(now);
                let room = state.tx_capacity.saturating_sub(unsent);
                // Room for one more once the oldest unsent byte is out.
                let oldest = state.flight.len().saturating_sub(unsent);
                let wait = state.flight.get(oldest).map(|(at, _)| *at - state.byte_time);
                (room, wait)
            };
            if room > 0 {
                let n = room.min(buf.len());
                self.0.send(buf.iter().take(n).copied());
                return Ok(n);
            }
            match wait {
                Some(at) if at > now => Timer::at(at).await,
                _ => Timer::after(self.0.byte_time()).await,
            }
        }
    }

    async fn flush(&mut self) -> Result<(), Infallible> {
        let done = {
            let state = self.0.0.borrow();
            state.flight.back().map(|(at, _)| *at)
        };
        if let Some(at) = done {
            Timer::at(at).await;
        }
        Ok(())
    }
}

#[cfg(all(test, feature = "std"))]
mod tests {
    use super::*;
    use crate::{Clock, Executor};
    use embedded_io_async::{Read, Write};
    use std::cell::Cell;

    fn clock() -> Clock {
        crate::clock::take()
    }

    #[test]
    fn bytes_take_ten_bit_times_each_and_a_full_receive_buffer_loses_them() {
        let clock = clock();
        let line = SerialLine::new(115_200, 512, 16);
        assert_eq!(line.byte_time(), Duration::from_micros(87));
        line.send(0..40u8);
        assert_eq!(
            line.next_arrival(),
            Some(Instant::from_ticks(0) + Duration::from_micros(87))
        );
        let mut rx = line.rx();
        // Nobody reads for the 40 bytes' time: the first 16 wait in the buffer, the other 24 are lost.
        clock.advance(Duration::from_micros(87 * 40));
        let mut buf = [0u8; 64];
        let n = embassy_futures::block_on(rx.read(&mut buf)).unwrap();
        assert_eq!(&buf[..n], (0..16).collect::<Vec<u8>>().as_slice());
        assert_eq!(line.lost(), 24);
    }

    #[test]
    fn a_reader_that_keeps_up_loses_nothing_and_a_writer_waits_for_the_line() {
        let clock = clock();
        let to_peer = SerialLine::new(115_200, 32, 256);
        let from_peer = SerialLine::new(115_200, 512, 16);
        let (mut tx, mut rx) = (to_peer.tx(), from_peer.rx());
        let got = RefCell::new(Vec::new());
        let wrote_at = Cell::new(None);
        let mut executor = Executor::new();
        executor.spawn(async {
            let mut buf = [0u8; 8];
            loop {
                let n = rx.read(&mut buf).await.unwrap();
                got.borrow_mut().extend_from_slice(&buf[..n]);
            }
        });
        executor.spawn(async {
            tx.write_all(&[7; 100]).await.unwrap();
            wrote_at.set(Some(Instant::now()));
        });
        from_peer.send(0..200u8);
        executor.run_for(&clock, Duration::from_millis(30), Duration::from_micros(10));
        assert_eq!(*got.borrow(), (0..200).collect::<Vec<u8>>());
        assert_eq!(from_peer.lost(), 0);
        // 100 bytes through a 32-byte buffer: the last one is in it once 67 have gone and the 68th is on the wire.
        let took = wrote_at.get().unwrap() - Instant::from_ticks(0);
        assert!(
            took >= Duration::from_micros(87 * 67) && took <= Duration::from_micros(87 * 67 + 10),
            "{took:?}"
        );
        assert_eq!(to_peer.take_arrived(), [7; 100]);
    }
}
