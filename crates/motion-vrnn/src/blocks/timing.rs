//! Where a step's time goes, block by block (`cargo xtask bench-train
//! --blocks`): while switched on, every fused block's CPU forward and
//! backward add their seconds to a table, summed over the threads that ran
//! them.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::Instant;

static ON: AtomicBool = AtomicBool::new(false);
/// Per block: forward and backward seconds, and calls.
type Table = BTreeMap<&'static str, ([f64; 2], u64)>;
static TABLE: Mutex<Table> = Mutex::new(BTreeMap::new());

/// Seconds one block spent over the steps timed, summed over threads.
#[derive(Clone, Debug, PartialEq)]
pub struct BlockTime {
    /// The block's op name (`linear`, `rollout`, …).
    pub name: &'static str,
    /// In its forward pass.
    pub forward: f64,
    /// In its backward pass.
    pub backward: f64,
    /// Calls, either way.
    pub calls: u64,
}

/// A block's pass being timed: its seconds are added to the table when it
/// is dropped (nothing is timed while the table is off).
pub(crate) struct Span {
    name: &'static str,
    backward: bool,
    start: Option<Instant>,
}

/// Time block `name`'s forward (or `backward`) pass until the span drops.
pub(crate) fn span(name: &'static str, backward: bool) -> Span {
    Span {
        name,
        backward,
        start: ON.load(Ordering::Relaxed).then(Instant::now),
    }
}

impl Drop for Span {
    fn drop(&mut self) {
        if let Some(s) = self.start {
            let dt = s.elapsed().as_secs_f64();
            let mut t = TABLE.lock().unwrap_or_else(|e| e.into_inner());
            let e = t.entry(self.name).or_insert(([0.0; 2], 0));
            e.0[self.backward as usize] += dt;
            e.1 += 1;
        }
    }
}

/// Empty the table and start timing.
pub fn start() {
    TABLE.lock().unwrap_or_else(|e| e.into_inner()).clear();
    ON.store(true, Ordering::Relaxed);
}

/// Stop timing; the table, the slowest block (both ways) first.
pub fn stop() -> Vec<BlockTime> {
    ON.store(false, Ordering::Relaxed);
    let t = std::mem::take(&mut *TABLE.lock().unwrap_or_else(|e| e.into_inner()));
    let mut v: Vec<BlockTime> = t
        .into_iter()
        .map(|(name, ([forward, backward], calls))| BlockTime {
            name,
            forward,
            backward,
            calls,
        })
        .collect();
    v.sort_by(|a, b| (b.forward + b.backward).total_cmp(&(a.forward + a.backward)));
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spans_count_only_while_on() {
        // Other tests' blocks may run meanwhile: only these names count.
        let mine = |t: &[BlockTime]| -> Vec<(&str, bool, u64)> {
            t.iter()
                .filter(|b| b.name.starts_with("timing-test"))
                .map(|b| (b.name, b.forward == 0.0, b.calls))
                .collect()
        };
        drop(span("timing-test off", false));
        start();
        for _ in 0..3 {
            drop(span("timing-test on", true));
        }
        let t = stop();
        drop(span("timing-test after", false));
        assert_eq!(mine(&t), [("timing-test on", true, 3)]);
        assert!(t.iter().all(|b| b.forward >= 0.0 && b.backward >= 0.0));
        assert!(mine(&stop()).is_empty());
    }
}
