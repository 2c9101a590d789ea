//! Compact Position Reporting (DO-260B Appendix A.1.7; ICAO Doc 9871 §C.2.6).

/// NZ: number of latitude zones between the equator and a pole (DO-260B A.1.7.2).
pub const NZ: f64 = 15.0;

/// NL(lat): number of longitude zones at a latitude (DO-260B A.1.7.2 d), in 1..=59.
///
/// Computed from the closed form; exact at the table's transition latitudes up to f64 rounding,
/// which is why callers compare NL of both frames of a pair rather than trusting a boundary.
pub fn nl(lat_deg: f64) -> u32 {
    let lat = lat_deg.abs();
    if lat.is_nan() || lat >= 87.0 {
        return 1;
    }
    if lat == 0.0 {
        return 59;
    }
    let a = 1.0 - (std::f64::consts::PI / (2.0 * NZ)).cos();
    let b = (std::f64::consts::PI / 180.0 * lat).cos().powi(2);
    let x = 1.0 - a / b;
    if !(-1.0..=1.0).contains(&x) {
        return 1;
    }
    let n = (2.0 * std::f64::consts::PI / x.acos()).floor();
    (n as u32).clamp(1, 59)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nl_matches_transition_table() {
        // DO-260B Table A-21: NL changes at these latitudes.
        assert_eq!(nl(0.0), 59);
        assert_eq!(nl(10.47), 59);
        assert_eq!(nl(10.48), 58);
        assert_eq!(nl(52.0), 36);
        assert_eq!(nl(86.9), 2);
        assert_eq!(nl(87.0), 1);
        assert_eq!(nl(-52.0), 36);
    }
}
