use clap::Parser;

fn main() -> std::process::ExitCode {
    taxel_estimator::cli::main(taxel_estimator::cli::Args::parse())
}
