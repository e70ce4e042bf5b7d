//! The `chain` slice channel between refine (publisher) and the filter's
//! chain backend (subscriber): its name, its QoS and the construction
//! parameters of the chains published on it — one definition for both
//! sides.

use crate::chain::snapshot;
use crate::chain::{moment_equations, ChainConfig, NearRule};
use crate::config::PipelineConfig;
use crate::ipc::{Qos, SliceQos};

/// The slice channel of chain snapshots.
pub const CHAIN_CHANNEL: &str = "chain";

/// The construction parameters of the pipeline's chain: moment-matching
/// kernel with the k-NN Near rule of `refine.knn_c`, built for the
/// reference control `refine.reference_control` (u₀ = 0 when empty).
pub fn chain_config(cfg: &PipelineConfig, dim: usize) -> ChainConfig {
    let mut c = ChainConfig::moment_matched(dim).with_near(NearRule::Knn {
        c: cfg.refine.knn_c,
    });
    let u0 = &cfg.refine.reference_control;
    c.control[..u0.len()].copy_from_slice(u0);
    c
}

/// The snapshot channel's QoS (identical for refine and filter): room for a
/// chain of `refine.max_states` states with the k-NN rule's out-degree.
pub fn chain_qos(cfg: &PipelineConfig, dim: usize) -> SliceQos {
    let n = cfg.refine.max_states;
    let k = ((cfg.refine.knn_c * (n as f64).ln()).ceil() as usize)
        .max(moment_equations(dim) + 1)
        .min(n - 1);
    SliceQos {
        max_len: snapshot::words_needed(dim, n, n * k),
        qos: Qos {
            history: 1,
            max_buffer: 1,
            default_buffer: 1,
            // Two: a restarted refine connects while the dead one's
            // connection may still be held by the filter.
            max_publishers: 2,
            max_subscribers: 3,
            max_nodes: 8,
        },
    }
}
