//! The motion queue of SPEC.md §7.3: a fixed ring of planned motions, the executing one at its
//! front, and the device-assigned motion ids (from 1 after power-up, 65535 wrapping to 1).

/// How one wheel is to move in a planned motion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Travel {
    /// Turn each wheel by these whole encoder counts (left, right) in `duration_us`, at constant
    /// speed, then complete.
    Counts {
        /// Left wheel travel (counts, signed).
        left: i32,
        /// Right wheel travel (counts, signed).
        right: i32,
        /// Time the motion takes at its commanded speed (µs).
        duration_us: u64,
    },
    /// Turn each wheel at these speeds (counts/s) until the next motion, STOP or the
    /// watchdog (WHEEL_SPEED with duration 0): never completes.
    OpenEnded {
        /// Left wheel speed (counts/s).
        left_counts_s: f64,
        /// Right wheel speed (counts/s).
        right_counts_s: f64,
    },
}

/// One accepted motion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Planned {
    /// Device-assigned id.
    pub id: u16,
    /// What the wheels do.
    pub travel: Travel,
}

impl Planned {
    /// Time it takes (µs); `None` if open-ended.
    pub fn duration_us(&self) -> Option<u64> {
        match self.travel {
            Travel::Counts { duration_us, .. } => Some(duration_us),
            Travel::OpenEnded { .. } => None,
        }
    }
}

/// The queue is full (NACK BUSY).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QueueFull;

/// A ring of at most `N` motions (the executing one included) and the id counter.
#[derive(Debug, Clone)]
pub struct MotionQueue<const N: usize> {
    slots: [Option<Planned>; N],
    head: usize,
    len: usize,
    next_id: u16,
}

impl<const N: usize> Default for MotionQueue<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> MotionQueue<N> {
    /// An empty queue whose first motion will be id 1.
    pub const fn new() -> Self {
        MotionQueue {
            slots: [None; N],
            head: 0,
            len: 0,
            next_id: 1,
        }
    }

    /// Motions queued, the executing one included (SPEC.md §7.3: a lone running motion is 1).
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether nothing is queued or executing.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Appends a motion, assigning it the next id; returns the motion as queued.
    pub fn push(&mut self, travel: Travel) -> Result<Planned, QueueFull> {
        if self.len >= N {
            return Err(QueueFull);
        }
        let planned = Planned {
            id: self.next_id,
            travel,
        };
        // 0 means "no motion" on the wire: after 65535 comes 1.
        self.next_id = self.next_id.checked_add(1).unwrap_or(1);
        self.slots[(self.head + self.len) % N] = Some(planned);
        self.len += 1;
        Ok(planned)
    }

    /// The executing (or next to execute) motion.
    pub fn front(&self) -> Option<&Planned> {
        if self.len == 0 {
            None
        } else {
            self.slots[self.head].as_ref()
        }
    }

    /// Removes the front motion.
    pub fn pop_front(&mut self) -> Option<Planned> {
        if self.len == 0 {
            return None;
        }
        let p = self.slots[self.head].take();
        self.head = (self.head + 1) % N;
        self.len -= 1;
        p
    }

    /// Drops every motion (ids already given out stay used).
    pub fn clear(&mut self) {
        self.slots = [None; N];
        self.head = 0;
        self.len = 0;
    }

    /// The queued motions, front first.
    pub fn iter(&self) -> impl Iterator<Item = &Planned> + '_ {
        (0..self.len).filter_map(move |i| self.slots[(self.head + i) % N].as_ref())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const STEP: Travel = Travel::Counts {
        left: 10,
        right: 10,
        duration_us: 1000,
    };

    #[test]
    fn ids_count_from_one_and_wrap_past_65535_to_one_never_zero() {
        let mut q = MotionQueue::<4>::new();
        assert_eq!(q.push(STEP).map(|p| p.id), Ok(1));
        q.pop_front();
        for expected in 2..=65535u16 {
            assert_eq!(q.push(STEP).map(|p| p.id), Ok(expected));
            q.pop_front();
        }
        assert_eq!(q.push(STEP).map(|p| p.id), Ok(1));
        assert_eq!(q.push(STEP).map(|p| p.id), Ok(2));
    }

    #[test]
    fn a_full_queue_refuses_and_keeps_its_order_across_the_ring() {
        let mut q = MotionQueue::<4>::new();
        for _ in 0..3 {
            q.push(STEP).unwrap();
        }
        q.pop_front();
        q.push(STEP).unwrap();
        q.push(STEP).unwrap();
        assert_eq!(q.len(), 4);
        assert_eq!(q.push(STEP), Err(QueueFull));
        let ids: [u16; 4] = core::array::from_fn(|i| q.iter().nth(i).map_or(0, |p| p.id));
        assert_eq!(ids, [2, 3, 4, 5]);
        assert_eq!(q.front().map(|p| p.id), Some(2));
        q.clear();
        assert!(q.is_empty() && q.front().is_none());
        // Ids given out before the clear are not reused.
        assert_eq!(q.push(STEP).map(|p| p.id), Ok(6));
    }
}
