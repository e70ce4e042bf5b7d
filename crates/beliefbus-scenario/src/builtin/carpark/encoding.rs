//! How the car park's observations sit in the sensor ABI's observation
//! vector (8 values at most per sample, docs/sensor-abi.md §3):
//!
//! ```text
//! component   0     1     2   3   4    5   6   7
//! odometry    v_l   α
//! laser                   r₁  b₁  m₁   r₂  b₂  m₂
//! ```
//!
//! A laser sample carries one or two features (range r in m, bearing b in
//! rad in the laser frame, landmark index m as a float); an empty second
//! slot is (0, 0, −1). A scan of k features is ⌈k/2⌉ samples with the
//! same measurement time. Ingest's rate check admits a burst of 3 samples
//! at one instant, hence at most [`MAX_FEATURES`] features per scan.

use beliefbus_localization::laser::Observation;

/// Observation dimension.
pub const OBS: usize = 8;
/// Features per laser sample.
pub const PER_SAMPLE: usize = 2;
/// Laser samples ingest admits at one instant (its rate bucket).
pub const SAMPLES_PER_SCAN: usize = 3;
/// Features per scan.
pub const MAX_FEATURES: usize = PER_SAMPLE * SAMPLES_PER_SCAN;
/// First laser component.
pub const LASER0: usize = 2;
/// The landmark index of an empty slot.
pub const EMPTY: f64 = -1.0;

/// Write the odometry (v_l, α) into `y`.
pub fn write_odometry(y: &mut [f64], wheel_speed: f64, steering: f64) {
    y[0] = wheel_speed;
    y[1] = steering;
}

/// Write one or two features into `y`'s laser components.
pub fn write_laser(y: &mut [f64], a: &Observation, b: Option<&Observation>) {
    let slot = |y: &mut [f64], i: usize, o: Option<&Observation>| {
        let k = LASER0 + 3 * i;
        match o {
            Some(o) => {
                y[k] = o.range;
                y[k + 1] = o.bearing;
                y[k + 2] = o.landmark as f64;
            }
            None => {
                y[k] = 0.0;
                y[k + 1] = 0.0;
                y[k + 2] = EMPTY;
            }
        }
    };
    slot(y, 0, Some(a));
    slot(y, 1, b);
}

/// Why a laser sample's slot cannot be read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SlotError {
    /// The landmark index is not an integer in 0..map_len.
    Landmark(f64),
    /// The range is not positive and finite, or the bearing not finite.
    Value,
}

/// Read slot `i` (0 or 1) of a laser sample: `Ok(None)` for an empty one.
pub fn read_slot(y: &[f64], i: usize, map_len: usize) -> Result<Option<Observation>, SlotError> {
    let k = LASER0 + 3 * i;
    let (r, b, m) = (y[k], y[k + 1], y[k + 2]);
    if m == EMPTY {
        return Ok(None);
    }
    if !(m >= 0.0 && m.fract() == 0.0 && m < map_len as f64) {
        return Err(SlotError::Landmark(m));
    }
    if !(r.is_finite() && r > 0.0 && b.is_finite()) {
        return Err(SlotError::Value);
    }
    Ok(Some(Observation {
        range: r,
        bearing: b,
        landmark: m as usize,
    }))
}
