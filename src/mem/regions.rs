//! First-fit ranges of one pool shared by many owners: the two-level
//! scene's geometries each take a run of the triangle budget
//! (`accel::twolevel`), and give it back when removed.
//!
//! The taken runs are kept sorted by start in a table carved at setup (one
//! entry per possible owner), so taking and freeing scan at most that many
//! entries and allocate nothing. Free space is what lies between runs; a
//! request that fits no gap but the gaps together would hold is served
//! after `compact` slides the runs down (the owner moves its data with
//! them), so only a short pool refuses.

use bytemuck::{Pod, Zeroable};

/// A taken run `[start, start + len)`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct Run {
    pub start: u32,
    pub len: u32,
}

/// The taken runs of a pool of `capacity` units.
pub struct Regions<'a> {
    runs: &'a mut [Run],
    used: usize,
    capacity: u32,
}

impl<'a> Regions<'a> {
    /// Runs of a pool of `capacity` units, at most `runs.len()` at once.
    pub fn new(runs: &'a mut [Run], capacity: u32) -> Self {
        Regions {
            runs,
            used: 0,
            capacity,
        }
    }

    /// Units in the pool.
    pub fn capacity(&self) -> u32 {
        self.capacity
    }

    /// Units taken.
    pub fn taken(&self) -> u32 {
        self.runs[..self.used].iter().map(|r| r.len).sum()
    }

    /// Where the gaps between runs start and how long they are, in order
    /// (gap `k` lies before run `k`; the last one ends the pool).
    fn gaps(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        let runs = &self.runs[..self.used];
        (0..=runs.len()).map(move |k| {
            let at = if k == 0 {
                0
            } else {
                runs[k - 1].start + runs[k - 1].len
            };
            let end = runs.get(k).map_or(self.capacity, |r| r.start);
            (at, end - at)
        })
    }

    /// The longest run a `take` could get now.
    pub fn largest_gap(&self) -> u32 {
        self.gaps().map(|g| g.1).max().unwrap_or(0)
    }

    /// Take the first gap of at least `len` units (`len` 0 takes an empty
    /// run at the first gap); `None` when none fits or the table is full.
    pub fn take(&mut self, len: u32) -> Option<u32> {
        if self.used == self.runs.len() {
            return None;
        }
        let (k, start) = self
            .gaps()
            .enumerate()
            .find(|(_, g)| g.1 >= len)
            .map(|(k, g)| (k, g.0))?;
        // Gap k lies before run k: insert there, keeping the order.
        self.runs.copy_within(k..self.used, k + 1);
        self.runs[k] = Run { start, len };
        self.used += 1;
        Some(start)
    }

    /// Slide every run down to close the gaps before it, in order, so the
    /// free units form one gap at the end: `take` then fits any length up
    /// to `capacity - taken`. `moved(from, to, len)` is called for each
    /// run that moves (`to < from`), in order, so the caller moves its
    /// data with `copy_within` before a later run lands where it was.
    /// Returns the units moved.
    pub fn compact(&mut self, mut moved: impl FnMut(u32, u32, u32)) -> u64 {
        let mut at = 0u32;
        let mut units = 0u64;
        for r in self.runs[..self.used].iter_mut() {
            if r.start != at {
                moved(r.start, at, r.len);
                units += u64::from(r.len);
                r.start = at;
            }
            at += r.len;
        }
        units
    }

    /// Give back the run `take` returned `start` (and `len`) for.
    /// Returns false (changing nothing) when there is no such run.
    pub fn free(&mut self, start: u32, len: u32) -> bool {
        let Some(k) = self.runs[..self.used]
            .iter()
            .position(|r| *r == Run { start, len })
        else {
            return false;
        };
        self.runs.copy_within(k + 1..self.used, k);
        self.used -= 1;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_fit_keeps_runs_apart_and_reuses_gaps() {
        let mut table = [Run::default(); 5];
        let mut r = Regions::new(&mut table, 100);
        assert_eq!(r.take(30), Some(0));
        assert_eq!(r.take(30), Some(30));
        assert_eq!(r.take(30), Some(60));
        assert_eq!(r.take(20), None, "10 units are left");
        assert_eq!(r.largest_gap(), 10);
        assert!(r.free(30, 30));
        assert!(!r.free(30, 30), "freed once");
        assert_eq!(r.taken(), 60);
        assert_eq!(r.take(20), Some(30), "the first gap that fits");
        assert_eq!(r.take(10), Some(50));
        assert_eq!(r.take(10), Some(90));
        assert_eq!(r.take(0), None, "the table holds 5 runs");
        assert_eq!(r.taken(), 100);
        assert!(r.free(0, 30) && r.free(60, 30));
        assert_eq!(r.largest_gap(), 30);
        // Fragmented: 60 units free in two gaps, no run of 40.
        assert_eq!(r.take(40), None);
        assert_eq!(r.take(30), Some(0));
    }

    #[test]
    fn compaction_closes_every_gap() {
        let mut table = [Run::default(); 6];
        let mut r = Regions::new(&mut table, 100);
        for _ in 0..5 {
            assert!(r.take(20).is_some());
        }
        assert!(r.free(0, 20) && r.free(40, 20) && r.free(80, 20));
        assert!(r.take(0).is_some(), "an empty run at the first gap");
        assert_eq!(r.take(50), None, "60 units free in three gaps");
        let mut moves = Vec::new();
        let units = r.compact(|from, to, len| moves.push((from, to, len)));
        // The empty run stays at 0; the runs at 20 and 60 slide down.
        assert_eq!(moves, vec![(20, 0, 20), (60, 20, 20)]);
        assert_eq!(units, 40);
        assert_eq!(r.largest_gap(), 60);
        assert_eq!(r.take(60), Some(40));
        assert_eq!(r.compact(|_, _, _| panic!("nothing to move")), 0);
    }

    #[test]
    fn empty_pool_and_empty_runs() {
        let mut table = [Run::default(); 2];
        let mut r = Regions::new(&mut table, 0);
        assert_eq!(r.take(1), None);
        assert_eq!(r.take(0), Some(0));
        assert!(r.free(0, 0));
        assert_eq!(r.largest_gap(), 0);
    }
}
