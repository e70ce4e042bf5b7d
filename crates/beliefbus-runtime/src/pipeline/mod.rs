//! The pipeline as a whole: the launcher that validates the config, spawns,
//! pins and supervises the stage processes, the monitor that collects their
//! statistics and the truth, and the report.

pub use crate::config;
pub mod external;
pub mod launcher;
pub mod monitor;
pub mod report;
pub mod stage_main;
pub mod supervisor;
pub use crate::stage::resume as supervisor_resume;
pub mod supervisor_timeline;

pub use config::{ConfigError, PipelineConfig};
