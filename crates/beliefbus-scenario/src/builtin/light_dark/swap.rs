//! Handing a policy built on the solver's thread to the control thread
//! without a lock, an allocation or a free on the control thread.
//!
//! The publisher boxes a fully built value and offers it through one
//! atomic pointer (`pending`); the reader takes it with one atomic swap and
//! exchanges it with the value in use — a pointer exchange — then hands
//! the replaced box back through a few atomic slots (`retired`) for the
//! publisher to free. Release on every store of a pointer and Acquire on
//! every load of one order the value's construction before its use (and
//! the reader's last reads of a retired value before its free), so the
//! reader sees either the old value or the new one, never a mixture.
//!
//! Why [`RETIRE_SLOTS`] slots suffice: the publisher empties them before
//! every offer, the reader retires once per value it takes, and takes are
//! sequential on one thread. A retirement still waiting after the
//! publisher's latest emptying comes from a take of the latest offer or
//! of one of the two before it (a take of an older offer precedes, on the
//! reader's thread, the take of a later one, which precedes that later
//! offer's replacement) — at most three. Should the slots be full all the
//! same, the reader keeps the replaced box and takes no new offer until a
//! slot frees: still no free on the control thread.

use std::ptr;
use std::sync::atomic::{AtomicPtr, Ordering};

/// Retirement slots (three are needed, module doc).
pub const RETIRE_SLOTS: usize = 4;

/// The shared half: one offered value and the retired ones.
pub struct Mailbox<T> {
    pending: AtomicPtr<T>,
    retired: [AtomicPtr<T>; RETIRE_SLOTS],
}

impl<T> Default for Mailbox<T> {
    fn default() -> Self {
        Self {
            pending: AtomicPtr::new(ptr::null_mut()),
            retired: std::array::from_fn(|_| AtomicPtr::new(ptr::null_mut())),
        }
    }
}

// SAFETY: the mailbox owns boxed `T`s and moves them between threads; a
// value is reachable from one side at a time (each pointer is taken out
// with an atomic swap before use), so `T: Send` suffices.
unsafe impl<T: Send> Send for Mailbox<T> {}
unsafe impl<T: Send> Sync for Mailbox<T> {}

/// Frees a box taken out of a slot (null: nothing).
fn free<T>(p: *mut T) {
    if !p.is_null() {
        // SAFETY: every non-null pointer in a slot came from Box::into_raw
        // and was swapped out of the slot exactly once (here).
        drop(unsafe { Box::from_raw(p) });
    }
}

impl<T> Mailbox<T> {
    /// Publisher: free what the reader retired.
    pub fn collect(&self) {
        for slot in &self.retired {
            free(slot.swap(ptr::null_mut(), Ordering::Acquire));
        }
    }

    /// Publisher: offer `value` (built in full before the call). An offer
    /// the reader has not taken yet is replaced and freed here.
    pub fn publish(&self, value: Box<T>) {
        self.collect();
        free(self.pending.swap(Box::into_raw(value), Ordering::AcqRel));
    }

    /// Reader: put a replaced value where the publisher frees it; gives it
    /// back if every slot is taken.
    fn retire(&self, value: Box<T>) -> Result<(), Box<T>> {
        let p = Box::into_raw(value);
        for slot in &self.retired {
            if slot
                .compare_exchange(ptr::null_mut(), p, Ordering::Release, Ordering::Relaxed)
                .is_ok()
            {
                return Ok(());
            }
        }
        // SAFETY: `p` came from Box::into_raw above and was stored nowhere.
        Err(unsafe { Box::from_raw(p) })
    }
}

impl<T> Drop for Mailbox<T> {
    fn drop(&mut self) {
        self.collect();
        free(self.pending.swap(ptr::null_mut(), Ordering::Acquire));
    }
}

/// The reader's half: the value in use.
pub struct Current<T> {
    value: Box<T>,
    /// A replaced value no slot took yet.
    held: Option<Box<T>>,
}

impl<T> Current<T> {
    pub fn new(value: Box<T>) -> Self {
        Self { value, held: None }
    }

    pub fn get(&self) -> &T {
        &self.value
    }

    /// Set-up, off the control path: put `value` in use, return the old.
    pub fn replace(&mut self, value: Box<T>) -> Box<T> {
        std::mem::replace(&mut self.value, value)
    }

