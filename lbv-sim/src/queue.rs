//! One-way links: a [`Queue`] of items (bytes, CAN frames) whose reader is woken on every send, the serial ports
//! built on it ([`SerialRx`], [`SerialTx`]), and a CAN bus that hands every frame to each node ([`CanBus`]).

use alloc::collections::VecDeque;
use alloc::rc::Rc;
use alloc::vec::Vec;
use core::cell::RefCell;
use core::convert::Infallible;
use core::future::poll_fn;
use core::task::{Poll, Waker};

struct Inner<T> {
    items: VecDeque<T>,
    reader: Option<Waker>,
}

/// Items in order from a writer to a reader; clones are handles on the same queue.
pub struct Queue<T>(Rc<RefCell<Inner<T>>>);

impl<T> Clone for Queue<T> {
    fn clone(&self) -> Self {
        Self(Rc::clone(&self.0))
    }
}

impl<T> Default for Queue<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T> core::fmt::Debug for Queue<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Queue").field("len", &self.len()).finish()
    }
}

impl<T> Queue<T> {
    /// An empty queue.
    pub fn new() -> Self {
        Self(Rc::new(RefCell::new(Inner {
            items: VecDeque::new(),
            reader: None,
        })))
    }

    /// Queue `items` and wake the reader.
    pub fn send(&self, items: impl IntoIterator<Item = T>) {
        let waker = {
            let mut inner = self.0.borrow_mut();
            let before = inner.items.len();
            inner.items.extend(items);
            (inner.items.len() > before).then(|| inner.reader.take()).flatten()
        };
        if let Some(waker) = waker {
            waker.wake();
        }
    }

    /// Queue one item and wake the reader.
    pub fn push(&self, item: T) {
        self.send([item]);
    }

    /// The next item, waiting for one.
    pub async fn receive(&self) -> T {
        poll_fn(|cx| {
            let mut inner = self.0.borrow_mut();
            match inner.items.pop_front() {
                Some(item) => Poll::Ready(item),
                None => {
                    inner.reader = Some(cx.waker().clone());
                    Poll::Pending
                }
            }
        })
        .await
    }

    /// The next item, if one is queued.
    pub fn try_receive(&self) -> Option<T> {
        self.0.borrow_mut().items.pop_front()
    }

    /// Everything queued, oldest first.
    pub fn take(&self) -> Vec<T> {
        self.0.borrow_mut().items.drain(..).collect()
    }

    /// Drop everything queued (a receiver reset).
    pub fn clear(&self) {
        self.0.borrow_mut().items.clear();
    }

    /// Items queued.
    pub fn len(&self) -> usize {
        self.0.borrow().items.len()
    }

    /// Nothing queued.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A serial port's receive side (`embedded_io_async::Read`): each read waits for a byte, then takes what is queued,
/// at most `chunk` bytes (a UART driver's buffer hands over what has arrived).
#[derive(Debug, Clone)]
pub struct SerialRx {
    queue: Queue<u8>,
    chunk: usize,
}

impl SerialRx {
    /// The receive side of `queue`.
    pub fn new(queue: Queue<u8>) -> Self {
        Self {
            queue,
            chunk: usize::MAX,
        }
    }

    /// Hand over at most `chunk` bytes per read (at least 1).
    pub fn chunked(queue: Queue<u8>, chunk: usize) -> Self {
        Self {
            queue,
            chunk: chunk.max(1),
        }
    }
}

impl embedded_io_async::ErrorType for SerialRx {
    type Error = Infallible;
}

impl embedded_io_async::Read for SerialRx {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        let Some((first, rest)) = buf.split_first_mut() else {
            return Ok(0);
        };
        *first = self.queue.receive().await;
        let mut n = 1;
        for slot in rest.iter_mut().take(self.chunk.saturating_sub(1)) {
            let Some(byte) = self.queue.try_receive() else { break };
            *slot = byte;
            n += 1;
        }
        Ok(n)
    }
}

/// A serial port's transmit side (`embedded_io_async::Write`): every byte written is queued at once for the other
/// end, which reads it through a [`SerialRx`], or takes it all as a capture ([`SerialTx::take`] on a clone).
#[derive(Debug, Clone, Default)]
pub struct SerialTx(pub Queue<u8>);

impl SerialTx {
    /// Everything written and not yet read, oldest first.
    pub fn take(&self) -> Vec<u8> {
        self.0.take()
    }
}

impl embedded_io_async::ErrorType for SerialTx {
    type Error = Infallible;
}

impl embedded_io_async::Write for SerialTx {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        self.0.send(buf.iter().copied());
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

/// A CAN bus: every frame sent reaches every node attached, each through its own receive queue (its controller's
/// FIFO). Frames of any type `F`.
#[derive(Debug)]
pub struct CanBus<F> {
    nodes: Vec<Queue<F>>,
    /// Frames sent so far.
    pub frames: u64,
}

impl<F> Default for CanBus<F> {
    fn default() -> Self {
        Self {
            nodes: Vec::new(),
            frames: 0,
        }
    }
}

impl<F: Clone> CanBus<F> {
    /// A node on the bus: its receive queue.
    pub fn attach(&mut self) -> Queue<F> {
        let node = Queue::new();
        self.nodes.push(node.clone());
        node
    }

    /// Put frames on the bus: every node receives them, in order.
    pub fn send(&mut self, frames: &[F]) {
        self.frames += frames.len() as u64;
        for node in &self.nodes {
            node.send(frames.iter().cloned());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Executor;
    use embedded_io_async::{Read, Write};
    use std::cell::Cell;

    #[test]
    fn a_reader_waits_for_bytes_and_takes_what_has_arrived() {
        let queue = Queue::new();
        let mut rx = SerialRx::chunked(queue.clone(), 3);
        let mut tx = SerialTx(queue.clone());
        let got = RefCell::new(Vec::new());
        let reads = Cell::new(0);
        let mut executor = Executor::new();
        executor.spawn(async {
            let mut buf = [0; 8];
            loop {
                let n = rx.read(&mut buf).await.unwrap_or(0);
                reads.set(reads.get() + 1);
                got.borrow_mut().extend_from_slice(&buf[..n]);
            }
        });
        executor.run_until_idle();
        assert_eq!(reads.get(), 0, "nothing to read yet");
        embassy_futures::block_on(tx.write_all(&[1, 2, 3, 4, 5])).unwrap();
        executor.run_until_idle();
        assert_eq!(*got.borrow(), [1, 2, 3, 4, 5]);
        assert_eq!(reads.get(), 2, "at most 3 bytes a read");
        assert!(queue.is_empty());
    }

    #[test]
    fn every_can_node_gets_every_frame() {
        let mut bus = CanBus::default();
        let (a, b) = (bus.attach(), bus.attach());
        bus.send(&[1u16, 2]);
        bus.send(&[3]);
        assert_eq!(a.take(), [1, 2, 3]);
        assert_eq!(b.take(), [1, 2, 3]);
        assert_eq!(bus.frames, 3);
    }
}
