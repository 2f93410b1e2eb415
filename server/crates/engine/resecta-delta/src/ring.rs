//! Bounded replay ring: the last messages of a stream by sequence number, so a reconnecting
//! client gets what it missed or learns that it must take a fresh snapshot.

use std::collections::VecDeque;

use crate::error::DeltaError;

/// What a client that has applied everything up to a sequence number needs next.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Since<T> {
    /// The items after that sequence number, oldest first (empty when it is up to date).
    Items(Vec<(u64, T)>),
    /// Something it needs is gone (or the sequence number is unknown): it must take a snapshot.
    Gap,
}

/// The most recent items of a stream, bounded by count and by total bytes.
///
/// Sequence numbers strictly increase but may skip. The ring serves a client at sequence `s`
/// when `s` is at or after its *horizon* and not after the last sequence: the horizon is the
/// newest sequence evicted (or set by [`ReplayRing::reset`]); before anything is evicted it is
/// the sequence just before the first item pushed (`seq − 1`), so a client must hold the state
/// that the first item was made against.
#[derive(Debug, Clone)]
pub struct ReplayRing<T> {
    items: VecDeque<(u64, T, usize)>,
    max_items: usize,
    max_bytes: usize,
    bytes: usize,
    horizon: Option<u64>,
    last: Option<u64>,
}

impl<T: Clone> ReplayRing<T> {
    /// A ring that holds at most `max_items` items of at most `max_bytes` bytes in total.
    pub fn new(max_items: usize, max_bytes: usize) -> Self {
        Self {
            items: VecDeque::new(),
            max_items,
            max_bytes,
            bytes: 0,
            horizon: None,
            last: None,
        }
    }

    /// Appends an item of `bytes` bytes, evicting the oldest until both bounds hold (an item
    /// larger than `max_bytes` is not kept: it only moves the horizon to `seq`).
    pub fn push(&mut self, seq: u64, item: T, bytes: usize) -> Result<(), DeltaError> {
        if let Some(last) = self.last
            && seq <= last
        {
            return Err(DeltaError::SeqOrder { seq, last });
        }
        if self.last.is_none() {
            self.horizon = Some(seq.saturating_sub(1));
        }
        self.last = Some(seq);
        self.items.push_back((seq, item, bytes));
        self.bytes = self.bytes.saturating_add(bytes);
        while self.items.len() > self.max_items || self.bytes > self.max_bytes {
            let Some((s, _, b)) = self.items.pop_front() else {
                break;
            };
            self.bytes -= b;
            self.horizon = Some(s);
        }
        Ok(())
    }

    /// Drops every item and declares `seq` the current state (say, after a snapshot that was
    /// not made of deltas): clients at `seq` are up to date, older ones get [`Since::Gap`].
    pub fn reset(&mut self, seq: u64) {
        self.items.clear();
        self.bytes = 0;
        self.horizon = Some(seq);
        self.last = Some(seq);
    }

    /// What a client that has applied everything up to `seq` needs.
    pub fn since(&self, seq: u64) -> Since<T> {
        match (self.horizon, self.last) {
            (Some(h), Some(last)) if h <= seq && seq <= last => Since::Items(
                self.items
                    .iter()
                    .filter(|(s, _, _)| *s > seq)
                    .map(|(s, t, _)| (*s, t.clone()))
                    .collect(),
            ),
            _ => Since::Gap,
        }
    }

    /// The newest sequence number pushed (or reset to).
    pub fn last_seq(&self) -> Option<u64> {
        self.last
    }

    /// The oldest sequence number still held.
    pub fn first_seq(&self) -> Option<u64> {
        self.items.front().map(|(s, _, _)| *s)
    }

    pub fn len(&self) -> usize {
        self.items.len()
    }

    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Total bytes of the items held.
    pub fn bytes(&self) -> usize {
        self.bytes
    }
}
