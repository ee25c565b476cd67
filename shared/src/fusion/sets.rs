//! Sample sets from samples that arrive one unit at a time: the units are triggered together,
//! so one set's samples carry nearly the same time stamp, and a stamp more than half an
//! interval after the set's closes it. A unit missing from a set is a dropout, which the
//! fault monitors see. A unit that was late and catches up gives two samples within one set:
//! the later replaces the earlier, which is stale; and a sample stamped within a set already
//! closed is discarded. Closing a set for such a sample instead would make the healthy units
//! look absent.

use super::{UnitReading, UNITS};

/// A completed sample set: the first sample's time (microseconds) and each unit's reading.
pub type SampleSet = (u64, [Option<UnitReading>; UNITS]);

/// Groups samples into sets.
#[derive(Debug, Clone)]
pub struct SetAssembler {
    pending: [Option<UnitReading>; UNITS],
    set_t_us: Option<u64>,
    /// The last closed set's time.
    closed_t_us: Option<u64>,
    half_interval_us: u64,
    /// Stale samples: replaced within their set, or arriving after it closed.
    discarded: u32,
}

impl SetAssembler {
    /// Sets `interval_us` apart.
    pub fn new(interval_us: u64) -> Self {
        Self {
            pending: [None; UNITS],
            set_t_us: None,
            closed_t_us: None,
            half_interval_us: interval_us / 2,
            discarded: 0,
        }
    }

    /// Stale samples discarded so far.
    pub fn discarded(&self) -> u32 {
        self.discarded
    }

    /// Unit `unit`'s sample at `t_us`; returns the set it completes or closes, if any.
    pub fn push(&mut self, unit: usize, t_us: u64, reading: UnitReading) -> Option<SampleSet> {
        if unit >= UNITS {
            return None;
        }
        let belongs_to_closed = self
            .closed_t_us
            .is_some_and(|t| t_us <= t.saturating_add(self.half_interval_us));
        if self.set_t_us.is_none() && belongs_to_closed {
            self.discarded = self.discarded.saturating_add(1);
            return None;
        }
        let mut closed = None;
        if let Some(t0) = self.set_t_us {
            if t_us > t0.saturating_add(self.half_interval_us) {
                closed = self.finish();
            } else if self.pending[unit].is_some() {
                self.discarded = self.discarded.saturating_add(1);
            }
        }
        self.set_t_us.get_or_insert(t_us);
        self.pending[unit] = Some(reading);
        if closed.is_none() && self.pending.iter().all(Option::is_some) {
            closed = self.finish();
        }
        closed
    }

    /// The set being gathered, closed as it is (at the end of the data).
    pub fn finish(&mut self) -> Option<SampleSet> {
        let t_us = self.set_t_us.take()?;
        self.closed_t_us = Some(t_us);
        Some((t_us, core::mem::replace(&mut self.pending, [None; UNITS])))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reading(x: f32) -> UnitReading {
        UnitReading {
            gyro_rad_s: [x; 3],
            accel_m_s2: [x; 3],
        }
    }

    #[test]
    fn complete_sets_close_at_once_and_a_missing_unit_is_a_gap() {
        let mut sets = SetAssembler::new(1000);
        assert_eq!(sets.push(0, 1000, reading(0.0)), None);
        assert_eq!(sets.push(2, 1003, reading(2.0)), None);
        let (t, set) = sets.push(1, 1001, reading(1.0)).unwrap();
        assert_eq!(t, 1000);
        assert_eq!(
            set,
            [Some(reading(0.0)), Some(reading(1.0)), Some(reading(2.0))]
        );
        // Unit 1 misses the next set: unit 0's next sample, a set later, closes it.
        assert_eq!(sets.push(0, 2000, reading(0.5)), None);
        assert_eq!(sets.push(2, 2002, reading(2.5)), None);
        let (t, set) = sets.push(0, 3000, reading(0.7)).unwrap();
        assert_eq!(
            (t, set),
            (2000, [Some(reading(0.5)), None, Some(reading(2.5))])
        );
        assert_eq!(
            sets.finish(),
            Some((3000, [Some(reading(0.7)), None, None]))
        );
        assert_eq!(sets.finish(), None);
        assert_eq!(sets.push(3, 4000, reading(9.0)), None);
    }

    #[test]
    fn a_late_unit_catching_up_is_discarded_not_a_set_of_its_own() {
        let mut sets = SetAssembler::new(1000);
        assert_eq!(sets.push(0, 1000, reading(0.0)), None);
        assert_eq!(sets.push(2, 1000, reading(2.0)), None);
        // Unit 1's late sample of the previous instant completes the set at 1000 ...
        assert!(sets.push(1, 1000, reading(0.9)).is_some());
        // ... and its own sample of 1000, stamped 1000 too, has no set left to join.
        assert_eq!(sets.push(1, 1000, reading(1.0)), None);
        assert_eq!(sets.discarded(), 1);
        // Within an open set, the later of a unit's two samples is the one kept.
        assert_eq!(sets.push(0, 2000, reading(0.0)), None);
        assert_eq!(sets.push(1, 2000, reading(0.4)), None);
        assert_eq!(sets.push(1, 2001, reading(0.5)), None);
        let (t, set) = sets.push(2, 2002, reading(2.0)).unwrap();
        assert_eq!(t, 2000);
        assert_eq!(
            set,
            [Some(reading(0.0)), Some(reading(0.5)), Some(reading(2.0))]
        );
        assert_eq!(sets.discarded(), 2);
    }
}
