//! The windowed normalised innovation squared (NIS) a track publishes: its own running
//! consistency check (Bar-Shalom, Li, Kirubarajan 2001, §5.4.2, the "time-average NIS").
//!
//! Each update's NIS εᵀS⁻¹ε is χ²(m) for a consistent filter, m the number of measured
//! components; over a window of updates the sum is χ²(Σm) when the innovations are white
//! (which a consistent filter's are). So the published pair (sum, Σm) is judged against the
//! χ²(Σm) quantiles: a sum far above its band says the filter is too sure of itself (or the
//! aircraft manoeuvres), far below too cautious. Fixed capacity: no allocation.

use super::{Observed, UNMEASURED_VARIANCE};

/// Updates in the window. Default 20: ten seconds of ADS-B at 2 Hz, about 90 degrees of
/// freedom with positions and velocities, where the 95 % band of the sum is ±30 % of its
/// mean: narrow enough to tell a filter off by a factor of 2 in variance.
pub const NIS_WINDOW: usize = 20;

/// A published windowed NIS: the sum over the window and its degrees of freedom.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NisStat {
    /// Σ NIS over the window.
    pub nis: f64,
    /// Σ m over the window (measured components).
    pub dof: u32,
}

/// The last [`NIS_WINDOW`] updates' NIS and dof.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NisWindow {
    nis: [f64; NIS_WINDOW],
    dof: [u8; NIS_WINDOW],
    next: usize,
    len: usize,
}

impl Default for NisWindow {
    fn default() -> Self {
        Self {
            nis: [0.0; NIS_WINDOW],
            dof: [0; NIS_WINDOW],
            next: 0,
            len: 0,
        }
    }
}

impl NisWindow {
    /// Adds one update's NIS over `dof` measured components (a non-finite NIS is skipped).
    pub fn push(&mut self, nis: f64, dof: u8) {
        if !nis.is_finite() || dof == 0 {
            return;
        }
        if let (Some(n), Some(d)) = (self.nis.get_mut(self.next), self.dof.get_mut(self.next)) {
            *n = nis;
            *d = dof;
        }
        self.next = (self.next + 1) % NIS_WINDOW;
        self.len = (self.len + 1).min(NIS_WINDOW);
    }

    /// Forgets everything (a new track).
    pub fn clear(&mut self) {
        *self = Self::default();
    }

    /// The sum and its dof; `None` while empty.
    pub fn stat(&self) -> Option<NisStat> {
        if self.len == 0 {
            return None;
        }
        // Unfilled slots hold zeros: summing the whole arrays is the window's sum.
        Some(NisStat {
            nis: self.nis.iter().sum(),
            dof: self.dof.iter().map(|&d| u32::from(d)).sum(),
        })
    }
}

/// Measured components of an observation (a component with [`UNMEASURED_VARIANCE`] is not).
pub fn measured_components(o: &Observed) -> u8 {
    (0..3)
        .map(|i| u8::from(o.cov[(i, i)] < 0.5 * UNMEASURED_VARIANCE))
        .sum()
}

/// Measured components of a report's position and velocity.
pub fn measured_dof(position: Option<&Observed>, velocity: Option<&Observed>) -> u8 {
    position.map_or(0, measured_components) + velocity.map_or(0, measured_components)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Vector3};

    #[test]
    fn window_sums_the_last_updates() {
        let mut w = NisWindow::default();
        assert_eq!(w.stat(), None);
        w.push(2.0, 3);
        w.push(f64::NAN, 3);
        assert_eq!(w.stat(), Some(NisStat { nis: 2.0, dof: 3 }));
        for _ in 0..NIS_WINDOW {
            w.push(1.0, 2);
        }
        // The first push left the window.
        assert_eq!(
            w.stat(),
            Some(NisStat {
                nis: NIS_WINDOW as f64,
                dof: 2 * NIS_WINDOW as u32
            })
        );
        let mut o = Observed {
            value: Vector3::zeros(),
            cov: Matrix3::identity(),
        };
        assert_eq!(measured_dof(Some(&o), None), 3);
        o.cov[(2, 2)] = UNMEASURED_VARIANCE;
        assert_eq!(measured_dof(Some(&o), Some(&o)), 4);
    }
}
