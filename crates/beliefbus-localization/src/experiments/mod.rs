//! The paper's experiments as library functions (filled in below).
