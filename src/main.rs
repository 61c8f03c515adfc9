//! The `causalcity` binary: parses flags, hands over to the library, and
//! turns its one error type into one exit code (2 bad input, 1 failure,
//! 130 interrupted).

mod cli;

use clap::Parser;

fn main() {
    causalcity::output::report_file_size_limit_as_error();
    let result = cli::run(cli::Cli::parse());
    if let Err(e) = result {
        causalcity::progress::note(format_args!("error: {e}"));
        std::process::exit(e.exit_code());
    }
}