    /// Take the offered value if there is one: atomic swaps and a pointer
    /// exchange, no allocation, no free, no lock. True if swapped.
    pub fn take_from(&mut self, mailbox: &Mailbox<T>) -> bool {
        if let Some(h) = self.held.take() {
            if let Err(h) = mailbox.retire(h) {
                self.held = Some(h);
                return false;
            }
        }
        let p = mailbox.pending.swap(ptr::null_mut(), Ordering::AcqRel);
        if p.is_null() {
            return false;
        }
        // SAFETY: the publisher stored a Box::into_raw pointer and this
        // swap took it out: it is ours alone.
        let old = std::mem::replace(&mut self.value, unsafe { Box::from_raw(p) });
        if let Err(old) = mailbox.retire(old) {
            self.held = Some(old);
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicUsize;
    use std::sync::Arc;

    /// A value whose every entry is its version, counting its drops.
    struct Table {
        version: u64,
        rows: Vec<u64>,
        drops: Arc<AtomicUsize>,
    }

    impl Drop for Table {
        fn drop(&mut self) {
            self.drops.fetch_add(1, Ordering::Relaxed);
        }
    }

    fn table(version: u64, drops: &Arc<AtomicUsize>) -> Box<Table> {
        Box::new(Table {
            version,
            rows: vec![version; 512],
            drops: drops.clone(),
        })
    }

    #[test]
    fn a_swap_under_concurrent_lookups_never_yields_a_torn_value() {
        const OFFERS: u64 = 20_000;
        let drops = Arc::new(AtomicUsize::new(0));
        let mailbox = Arc::new(Mailbox::<Table>::default());
        let publisher = {
            let (mailbox, drops) = (mailbox.clone(), drops.clone());
            std::thread::spawn(move || {
                for v in 1..=OFFERS {
                    mailbox.publish(table(v, &drops));
                    if v % 64 == 0 {
                        std::thread::yield_now();
                    }
                }
            })
        };
        let mut current = Current::new(table(0, &drops));
        let (mut swaps, mut last) = (0u64, 0u64);
        loop {
            let done = publisher.is_finished();
            if current.take_from(&mailbox) {
                swaps += 1;
            }
            // Every entry of the value in use is its version: never a
            // mixture of an old and a new value; versions never go back.
            let t = current.get();
            assert!(t.version >= last, "{} after {last}", t.version);
            assert!(
                t.rows.iter().all(|&r| r == t.version),
                "torn at {}",
                t.version
            );
            last = t.version;
            if done && !current.take_from(&mailbox) {
                break;
            }
        }
        publisher.join().unwrap();
        // The last offer always arrives; some were replaced untaken.
        assert_eq!(current.get().version, OFFERS);
        assert!((1..=OFFERS).contains(&swaps));
        // Every value but the one in use was freed exactly once, on the
        // publisher's side or with the mailbox.
        drop(mailbox);
        drop(current.held.take());
        assert_eq!(drops.load(Ordering::Relaxed), OFFERS as usize);
        drop(current);
        assert_eq!(drops.load(Ordering::Relaxed), OFFERS as usize + 1);
    }

    #[test]
    fn the_reader_frees_nothing_and_the_publisher_frees_what_it_replaced() {
        let drops = Arc::new(AtomicUsize::new(0));
        let mailbox = Mailbox::<Table>::default();
        let mut current = Current::new(table(0, &drops));
        assert!(!current.take_from(&mailbox));
        // An untaken offer replaced by a newer one is freed by the
        // publisher.
        mailbox.publish(table(1, &drops));
        mailbox.publish(table(2, &drops));
        assert_eq!(drops.load(Ordering::Relaxed), 1);
        // Taking it frees nothing: the replaced value waits in a slot.
        assert!(current.take_from(&mailbox));
        assert_eq!(current.get().version, 2);
        assert_eq!(drops.load(Ordering::Relaxed), 1);
        // Fill every slot without the publisher collecting: the reader
        // holds the next replaced value, then stops taking offers.
        for v in 3..3 + RETIRE_SLOTS as u64 {
            free(
                mailbox
                    .pending
                    .swap(Box::into_raw(table(v, &drops)), Ordering::AcqRel),
            );
            assert!(current.take_from(&mailbox));
        }
        assert!(current.held.is_some());
        free(
            mailbox
                .pending
                .swap(Box::into_raw(table(99, &drops)), Ordering::AcqRel),
        );
        assert!(!current.take_from(&mailbox));
        assert_eq!(drops.load(Ordering::Relaxed), 1);
        // The publisher's next offer collects the slots; the reader
        // catches up.
        mailbox.publish(table(100, &drops));
        assert_eq!(drops.load(Ordering::Relaxed), 1 + RETIRE_SLOTS + 1);
        assert!(current.take_from(&mailbox));
        assert_eq!(current.get().version, 100);
    }
}
