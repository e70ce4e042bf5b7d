//! The paper's Tables I and II (§VI), verbatim: cost per method at each σ.
//! Columns: ours, CE, CE-MLE, greedy. The percentages in parentheses are
//! derived: Table I's imply a full-observation reference of 12.834, Table
//! II's a reference of 113.70 that the stated protocol does not reproduce
//! (the full-observation threshold policy costs ≈ 125.5–126 over 40–41
//! discounted periods) but a horizon of about 20 periods does
//! ([`TABLE_II_REFERENCE_TERMS`]), so we compare absolute values there.

/// Which table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Protocol {
    /// Table I: average cost per period.
    Average,
    /// Table II: discounted total cost, γ.
    Discounted { gamma: f64 },
}

/// σ = 0.1, 0.3, …, 3.3.
pub const SIGMAS: [f64; 17] = [
    0.1, 0.3, 0.5, 0.7, 0.9, 1.1, 1.3, 1.5, 1.7, 1.9, 2.1, 2.3, 2.5, 2.7, 2.9, 3.1, 3.3,
];

/// The method names of the columns, as in our rows.
pub const METHODS: [&str; 4] = ["ours", "ce", "ce_mle", "greedy"];

/// Table I: average cost, one run of horizon 10⁵.
pub const TABLE_I: [[f64; 4]; 17] = [
    [12.849, 12.842, 12.837, 25.454],
    [12.845, 12.857, 12.861, 25.467],
    [12.864, 12.867, 12.884, 25.457],
    [12.881, 12.882, 12.890, 25.452],
    [12.904, 12.908, 12.940, 25.450],
    [12.938, 12.945, 12.969, 25.428],
    [12.973, 12.977, 12.993, 25.356],
    [13.016, 13.034, 13.029, 25.293],
    [13.066, 13.100, 13.117, 25.324],
    [13.110, 13.159, 13.172, 25.343],
    [13.123, 13.183, 13.227, 25.332],
    [13.210, 13.263, 13.292, 25.355],
    [13.250, 13.314, 13.333, 25.402],
    [13.323, 13.382, 13.454, 25.428],
    [13.374, 13.458, 13.497, 25.478],
    [13.444, 13.527, 13.580, 25.553],
    [13.512, 13.603, 13.655, 25.655],
];

/// Table II: discounted total cost (γ = 0.9), 1000 runs of horizon 40.
pub const TABLE_II: [[f64; 4]; 17] = [
    [129.126, 129.120, 129.090, 241.667],
    [129.016, 129.169, 129.105, 242.079],
    [129.097, 129.122, 129.164, 242.656],
    [129.474, 129.299, 129.623, 243.327],
    [129.868, 129.593, 129.762, 244.002],
    [129.940, 130.192, 130.229, 244.804],
    [130.336, 130.493, 130.543, 245.673],
    [130.575, 130.738, 131.085, 246.708],
    [130.724, 130.952, 131.446, 247.701],
    [131.266, 131.294, 131.595, 248.545],
    [131.778, 131.758, 132.235, 249.452],
    [132.176, 132.222, 132.763, 250.070],
    [132.741, 132.536, 133.467, 250.492],
    [133.070, 133.184, 133.978, 250.763],
    [133.484, 133.606, 134.558, 250.811],
    [133.961, 134.088, 135.827, 250.887],
    [134.502, 134.807, 136.117, 250.767],
];

/// The full-observation reference implied by Table I's percentages.
pub const TABLE_I_REFERENCE: f64 = 12.834;
/// The reference implied by Table II's percentages: not the stated
/// protocol's full-observation value, but a 21-term one
/// ([`TABLE_II_REFERENCE_TERMS`]).
pub const TABLE_II_REFERENCE: f64 = 113.70;

/// Terms of the discounted sum (i = 0..20, H = 20) whose full-observation
/// expectation [`TABLE_II_REFERENCE`] matches best (20 and 22 terms give
/// 111.82 and 114.77, each about one standard error away, so the horizon
/// is "about 20", not pinned to one term): the threshold policy's exact
/// 21-term value from x_0 = 5 is 113.37 (the reference +0.29 %, well
/// within one 1000-run standard error ≈ 1.3), its 41-term value 125.64 and its
/// infinite-horizon value 127.34. The table's entries are not on that
/// horizon (they sit near the infinite-horizon value), so its percentages
/// compare different horizons.
pub const TABLE_II_REFERENCE_TERMS: usize = 21;
/// The paper's full-observation optimal threshold.
pub const PAPER_THRESHOLD: f64 = 7.7;

/// The paper's row for σ (nearest tabulated σ within 1e-9), if any.
pub fn lookup(table: &[[f64; 4]; 17], sigma: f64) -> Option<[f64; 4]> {
    SIGMAS
        .iter()
        .position(|s| (s - sigma).abs() < 1e-9)
        .map(|i| table[i])
}
