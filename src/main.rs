//! The `causalcity` binary: parses flags and hands over to the library.

use causalcity::cli::{Cli, Command};
use causalcity::orchestrate::progress::ProgressMode;
use causalcity::orchestrate::run::{generate, GenOptions, Summary};
use clap::Parser;

fn main() {
    let cli = Cli::parse();
    let code = match cli.command {
        Command::Gen(args) => {
            let options = GenOptions {
                spec_path: args.spec,
                out: args.out,
                limit: args.limit,
                threads: args.threads.map(|t| t as usize),
                images: !args.no_images,
                progress: if args.quiet { ProgressMode::Quiet } else { ProgressMode::Auto },
            };
            match generate(&options) {
                Ok(summary) => {
                    println!("{}", summary_line(&summary));
                    0
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    e.exit_code()
                }
            }
        }
    };
    std::process::exit(code);
}

fn summary_line(s: &Summary) -> String {
    let secs = s.elapsed.as_secs_f64();
    let mut line = format!(
        "wrote {} scenarios ({} frame pairs, {:.1} MB) to {} in {:.1} s: {:.1} scenarios/s on {} threads",
        s.scenarios,
        s.frame_pairs,
        s.bytes as f64 / 1e6,
        s.out.display(),
        secs,
        s.scenarios as f64 / secs.max(1e-9),
        s.threads
    );
    if let Some(peak) = s.peak_memory {
        line.push_str(&format!(", peak memory {:.0} MB", peak as f64 / 1e6));
    }
    line
}
