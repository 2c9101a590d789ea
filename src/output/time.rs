//! UTC calendar arithmetic for the outputs' timestamps (no time-zone database needed: UTC
//! has none, and leap seconds are not counted in Unix time).

/// Unix time of 2000-01-01T00:00:00Z: a feed time below it is not a Unix time (a Beast
/// receiver's 12 MHz counter starts near zero), and the outputs use the wall clock instead.
pub const UNIX_2000_S: f64 = 946_684_800.0;

/// Seconds in a day.
pub const DAY_S: f64 = 86_400.0;

/// The wall clock as Unix time, s.
pub fn now_unix_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

/// Feed time `t_s` when it is a Unix time (after 2000), else the wall clock.
pub fn utc_of_feed_time(t_s: f64) -> f64 {
    if t_s.is_finite() && t_s >= UNIX_2000_S {
        t_s
    } else {
        now_unix_s()
    }
}

/// (year, month 1-12, day 1-31) of a count of days since 1970-01-01 (proleptic Gregorian;
/// H. Hinnant's `civil_from_days`).
pub fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let y = yoe + era * 400;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = if m <= 2 { y + 1 } else { y };
    // d is within 1..=31 and m within 1..=12 by construction.
    (y, m as u32, d as u32)
}

/// `YYYY/MM/DD` and `HH:MM:SS.mmm` (UTC) of a Unix time, as SBS writes them.
pub fn sbs_date_time(unix_s: f64) -> (String, String) {
    let ms_total = (unix_s * 1000.0).round() as i64;
    let days = ms_total.div_euclid(86_400_000);
    let ms_of_day = ms_total.rem_euclid(86_400_000);
    let (y, mo, d) = civil_from_days(days);
    let h = ms_of_day / 3_600_000;
    let mi = ms_of_day / 60_000 % 60;
    let s = ms_of_day / 1000 % 60;
    let ms = ms_of_day % 1000;
    (
        format!("{y:04}/{mo:02}/{d:02}"),
        format!("{h:02}:{mi:02}:{s:02}.{ms:03}"),
    )
}

/// Seconds since the last UTC midnight of a Unix time (ASTERIX time of day).
pub fn time_of_day_s(unix_s: f64) -> f64 {
    unix_s.rem_euclid(DAY_S)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_and_times() {
        assert_eq!(civil_from_days(0), (1970, 1, 1));
        // 2024-07-06T06:43:09.525Z (the AFR34ZG recording's first frame).
        let (d, t) = sbs_date_time(1_720_248_189.525);
        assert_eq!(d, "2024/07/06");
        assert_eq!(t, "06:43:09.525");
        let (d, t) = sbs_date_time(951_782_400.0); // 2000-02-29
        assert_eq!((d.as_str(), t.as_str()), ("2000/02/29", "00:00:00.000"));
        assert!((time_of_day_s(1_720_248_189.5) - 24_189.5).abs() < 1e-6);
        assert_eq!(utc_of_feed_time(1_720_248_189.5), 1_720_248_189.5);
        assert!(utc_of_feed_time(12.0) > UNIX_2000_S);
    }
}
