//! One module per subcommand. Each has `Args` (clap) and `run`, returning a readable error.

pub mod bench;
pub mod compare;
pub mod compute_node;
pub mod expand;
pub mod gc;
pub mod inspect;
pub mod metrics;
pub mod plan;
pub mod render;
pub mod run;
pub mod status;
pub mod verify;
pub mod view;
pub mod weights;
pub mod why;

/// A subcommand's result: `Err` holds the report printed after `error: `.
pub type CmdResult = Result<(), String>;
