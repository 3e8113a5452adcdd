//! Writes a benchmark record ([`augsplat_core::BenchRecord`]) for a measurement that no
//! example makes itself (a script's end-to-end run), with this commit, today's date and this
//! machine named as every record names them:
//!
//! `cargo run --release -p augsplat-core --example bench_record -- WHAT COMMAND FIGURE VALUE
//! UNIT --json PATH`

use augsplat_core::bench_record::{self, BenchRecord};

fn main() {
    let (args, json) = bench_record::args_and_json();
    let [what, command, figure, value, unit] = args.as_slice() else {
        eprintln!("usage: bench_record WHAT COMMAND FIGURE VALUE UNIT --json PATH");
        std::process::exit(2);
    };
    let Ok(value) = value.parse::<f64>() else {
        eprintln!("VALUE {value:?} is not a number");
        std::process::exit(2);
    };
    if json.is_none() {
        eprintln!("--json PATH is needed: the record goes there");
        std::process::exit(2);
    }
    BenchRecord::now(what, command, figure, value, unit).write_or_exit(json.as_deref());
}
