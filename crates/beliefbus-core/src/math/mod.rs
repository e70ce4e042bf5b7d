//! Numerical building blocks below the models, depending on nothing else in
//! the crate: small dense linear algebra on stack arrays ([`linalg`]), the
//! normal law restricted to an interval, stable in the tails
//! ([`truncnorm`]), and importance weights in the log domain ([`weights`]).

pub mod linalg;
pub mod truncnorm;
pub mod weights;

#[cfg(test)]
mod timing_tests;
