//! The published figures the `slam` experiment prints beside its own: Table 6
//! of paper 003 (Morzfeld, implicit sampling for SLAM, §4.2.1) and the
//! EKF-SLAM figure of its text.

/// Table 6 of the paper: samples, then (time ms, error %) of FastSLAM,
/// FastSLAM 2.0 and implicit sampling.
type Cell = Option<(f64, f64)>;
pub const TABLE6: &[(usize, Cell, Cell, Cell)] = &[
    (10, None, None, Some((7.31, 8.31))),
    (
        20,
        Some((5.55, 17.7)),
        Some((8.36, 20.0)),
        Some((14.4, 7.18)),
    ),
    (
        50,
        Some((13.6, 14.8)),
        Some((20.5, 13.1)),
        Some((35.4, 4.54)),
    ),
    (
        100,
        Some((26.9, 12.0)),
        Some((40.7, 8.36)),
        Some((70.3, 2.98)),
    ),
    (
        200,
        Some((52.7, 10.8)),
        Some((82.1, 5.24)),
        Some((140.9, 2.55)),
    ),
    (
        400,
        Some((105.2, 7.64)),
        Some((164.0, 4.83)),
        Some((286.0, 3.25)),
    ),
    (
        500,
        Some((133.2, 8.67)),
        Some((346.7, 4.71)),
        Some((355.9, 3.25)),
    ),
    (800, Some((213.2, 10.4)), None, None),
    (1000, Some((280.1, 8.78)), None, None),
];
/// EKF-SLAM in the paper's text: 3.89 % at 0.43 ms.
pub const EKF: (f64, f64) = (0.43, 3.89);
