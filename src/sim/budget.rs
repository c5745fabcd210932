//! The step budget: a run that cannot finish within it (or whose pace says
//! it would not) ends with a diagnostic instead of running for ever.

use super::SimError;

/// Default largest number of steps in a run (`--max-steps`). A TMAX that
/// asks for more than 10^7 steps is raised to TSTOP/10^7 before the run,
/// so a run that respects TMAX fits, with room for the error test's own
/// shorter steps.
pub const DEFAULT_MAX_STEPS: usize = 50_000_000;

/// The pace is judged over windows of this many steps.
const PACE_WINDOW: usize = 100_000;

/// Counts the steps of a run and checks its pace.
pub(super) struct Budget {
    max: usize,
    taken: usize,
    t_end: f64,
    /// Where the current pace window started, and its step count then.
    window: (f64, usize),
}

impl Budget {
    /// A budget of `max` steps for a run that has taken `taken` steps and
    /// is at `t` on its way to `t_end`.
    pub(super) fn new(max: usize, taken: usize, t: f64, t_end: f64) -> Budget {
        Budget {
            max,
            taken,
            t_end,
            window: (t, taken),
        }
    }

    /// The steps counted so far (with those before the budget began).
    pub(super) fn taken(&self) -> usize {
        self.taken
    }

    /// Count a step that ended at `t` with size `h`: an error when the run
    /// has used its budget, or when the pace of its last
    /// [`PACE_WINDOW`] steps would need more than twice what is left.
    pub(super) fn step(&mut self, t: f64, h: f64) -> Result<(), SimError> {
        self.taken += 1;
        let over = self.taken > self.max;
        let mut projected = None;
        if self.taken - self.window.1 >= PACE_WINDOW {
            let pace = (t - self.window.0) / (self.taken - self.window.1) as f64;
            let left = (self.t_end - t) / pace.max(f64::MIN_POSITIVE);
            // Twice what is left: a pace that is picking up gets its chance.
            if left > 2.0 * (self.max - self.taken.min(self.max)) as f64 {
                projected = Some(self.taken as f64 + left);
            }
            self.window = (t, self.taken);
        }
        if over || projected.is_some() {
            return Err(SimError::TooManySteps {
                steps: self.taken,
                max: self.max,
                t,
                h,
                tstop: self.t_end,
                projected,
                newton: None,
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_at_a_hopeless_pace_ends_after_one_window() {
        let mut b = Budget::new(1_000_000, 0, 0.0, 1.0);
        let mut t = 0.0;
        let mut err = None;
        for _ in 0..2 * PACE_WINDOW {
            t += 1e-9;
            if let Err(e) = b.step(t, 1e-9) {
                err = Some(e);
                break;
            }
        }
        match err {
            Some(SimError::TooManySteps {
                steps, projected, ..
            }) => {
                assert_eq!(steps, PACE_WINDOW);
                assert!(projected.is_some_and(|p| p > 1e8));
            }
            other => panic!("expected TooManySteps, got {other:?}"),
        }
    }

    /// The message says when the integrator's Newton, not its error test,
    /// held the steps short, and only then.
    #[test]
    fn a_stall_says_whether_the_corrector_held_the_steps() {
        let stalled = |newton| {
            SimError::TooManySteps {
                steps: 3001,
                max: 3000,
                t: 5e-8,
                h: 3e-12,
                tstop: 0.1,
                projected: None,
                newton,
            }
            .to_string()
        };
        assert!(stalled(Some((1731, 0))).contains("Newton failed 1731 times"));
        assert!(!stalled(Some((3, 40))).contains("Newton failed"));
        assert!(!stalled(None).contains("Newton failed"));
    }

    #[test]
    fn a_run_that_fits_its_budget_is_never_stopped() {
        let n = 3 * PACE_WINDOW;
        let mut b = Budget::new(n, 0, 0.0, 1.0);
        let h = 1.0 / n as f64;
        for k in 1..=n {
            b.step(k as f64 * h, h).unwrap();
        }
        assert!(b.step(1.0 + h, h).is_err());
    }
}
