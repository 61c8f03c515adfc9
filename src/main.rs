//! The `causalcity` binary: parses flags and hands over to the library.

use causalcity::cli::{Cli, Command, ExportCommand};
use causalcity::export::nri::{export_nri, NriOptions};
use causalcity::orchestrate::merge::merge;
use causalcity::orchestrate::progress::ProgressMode;
use causalcity::orchestrate::run::{generate, GenOptions, Summary};
use causalcity::validate::validate;
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
                annotations: args.annotations,
                progress: if args.quiet { ProgressMode::Quiet } else { ProgressMode::Auto },
                shard: args.shard,
                force: args.force,
                fsync: args.fsync,
                handle_signals: true,
            };
            match generate(&options) {
                Ok(summary) => {
                    if args.json {
                        println!("{}", serde_json::to_string_pretty(&summary).expect("summary serialises"));
                    } else {
                        println!("{}", summary_line(&summary));
                    }
                    0
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    e.exit_code()
                }
            }
        }
        Command::Merge(args) => match merge(&args.out, &args.shards) {
            Ok(report) => {
                println!("{report}");
                0
            }
            Err(e) => {
                eprintln!("error: {e}");
                e.exit_code()
            }
        },
        Command::Export(ExportCommand::Nri(args)) => {
            let options = NriOptions { layout: args.layout, suffix: args.suffix, directed: args.directed };
            match export_nri(&args.dataset, &args.out, &options) {
                Ok(report) => {
                    for line in report {
                        println!("{line}");
                    }
                    0
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    1
                }
            }
        }
        Command::Export(ExportCommand::Nsdr(args)) => {
            finish(causalcity::export::nsdr::export_nsdr(&args.dataset, &args.out, progress_mode(args.quiet)), |n| {
                println!("wrote annotations.json for {n} scenarios under {}", args.out.display())
            })
        }
        Command::Export(ExportCommand::Vcdn(args)) => {
            finish(causalcity::export::vcdn::export_vcdn(&args.dataset, &args.out, progress_mode(args.quiet)), |n| {
                println!("wrote {n} V-CDN HDF5 files under {}", args.out.display())
            })
        }
        Command::Preview(args) => {
            let options = causalcity::preview::PreviewOptions {
                scale: args.scale,
                every: args.every,
                fps: args.fps,
                masks: args.masks,
                trails: args.trails,
                arrows: args.arrows,
                sheet_frames: args.sheet_frames,
                columns: args.columns,
            };
            finish(causalcity::preview::preview(&args.scenario, &args.out, &options), |s| {
                println!(
                    "wrote {} ({}x{}, {} frames, {:.0} KB)",
                    args.out.display(),
                    s.width,
                    s.height,
                    s.frames,
                    s.bytes as f64 / 1e3
                )
            })
        }
        Command::Baseline(args) => {
            finish(causalcity::analysis::baseline::baseline(&args.dataset, args.max_lag), |report| {
                if args.json {
                    println!("{}", serde_json::to_string_pretty(&report).expect("report serialises"));
                } else {
                    print!("{report}");
                }
            })
        }
        Command::Run(args) => {
            let options = run_options(&args);
            match causalcity::orchestrate::handwritten::run_file(&options) {
                Ok(written) => {
                    if args.json {
                        println!("{}", serde_json::to_string_pretty(&written).expect("report serialises"));
                    } else {
                        for w in &written {
                            println!("wrote {} ({:.1} MB)", w.path.display(), w.bytes as f64 / 1e6);
                        }
                    }
                    0
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    e.exit_code()
                }
            }
        }
        Command::Counterfactual(args) => {
            use causalcity::orchestrate::handwritten::{counterfactual, sweep, RunOptions, SweepOptions};
            let images = !args.no_images;
            if let Some(spec_path) = args.sweep.clone() {
                let options = SweepOptions {
                    spec_path,
                    out: args.out.clone(),
                    limit: args.limit,
                    kinds: args.kinds.clone(),
                    products: causalcity::output::manifest::Products { images, annotations: false },
                    threads: args.threads.map(|t| t as usize),
                    progress: progress_mode(args.quiet),
                };
                match sweep(&options) {
                    Ok(summary) => {
                        if args.json {
                            println!("{}", serde_json::to_string_pretty(&summary).expect("summary serialises"));
                        } else {
                            println!(
                                "wrote {} counterfactual pairs to {}: {} with an effect, {:.2} cars affected on average",
                                summary.pairs,
                                summary.out.display(),
                                summary.pairs_with_effect,
                                summary.mean_affected_cars
                            );
                        }
                        0
                    }
                    Err(e) => {
                        eprintln!("error: {e}");
                        e.exit_code()
                    }
                }
            } else {
                let options = RunOptions {
                    scenario_file: args.scenario.clone().expect("clap requires --scenario or --sweep"),
                    out: args.out.clone(),
                    world: args.world,
                    images,
                    annotations: false,
                };
                match counterfactual(&options, args.intervention.as_deref()) {
                    Ok(pairs) => {
                        if args.json {
                            println!("{}", serde_json::to_string_pretty(&pairs).expect("report serialises"));
                        } else {
                            for p in &pairs {
                                println!(
                                    "{}: {} -> affected {} of {} cars: {}",
                                    p.scenario,
                                    p.interventions.join("; "),
                                    p.affected.len(),
                                    p.cars.len(),
                                    if p.affected.is_empty() { "none".to_string() } else { p.affected.join(", ") }
                                );
                            }
                        }
                        0
                    }
                    Err(e) => {
                        eprintln!("error: {e}");
                        e.exit_code()
                    }
                }
            }
        }
        Command::Stats(args) => match causalcity::analysis::stats::dataset_stats(&args.dataset) {
            Ok(stats) => {
                if args.json {
                    println!("{}", serde_json::to_string_pretty(&stats).expect("stats serialise"));
                } else {
                    print!("{stats}");
                }
                0
            }
            Err(e) => {
                eprintln!("error: {e}");
                1
            }
        },
        Command::Heatmap(args) => {
            use causalcity::analysis::heatmap::{heatmap, HeatmapFilter};
            use causalcity::spec::Split;
            let split = args.split.as_deref().map(|s| match s {
                "train" => Split::Train,
                "val" => Split::Val,
                _ => Split::Test,
            });
            match heatmap(&args.dataset, &args.out, &HeatmapFilter { group: args.group, split }) {
                Ok(summary) => {
                    if args.json {
                        println!("{}", serde_json::to_string_pretty(&summary).expect("summary serialises"));
                    } else {
                        println!(
                            "wrote {} ({}x{}): {} scenarios, {} car-frames, {} cells visited, dwell CV {:.2}",
                            args.out.display(),
                            summary.width,
                            summary.height,
                            summary.scenarios,
                            summary.car_frames,
                            summary.cells_visited,
                            summary.visited_cell_cv
                        );
                    }
                    0
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    1
                }
            }
        }
        Command::Validate(args) => match validate(&args.dir, args.threads.map(|t| t as usize)) {
            Ok(report) => {
                if args.json {
                    println!("{}", serde_json::to_string_pretty(&report).expect("report serialises"));
                } else {
                    print!("{report}");
                }
                if report.problems.is_empty() {
                    0
                } else {
                    1
                }
            }
            Err(e) => {
                eprintln!("error: {e}");
                2
            }
        },
    };
    std::process::exit(code);
}

