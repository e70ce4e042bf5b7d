//! The landmark layout's lateral range, `landmark_offset=lo-hi` (m): every
//! landmark of the synthetic car park sits on a random side of the true
//! path at a distance uniform in [lo, hi] ([`crate::carpark`]). The paper
//! states only "a seeded landmark layout along the path", so the range is a
//! setting to sweep (`landmark_offset=0.5-2,2-10,10-15`).

use crate::error::LocalizationError;

/// The key of the setting.
pub const KEY: &str = "landmark_offset";

/// Parse `lo-hi` (or one number: every landmark at that distance) against
/// the laser's radius. Refused, with the reason: text that is not one or
/// two numbers, lo ≤ 0 (a landmark on the path has no bearing from it),
/// lo > hi, and hi > `max_range` (a landmark farther to the side than the
/// laser reaches is seen, if at all, only where the path bends towards it).
pub fn parse_offset(text: &str, max_range: f64) -> Result<(f64, f64), LocalizationError> {
    let err = |msg: String| LocalizationError::Param {
        key: KEY.into(),
        msg: format!("'{text}': {msg}"),
    };
    let num = |s: &str| -> Result<f64, LocalizationError> {
        let t = s.trim();
        t.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| {
                err(format!(
                    "'{t}' is not a number of metres (want lo-hi, e.g. 2-10)"
                ))
            })
    };
    let (lo, hi) = match text.split_once('-') {
        Some((a, b)) => (num(a)?, num(b)?),
        None => {
            let x = num(text)?;
            (x, x)
        }
    };
    if lo <= 0.0 {
        return Err(err(format!(
            "the least offset must be > 0 m (a landmark on the path has no bearing), got {lo}"
        )));
    }
    if lo > hi {
        return Err(err(format!(
            "the least offset {lo} m exceeds the greatest {hi} m"
        )));
    }
    if hi > max_range {
        return Err(err(format!(
            "the greatest offset {hi} m exceeds the laser's radius max_range = {max_range} m"
        )));
    }
    Ok((lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::experiments::slam::setup;

    fn kv(pairs: &[(&str, &str)]) -> Vec<(String, String)> {
        pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    #[test]
    fn the_offset_range_is_read_and_the_default_is_2_to_10_m() {
        assert_eq!(parse_offset("2-10", 15.0).unwrap(), (2.0, 10.0));
        assert_eq!(parse_offset(" 0.5 - 2 ", 15.0).unwrap(), (0.5, 2.0));
        assert_eq!(parse_offset("4", 15.0).unwrap(), (4.0, 4.0));
        assert_eq!(parse_offset("10-15", 15.0).unwrap(), (10.0, 15.0));
        let d = setup(&[]).unwrap();
        assert_eq!(d.carpark.landmark_offset, (2.0, 10.0));
        let s = setup(&kv(&[("landmark_offset", "1-4")])).unwrap();
        assert_eq!(s.carpark.landmark_offset, (1.0, 4.0));
        // The radius it is checked against is the one given.
        let s = setup(&kv(&[("max_range", "30"), ("landmark_offset", "10-20")])).unwrap();
        assert_eq!(s.carpark.landmark_offset, (10.0, 20.0));
    }

    #[test]
    fn bad_offsets_are_refused_naming_the_key_and_the_reason() {
        for (text, why) in [
            ("", "not a number"),
            ("a-4", "'a' is not a number"),
            ("2-", "'' is not a number"),
            ("2-10-12", "'10-12' is not a number"),
            ("nan-3", "'nan' is not a number"),
            ("0-4", "must be > 0"),
            ("-1-4", "'' is not a number"),
            ("4-2", "exceeds the greatest"),
            ("10-16", "exceeds the laser's radius"),
        ] {
            match setup(&kv(&[("landmark_offset", text)])) {
                Err(LocalizationError::Param { key, msg }) => {
                    assert_eq!(key, "landmark_offset", "{text}");
                    assert!(msg.contains(why), "{text}: {msg}");
                    assert!(msg.contains(&format!("'{text}'")), "{text}: {msg}");
                }
                other => panic!("{text}: {other:?}"),
            }
        }
        // The radius it is checked against is the one given.
        assert!(setup(&kv(&[("max_range", "8"), ("landmark_offset", "2-10")])).is_err());
    }
}
