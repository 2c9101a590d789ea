//! Plumbing shared by the alternative trackers ([`super::singer`], [`super::jerk`],
//! [`super::vsimm`]): input validation, out-of-order refusal, long-gap re-initiation and the
//! "velocity from a recent velocity report" rule of [`super::cv::CvKalman`], so that every
//! tracker starts and restarts tracks the same way and the evaluation compares the filters,
//! not their book-keeping.

use super::{Measurement, Observed, TrackError};
use nalgebra::{SMatrix, SVector};

/// What a tracker must do with one report. Returned by value and matched at once, never
/// stored: the size of its initiating variant (two reports) costs nothing kept.
#[derive(Clone, Copy, Debug, PartialEq)]
#[allow(clippy::large_enum_variant)]
pub(crate) enum Step {
    /// No track after this report (none yet, or a long gap dropped it and the report had no
    /// position): the tracker clears its track.
    NoTrack,
    /// Start (or restart) a track from this position; `velocity` is the same report's
    /// velocity or a recent one, with its age in seconds.
    Initiate {
        position: Observed,
        velocity: Option<(f64, Observed)>,
    },
    /// Predict the existing track over `dt_s` (>= 0) and update it with the report.
    Update { dt_s: f64 },
}

/// Track life-cycle rules (see [`super::cv::CvParams`] for the reasoning behind the values).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Lifecycle {
    /// A report this long after the track restarts it, s.
    pub max_gap_s: f64,
    /// A velocity report at most this old initialises a new track's velocity, s.
    pub init_velocity_max_age_s: f64,
    pending_velocity: Option<(f64, Observed)>,
    /// Times a long gap restarted the track.
    pub reinitialisations: u64,
}

fn observed_is_finite(o: &Observed) -> bool {
    o.value.iter().chain(o.cov.iter()).all(|v| v.is_finite())
}

impl Lifecycle {
    pub fn new(max_gap_s: f64, init_velocity_max_age_s: f64) -> Self {
        Self {
            max_gap_s,
            init_velocity_max_age_s,
            pending_velocity: None,
            reinitialisations: 0,
        }
    }

    /// Classifies a report given the time of the current track (`None`: no track).
    /// Non-finite input is `NonFinite`, a report older than the track `OutOfOrder`; neither
    /// changes anything.
    pub fn step(&mut self, m: &Measurement, track_t_s: Option<f64>) -> Result<Step, TrackError> {
        if !m.t_s.is_finite()
            || !m
                .position
                .iter()
                .chain(m.velocity.iter())
                .all(observed_is_finite)
        {
            return Err(TrackError::NonFinite("measurement"));
        }
        if let Some(t0) = track_t_s {
            if m.t_s < t0 {
                return Err(TrackError::OutOfOrder {
                    t_s: m.t_s,
                    track_t_s: t0,
                });
            }
            if m.t_s - t0 <= self.max_gap_s {
                return Ok(Step::Update { dt_s: m.t_s - t0 });
            }
            self.reinitialisations = self.reinitialisations.saturating_add(1);
        }
        match (&m.position, &m.velocity) {
            (Some(position), velocity) => {
                let recent = self.pending_velocity.take().and_then(|(tv, v)| {
                    let age_s = m.t_s - tv;
                    (0.0..=self.init_velocity_max_age_s)
                        .contains(&age_s)
                        .then_some((age_s, v))
                });
                Ok(Step::Initiate {
                    position: *position,
                    velocity: velocity.map(|v| (0.0, v)).or(recent),
                })
            }
            (None, Some(v)) => {
                if self.pending_velocity.is_none_or(|(tv, _)| m.t_s >= tv) {
                    self.pending_velocity = Some((m.t_s, *v));
                }
                Ok(Step::NoTrack)
            }
            (None, None) => Ok(Step::NoTrack),
        }
    }
}

/// A 3xN observation matrix picking the states `idx` (east, north, up).
pub(crate) fn pick<const N: usize>(idx: [usize; 3]) -> SMatrix<f64, 3, N> {
    let mut h = SMatrix::<f64, 3, N>::zeros();
    for (row, &col) in idx.iter().enumerate() {
        if col < N {
            h[(row, col)] = 1.0;
        }
    }
    h
}

/// The 3-vector of states `idx`.
pub(crate) fn gather<const N: usize>(x: &SVector<f64, N>, idx: [usize; 3]) -> SVector<f64, 3> {
    SVector::<f64, 3>::from_fn(|r, _| idx.get(r).and_then(|&i| x.get(i)).copied().unwrap_or(0.0))
}

/// The 3x3 block of `p` over the states `idx`.
pub(crate) fn gather_cov<const N: usize>(
    p: &SMatrix<f64, N, N>,
    idx: [usize; 3],
) -> SMatrix<f64, 3, 3> {
    SMatrix::<f64, 3, 3>::from_fn(|r, c| match (idx.get(r), idx.get(c)) {
        (Some(&i), Some(&j)) => p.get((i, j)).copied().unwrap_or(0.0),
        _ => 0.0,
    })
}

/// Writes an observed vector and its covariance into the states `idx` of `x` and `p`: the
/// inverse of [`gather`] and [`gather_cov`], for initiating a track from a report.
pub(crate) fn scatter<const N: usize>(
    x: &mut SVector<f64, N>,
    p: &mut SMatrix<f64, N, N>,
    idx: [usize; 3],
    o: &super::Observed,
) {
    for (r, &i) in idx.iter().enumerate() {
        if let (Some(xi), Some(&v)) = (x.get_mut(i), o.value.get(r)) {
            *xi = v;
        }
        for (c, &j) in idx.iter().enumerate() {
            if let (Some(pij), Some(&v)) = (p.get_mut((i, j)), o.cov.get((r, c))) {
                *pij = v;
            }
        }
    }
}
