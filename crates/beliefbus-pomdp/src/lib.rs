//! Discrete POMDPs for beliefbus: Cassandra's `.pomdp` format ([`parse`]),
//! a point-based anytime solver ([`solver`]), α-vector policies
//! ([`policy`]) and a Monte-Carlo policy simulator ([`simulate`]).
//!
//! The model type [`Pomdp`] is shared by all of them; a POMDP built in code
//! (for instance from a Markov chain: sparse `T` per action, observation
//! likelihoods per state) goes through [`Pomdp::new`] and then to the same
//! [`solve`] as one read from a file.

pub mod belief;
pub mod chain_pomdp;
pub mod model;
pub mod parse;
pub mod policy;
pub mod simulate;
pub mod simulate_plan;
pub mod solver;

pub use model::{ModelError, Pomdp, SparseRows};
pub use parse::{parse_file, parse_str, ParseError};
pub use policy::{AlphaPolicy, PolicyError};
pub use simulate::{simulate, SimulateError, SimulateOptions, SimulationResult};
pub use simulate_plan::{simulate_plan, PlanSimulation};
pub use solver::{solve, Progress, Solution, SolveError, SolveOptions};
