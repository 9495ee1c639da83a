use clap::Parser;

fn main() -> std::process::ExitCode {
    taxel_calibrator::cli::main(taxel_calibrator::cli::Args::parse())
}
