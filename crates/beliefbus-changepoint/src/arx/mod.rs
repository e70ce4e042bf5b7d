//! Change-point ARX model (placeholder, filled below).
