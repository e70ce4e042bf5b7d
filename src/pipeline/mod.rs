//! The pipeline as a whole: its configuration (validated entirely before
//! anything starts), the scenarios, the launcher that spawns, pins and
//! supervises the stage processes, the monitor that collects their
//! statistics and the truth, and the report.

pub mod config;
pub mod external;
pub mod launcher;
pub mod monitor;
pub mod report;
pub mod scenario;
pub mod stage_main;
pub mod supervisor;
pub mod supervisor_resume;
pub mod supervisor_timeline;

pub use config::{ConfigError, PipelineConfig};
pub use scenario::{AnyModel, Scenario};