/// Exit code 0 after `done` on success; the error and exit 1 otherwise.
fn finish<T>(result: Result<T, String>, done: impl FnOnce(T)) -> i32 {
    match result {
        Ok(value) => {
            done(value);
            0
        }
        Err(e) => {
            eprintln!("error: {e}");
            1
        }
    }
}

fn run_options(args: &causalcity::cli::RunArgs) -> causalcity::orchestrate::handwritten::RunOptions {
    causalcity::orchestrate::handwritten::RunOptions {
        scenario_file: args.scenario.clone(),
        out: args.out.clone(),
        world: args.world,
        images: !args.no_images,
        annotations: args.annotations,
    }
}

fn progress_mode(quiet: bool) -> ProgressMode {
    if quiet {
        ProgressMode::Quiet
    } else {
        ProgressMode::Auto
    }
}

fn summary_line(s: &Summary) -> String {
    let secs = s.elapsed.as_secs_f64();
    let mut line = format!(
        "wrote {} scenarios ({} frame pairs, {:.1} MB), skipped {} already complete, {} failed, to {} in {:.1} s: {:.1} scenarios/s on {} threads",
        s.written,
        s.frame_pairs,
        s.bytes as f64 / 1e6,
        s.skipped,
        s.failed,
        s.out.display(),
        secs,
        s.written as f64 / secs.max(1e-9),
        s.threads
    );
    if let Some(shard) = &s.shard {
        line.push_str(&format!(", shard {shard}"));
    }
    if let Some(peak) = s.peak_memory {
        line.push_str(&format!(", peak memory {:.0} MB", peak as f64 / 1e6));
    }
    line
}
