//! The `slam` experiment's noise reading and map score. Table 7 of paper
//! 003 calls P and Q covariances, but the model multiplies dW_u and dW by
//! them; the appendix's gradient divides the laser innovations by σ₁, σ₂,
//! while 0.05π/180 reads as a standard deviation of 0.05° (the notes'
//! §3.4). [`NoiseReading`] picks one reading for the filters and the
//! synthetic data alike.

use crate::error::LocalizationError;
use crate::geometry::Point;
use crate::laser::LaserNoise;
use crate::vehicle::MotionNoise;

/// How the numbers of Table 7 and σ₁, σ₂ are read (the notes' §3.4): the
/// table calls P and Q covariances, but the model multiplies dW by them,
/// and the appendix's gradient divides by σ where 0.05π/180 reads as a
/// standard deviation of 0.05°.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NoiseReading {
    /// P, Q and σ₁, σ₂ are the diagonal entries of the covariances.
    Variance,
    /// They are standard deviations (of the intensities): Σ₁ = δ(G PPᵀ Gᵀ + QQᵀ),
    /// Σ₂ = diag(σ₁², σ₂²).
    Sigma,
}

impl NoiseReading {
    /// Parse "variance" or "sigma" (`noise_reading`).
    pub fn parse(s: &str) -> Result<Self, LocalizationError> {
        Self::parse_key("noise_reading", s)
    }

    /// Parse "variance" or "sigma" given for `key`.
    pub fn parse_key(key: &str, s: &str) -> Result<Self, LocalizationError> {
        match s {
            "variance" => Ok(Self::Variance),
            "sigma" => Ok(Self::Sigma),
            _ => Err(LocalizationError::Param {
                key: key.into(),
                msg: format!("'{s}': need 'variance' or 'sigma'"),
            }),
        }
    }

    /// The motion noise intensities under this reading.
    pub fn motion(self, m: MotionNoise) -> MotionNoise {
        match self {
            Self::Variance => m,
            Self::Sigma => MotionNoise {
                p: m.p.map(|v| v * v),
                q: m.q.map(|v| v * v),
            },
        }
    }

    /// The laser variances under this reading.
    pub fn laser(self, l: LaserNoise) -> LaserNoise {
        match self {
            Self::Variance => l,
            Self::Sigma => LaserNoise {
                var_range: l.var_range * l.var_range,
                var_bearing: l.var_bearing * l.var_bearing,
            },
        }
    }
}

/// Mean distance from each estimated landmark to its nearest true one.
pub fn map_error(est: &[Point], truth: &[Point]) -> f64 {
    if est.is_empty() {
        return 0.0;
    }
    let near = |m: &Point| {
        truth
            .iter()
            .map(|t| (t[0] - m[0]).hypot(t[1] - m[1]))
            .fold(f64::INFINITY, f64::min)
    };
    est.iter().map(near).sum::<f64>() / est.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sigma_reading_squares_every_table_entry() {
        let m = NoiseReading::Sigma.motion(MotionNoise::default());
        assert_eq!(m.p, [0.25, 0.25]);
        assert!((m.q[0] - 0.01).abs() < 1e-15 && (m.q[1] - 0.01).abs() < 1e-15);
        assert!((m.q[2] - (0.1f64.to_radians()).powi(2)).abs() < 1e-18);
        let l = NoiseReading::Sigma.laser(LaserNoise::default());
        assert!((l.var_range - 0.0025).abs() < 1e-15);
        assert!((l.var_bearing - 0.05f64.to_radians().powi(2)).abs() < 1e-18);
        assert_eq!(
            NoiseReading::Variance.motion(MotionNoise::default()),
            MotionNoise::default()
        );
        assert_eq!(NoiseReading::parse("sigma").unwrap(), NoiseReading::Sigma);
        assert!(NoiseReading::parse("std").is_err());
    }

    #[test]
    fn the_paths_figure_sits_beside_the_error_figure() {
        use crate::experiments::slam_plot::paths_file;
        assert_eq!(paths_file("out/slam.svg"), "out/slam-paths.svg");
        assert_eq!(paths_file("slam"), "slam-paths.svg");
    }

    #[test]
    fn map_error_is_the_mean_distance_to_the_nearest_true_landmark() {
        let truth = [[0.0, 0.0], [10.0, 0.0]];
        let est = [[0.0, 3.0], [9.0, 0.0], [10.0, 4.0]];
        assert!((map_error(&est, &truth) - (3.0 + 1.0 + 4.0) / 3.0).abs() < 1e-12);
        assert_eq!(map_error(&[], &truth), 0.0);
    }

    #[test]
    fn the_laser_reading_can_differ_from_the_motion_reading() {
        use crate::experiments::slam::setup;
        let kv = |pairs: &[(&str, &str)]| -> Vec<(String, String)> {
            pairs
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect()
        };
        let sigma = setup(&[]).unwrap();
        let lv = setup(&kv(&[("laser_reading", "variance")])).unwrap();
        // The laser's variances are Table 7's numbers, the motion keeps σ.
        assert_eq!(lv.model.laser, LaserNoise::default());
        assert_eq!(lv.carpark.laser, LaserNoise::default());
        assert_eq!(lv.model.motion, sigma.model.motion);
        assert_eq!(
            sigma.model.laser,
            NoiseReading::Sigma.laser(LaserNoise::default())
        );
        // Without laser_reading the laser follows noise_reading.
        let v = setup(&kv(&[("noise_reading", "variance")])).unwrap();
        assert_eq!(v.model.laser, LaserNoise::default());
        assert_eq!(v.model.motion, MotionNoise::default());
        let back = setup(&kv(&[
            ("noise_reading", "variance"),
            ("laser_reading", "sigma"),
        ]))
        .unwrap();
        assert_eq!(back.model.laser, sigma.model.laser);
        match setup(&kv(&[("laser_reading", "std")])) {
            Err(LocalizationError::Param { key, msg }) => {
                assert_eq!(key, "laser_reading");
                assert!(msg.contains("std"), "{msg}");
            }
            other => panic!("{other:?}"),
        }
    }
}
